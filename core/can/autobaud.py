"""Finding a bus's bit rate by listening (the NA-9161's switch code 9, "auto-baud").

The controller listens at each standard rate in turn, in listen-only mode (it sends no
acknowledge and no error frame, so a wrong guess never disturbs the bus), until it sees
valid frames; then it goes to normal mode at that rate. At a wrong rate a controller sees no
valid frame, only bus errors (error frames, where the driver reports them).

:class:`BitrateProbe` is the decision, sans I/O: fed frames and the time, it says which rate
to listen at next, when, and when it has found the rate. :func:`probe_bitrate` runs it on a
SocketCAN interface through :mod:`.link` (blocking: call it in a thread from async code).
"""

from __future__ import annotations

import asyncio
import select
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from . import link as canlink
from .socketcan_raw import CAN_ERR_FLAG, FRAME

# CiA 301 / CiA 102's bit rates, fastest first: the NA-9161's baud switch codes 0..8
STANDARD_RATES = (1_000_000, 800_000, 500_000, 250_000, 125_000, 100_000, 50_000, 20_000, 10_000)


@dataclass(frozen=True)
class Step:
    """``listen`` at ``bitrate`` (listen-only), ``found`` (normal mode at ``bitrate``) or
    ``give-up`` (every round ended without valid frames)."""

    action: str
    bitrate: int | None = None


class BitrateProbe:
    """Listen at each rate for ``dwell_s``; ``frames_needed`` valid frames at one rate (with
    no error frame between them) find it; an error frame moves on to the next rate at once.
    ``rounds`` passes over the rates (None: until found)."""

    def __init__(
        self,
        rates: Sequence[int] = STANDARD_RATES,
        dwell_s: float = 1.0,
        frames_needed: int = 2,
        rounds: int | None = None,
    ) -> None:
        if not rates:
            raise ValueError("no bit rates to probe")
        self.rates = list(rates)
        self.dwell_s = dwell_s
        self.frames_needed = frames_needed
        self.rounds = rounds
        self.index = -1
        self.round = 0
        self.valid = 0
        self.deadline: float | None = None
        self.found: int | None = None
        self.tried: list[int] = []

    @property
    def bitrate(self) -> int:
        return self.rates[self.index]

    def start(self, now: float) -> Step:
        return self._next(now)

    def _next(self, now: float) -> Step:
        self.index += 1
        if self.index == len(self.rates):
            self.index = 0
            self.round += 1
            if self.rounds is not None and self.round >= self.rounds:
                self.deadline = None
                return Step("give-up")
        self.valid = 0
        self.deadline = now + self.dwell_s
        self.tried.append(self.bitrate)
        return Step("listen", self.bitrate)

    def on_frame(self, now: float, error_frame: bool) -> Step | None:
        """A frame received at the current rate; a Step when that decides something."""
        if self.found is not None or self.deadline is None:
            return None
        if error_frame:
            return self._next(now)
        self.valid += 1
        if self.valid >= self.frames_needed:
            self.found = self.bitrate
            self.deadline = None
            return Step("found", self.found)
        return None

    def on_time(self, now: float) -> Step | None:
        """The clock moved; a Step when the dwell at this rate ended."""
        if self.deadline is not None and now >= self.deadline:
            return self._next(now)
        return None


CAN_RAW_ERR_FILTER = 2
SOL_CAN_RAW = 101
CAN_ERR_MASK = 0x1FFF_FFFF


def probe_bitrate(
    name: str,
    probe: BitrateProbe,
    clock: Callable[[], float] = time.monotonic,
    on_step: Callable[[Step], None] = lambda step: None,
) -> int | None:
    """Run ``probe`` on the SocketCAN interface ``name``: listen-only at each rate, then
    normal mode at the rate found (returned), or None when the probe gave up (the interface
    is then left down). Raises :class:`~.link.LinkError` (no CAP_NET_ADMIN, a controller
    without listen-only mode)."""
    info = canlink.read_link(name)
    if info.kind != "can":
        raise canlink.LinkError(
            f"{name} has no bit timing (link kind {info.kind or 'none'!r}): nothing to probe"
        )
    if info.listen_only_supported is False:
        raise canlink.LinkError(
            f"{name}: the controller has no listen-only mode: probing the bit rate would "
            "disturb the bus at every wrong guess"
        )
    step = probe.start(clock())
    while True:
        on_step(step)
        if step.action == "give-up":
            canlink.set_up(name, False)
            return None
        if step.action == "found":
            assert step.bitrate is not None
            canlink.apply_settings(name, canlink.LinkSettings(step.bitrate, listen_only=False))
            return step.bitrate
        assert step.bitrate is not None
        canlink.apply_settings(name, canlink.LinkSettings(step.bitrate, listen_only=True))
        step = _listen(name, probe, clock)


