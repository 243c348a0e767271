"""A CAN front's SocketCAN interface under its control: settings at start, bit-rate switches,
bus-off recovery and what the kernel says of the controller (docs/can-link.md).

:class:`InterfaceControl` is what :class:`~.front.CanFront` and the adapter's controller
call; it runs :mod:`.link`'s blocking calls in a thread (``asyncio.to_thread``) so the
event loop never waits for the kernel. It manages an interface only where that makes sense:
python-can's ``socketcan`` interface with ``configure_interface`` on (the default), and a link
of kind ``can`` (a ``vcan`` has no bit timing: nothing to do). With ``configure_interface:
false`` (systemd-networkd or ``ip link`` owns the interface) it only reads: a rate the
protocol asks for that the interface does not have is said (one line, the front's EMCY or
status), never set. Other python-can interfaces are left to their drivers.

A failure is never an exception to the caller: :meth:`InterfaceControl.apply` returns the
one line saying why (no CAP_NET_ADMIN, a rate the controller cannot make), the front logs it
once and shows it the way its device would (a CANopen EMCY, the DeviceNet Identity status),
and the node runs on with the interface as it is.

The link calls are injectable (:class:`LinkOps`): the host tests, where there is no
SocketCAN, drive the logic with a fake kernel.
"""

from __future__ import annotations

import asyncio
import errno
import logging
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from . import link as canlink
from .link import Applied, CanLink, LinkError, LinkSettings

log = logging.getLogger("fieldgate.can.interface")


@dataclass(frozen=True)
class LinkOps:
    """The kernel calls (blocking); :mod:`.link`'s by default."""

    read_link: Callable[[str], CanLink] = canlink.read_link
    apply_settings: Callable[[str, LinkSettings], Applied] = canlink.apply_settings
    restart: Callable[[str], str] = canlink.restart


@dataclass
class InterfaceControl:
    """One front's SocketCAN interface: ``channel`` (can0), the sample point and restart-ms
    to apply with every bit rate (None: leave the interface's own)."""

    channel: str
    sample_point: float | None = None
    restart_ms: int | None = None
    ops: LinkOps = field(default_factory=LinkOps)
    managed: bool = True  # False: read only (configure_interface: false)
    link: CanLink | None = None  # as last read
    error: str | None = None  # the last apply that failed (None once one succeeded)
    note: str = ""  # what the last apply said besides its differences (a virtual interface)
    restart_ms_unsupported: bool = False  # the driver refused restart-ms (slcan)
    counters: Counter[str] = field(default_factory=Counter)

    # -- applying settings -------------------------------------------------------------------
    async def apply(self, bitrate: int) -> str | None:
        """Bring the interface to ``bitrate`` (and the sample point, restart-ms): None when it
        is there now, else the one line saying why not (the interface is left as it is)."""
        if not self.managed:
            return await self._compare(bitrate)
        wanted = LinkSettings(
            bitrate,
            sample_point=self.sample_point,
            restart_ms=None if self.restart_ms_unsupported else self.restart_ms,
        )
        try:
            done = await asyncio.to_thread(self.ops.apply_settings, self.channel, wanted)
        except LinkError as exc:
            if exc.errno == errno.EOPNOTSUPP and wanted.restart_ms is not None:
                # slcan and the like have no restart-ms: the front restarts them after bus-off
                self.restart_ms_unsupported = True
                log.info(
                    "%s: the driver has no restart-ms: the front restarts it after bus-off",
                    self.channel,
                )
                return await self.apply(bitrate)
            self.counters["apply_failures"] += 1
            self.error = str(exc)
            await self.refresh()
            return self.error
        self.link, self.note, self.error = done.link, done.note, None
        if done.changed:
            self.counters["applied"] += 1
            log.info("%s: %s", self.channel, "; ".join(done.differences))
        elif done.note:
            log.debug("%s: %s", self.channel, done.note)
        return None

    async def _compare(self, bitrate: int) -> str | None:
        """Read only: whether the interface runs at ``bitrate``."""
        info = await self.refresh()
        if info is None or info.kind != "can" or info.bitrate in (None, bitrate):
            self.error = None
            return None
        self.counters["apply_failures"] += 1
        self.error = (
            f"{self.channel}: bit rate {bitrate} asked, the interface runs at {info.bitrate} "
            "(configure_interface: false: fieldgate leaves it to ip link / systemd-networkd)"
        )
        return self.error

    # -- reading and restarting --------------------------------------------------------------
    async def refresh(self) -> CanLink | None:
        """Read the interface again (bus-off, restarted, after a change); None if it cannot be read."""
        try:
            self.link = await asyncio.to_thread(self.ops.read_link, self.channel)
        except LinkError as exc:
            self.counters["read_failures"] += 1
            log.debug("%s: %s", self.channel, exc)
            return None
        return self.link

    @property
    def kernel_restarts(self) -> bool:
        """Whether the kernel restarts the controller after bus-off by itself (restart-ms > 0)."""
        return bool(self.link is not None and self.link.restart_ms)

    async def restart(self) -> str | None:
        """Restart the controller after bus-off (the front's own recovery where restart-ms is
        0); None when done, else why not."""
        if not self.managed:
            return (
                f"{self.channel}: not restarted: configure_interface is false (give the "
                "interface a restart-ms: RestartSec= in systemd-networkd's [CAN] section)"
            )
        try:
            how = await asyncio.to_thread(self.ops.restart, self.channel)
        except LinkError as exc:
            self.counters["restart_failures"] += 1
            await self.refresh()
            return str(exc)
        self.counters["restarts"] += 1
        log.info("%s: restarted after bus-off (%s)", self.channel, how)
        await self.refresh()
        return None

    def status(self) -> dict[str, Any]:
        """The interface as the kernel reported it last: its settings, the controller's state and
        error counters, the kernel's bus-off and restart counts; what fieldgate did to it."""
        info = self.link
        out: dict[str, Any] = {
            "channel": self.channel,
            "error": self.error,
            "applied": self.counters["applied"],
            "restarts_by_fieldgate": self.counters["restarts"],
        }
        if info is None:
            return out
        counters = info.counters
        out.update(
            kind=info.kind,
            up=info.up,
            bitrate=info.bitrate,
            sample_point=info.sample_point,
            restart_ms=info.restart_ms,
            state=info.state,
            tx_errors=info.tx_errors,
            rx_errors=info.rx_errors,
            bus_off=counters.get("bus_off"),
            restarts=counters.get("restarts"),
        )
        if self.note:
            out["note"] = self.note
        return out


def controls(interface: str, channel: str | None) -> bool:
    """Whether a front has a SocketCAN interface to read (and, with ``configure_interface``,
    to set): python-can's ``socketcan`` with a channel."""
    return interface == "socketcan" and bool(channel)
