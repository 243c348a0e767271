"""systemd's service notification protocol for ``fieldgate run`` (a ``Type=notify`` unit).

When systemd starts a service it sets ``$NOTIFY_SOCKET`` (a Unix datagram socket; a name
starting with ``@`` is in the abstract namespace) and, with ``WatchdogSec=``,
``$WATCHDOG_USEC`` (and ``$WATCHDOG_PID``). A service sends newline-separated
``KEY=VALUE`` lines there (sd_notify(3)); fieldgate sends:

* ``READY=1`` once every back and every front has started, with a ``STATUS=`` line;
* ``WATCHDOG=1`` every half watchdog period, **from the event loop**: a task that sleeps and
  sends, so a loop that stalls (a blocking call, a runaway callback) stops the keep-alives
  and systemd restarts the service (``Restart=on-failure``); a thread would keep them coming;
* ``STATUS=`` whenever the one-line summary changes (readiness, modules online, masters);
* ``STOPPING=1`` when SIGTERM/SIGINT starts the clean stop.

Without ``$NOTIFY_SOCKET`` nothing is sent. The protocol is one ``sendto`` of a datagram:
written here rather than taken from a library (README, library table: sdnotify, last
released in 2017, reads no watchdog settings and hides every error; systemd-python builds
against libsystemd's headers). A failed send is logged once and never stops the gateway.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .runtime import Gateway

log = logging.getLogger("fieldgate.systemd")

STATUS_PERIOD_S = 5.0  # how often the STATUS line is looked at when there is no watchdog


def socket_address(name: str) -> str:
    """``$NOTIFY_SOCKET`` as an AF_UNIX address: ``@name`` is ``\\0name`` (abstract namespace)."""
    return "\0" + name[1:] if name.startswith("@") else name


class Notifier:
    """Datagrams to the service manager; ``watchdog_s`` is the keep-alive period (or None)."""

    def __init__(self, address: str, watchdog_s: float | None = None):
        self.address = address
        self.watchdog_s = watchdog_s
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self._socket.setblocking(False)
        self._failed = False
        self.last_status = ""

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] = os.environ) -> Notifier | None:
        """The notifier systemd asks for, or None when not started as a ``Type=notify`` service."""
        name = environ.get("NOTIFY_SOCKET", "")
        if not name.startswith(("/", "@")) or len(name) < 2:
            return None
        return cls(socket_address(name), watchdog_period(environ))

    def send(self, *lines: str) -> bool:
        """One datagram of ``KEY=VALUE`` lines; False (logged once) when it cannot be sent."""
        try:
            self._socket.sendto("\n".join(lines).encode(), self.address)
        except OSError as exc:
            if not self._failed:
                log.warning("cannot notify the service manager: %s", exc.strerror or exc)
            self._failed = True
            return False
        self._failed = False
        return True

    def ready(self, status: str) -> None:
        self.last_status = status
        self.send("READY=1", f"STATUS={status}")

    def stopping(self) -> None:
        self.last_status = "stopping"
        self.send("STOPPING=1", "STATUS=stopping")

    def status(self, status: str) -> None:
        self.last_status = status
        self.send(f"STATUS={status}")

    async def keep_alive(self, status: Callable[[], str]) -> None:
        """Until cancelled: WATCHDOG=1 every half watchdog period, and STATUS when it changed.

        Runs as a task on the gateway's loop: when the loop stalls, the keep-alives stop.
        """
        period = self.watchdog_s / 2 if self.watchdog_s else STATUS_PERIOD_S
        while True:
            await asyncio.sleep(period)
            lines = ["WATCHDOG=1"] if self.watchdog_s else []
            text = status()
            if text != self.last_status:
                self.last_status = text
                lines.append(f"STATUS={text}")
            if lines:
                self.send(*lines)

    def close(self) -> None:
        self._socket.close()


def watchdog_period(environ: Mapping[str, str]) -> float | None:
    """``$WATCHDOG_USEC`` in seconds, when the watchdog is meant for this process."""
    pid = environ.get("WATCHDOG_PID")
    if pid is not None and pid.strip() != str(os.getpid()):
        return None
    try:
        usec = int(environ.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    return usec / 1e6 if usec > 0 else None


def status_line(gateway: Gateway) -> str:
    """The gateway in one line, for ``systemctl status``: readiness, modules, masters."""
    from .http.explain import readiness

    ready, reasons = readiness(gateway)
    starting: list[str] = []
    if not ready and gateway.fieldbus_up and not gateway.running:
        # READY went out with the fieldbus side; the north-facing children are starting
        starting = [c.name for c in gateway.fronts if not getattr(c, "started", False)]
    elif not ready:
        return "not ready: " + "; ".join(reasons)
    modules = gateway.health.modules()
    online = sum(m.online for m in modules)
    lost = [f.name for f in gateway.fronts if not gateway.masters.is_ok(f.name)]
    text = (
        f"running: {len(gateway.fronts)} front(s), {len(gateway.backs)} back(s), "
        f"{online}/{len(modules)} module(s) online"
    )
    text += f"; master lost: {', '.join(lost)}" if lost else ""
    return text + (f"; starting: {', '.join(starting)}" if starting else "")