def _listen(name: str, probe: BitrateProbe, clock: Callable[[], float]) -> Step:
    """Feed the probe what the interface receives until it decides."""
    sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    try:
        sock.setsockopt(SOL_CAN_RAW, CAN_RAW_ERR_FILTER, struct.pack("=I", CAN_ERR_MASK))
        sock.bind((name,))
        sock.setblocking(False)
        while True:
            now = clock()
            step = probe.on_time(now)
            if step is not None:
                return step
            wait = max(0.0, (probe.deadline or now) - now)
            ready, _, _ = select.select([sock], [], [], wait)
            if not ready:
                continue
            try:
                data = sock.recv(FRAME.size)
            except BlockingIOError:
                continue
            word = FRAME.unpack(data)[0]
            step = probe.on_frame(clock(), bool(word & CAN_ERR_FLAG))
            if step is not None:
                return step
    finally:
        sock.close()


class _Stopped(Exception):
    """The front stopped while probing."""


class AutoBaud:
    """A CAN front's auto-baud (``bitrate: auto``): :func:`probe_bitrate` in a thread before the
    engine boots, its progress for the front's status. Where the interface cannot be probed
    (not SocketCAN, ``configure_interface: false``, a ``vcan`` without bit timing, a
    controller without listen-only mode, no CAP_NET_ADMIN) one line says why and the bus opens
    with the interface as it is (:meth:`run` returns None)."""

    def __init__(
        self,
        channel: str,
        interface: object | None,
        probe: BitrateProbe | None = None,
        probing: Callable[..., int | None] | None = None,
    ) -> None:
        self.channel = channel
        self.controlled = interface is not None
        self.probe = probe or BitrateProbe()
        self._probing = probing or probe_bitrate
        self.state = "waiting"  # probing, found, not-probed
        self.listening_at: int | None = None
        self.found: int | None = None
        self.why: str = ""
        self._stop = threading.Event()

    def _step(self, step: Step) -> None:
        if self._stop.is_set():
            raise _Stopped
        if step.action == "listen":
            self.listening_at = step.bitrate

    async def run(self, log: Any) -> int | None:
        if not self.controlled:
            return self._not_probed(
                log,
                "fieldgate does not control this interface (SocketCAN with configure_interface only)",
            )
        self.state = "probing"
        log.info(
            "%s: bit rate auto: listening (listen-only) at %s bit/s until frames are seen",
            self.channel,
            ", ".join(str(r) for r in self.probe.rates),
        )
        try:
            found = await asyncio.to_thread(
                self._probing, self.channel, self.probe, on_step=self._step
            )
        except canlink.LinkError as exc:
            return self._not_probed(log, str(exc))
        except _Stopped:
            return None
        self.listening_at = None
        if found is None:  # (a probe without a round limit never gives up)
            return self._not_probed(log, "no rate had valid frames")
        self.state, self.found = "found", found
        log.info("%s: bit rate auto: %d bit/s found, normal mode", self.channel, found)
        return found

    def _not_probed(self, log: Any, why: str) -> int | None:
        """Auto-baud could not run: said once; the bus opens with the interface as it is."""
        self.state, self.why = "not-probed", why
        log.warning("bit rate auto: %s; the bus opens with the interface as it is", why)
        return None

    def stop(self) -> None:
        """Ends a probe running in its thread at its next step (within one dwell)."""
        self._stop.set()

    def status(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "listening_at": self.listening_at,
            "found": self.found,
            "tried": len(self.probe.tried),
            "round": self.probe.round + 1,
            "why": self.why or None,
        }
