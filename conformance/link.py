"""The tester's side of the bus: send raw frames, wait for frames, keep a log per case.

Everything a case sees of the device goes through :class:`Link`; the log it keeps is
what a FAIL report prints (frames sent, frames seen, with times relative to the case start).
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
import canopen


@dataclass(frozen=True)
class Frame:
    cob: int
    data: bytes
    rtr: bool = False
    dlc: int | None = None
    timestamp: float = 0.0

    @property
    def length(self) -> int:
        return self.dlc if self.dlc is not None else len(self.data)

    def __str__(self) -> str:
        if self.rtr:
            return f"{self.cob:03X} RTR [{self.length}]"
        return f"{self.cob:03X} [{len(self.data)}] {self.data.hex(' ').upper()}".rstrip()


Match = Callable[[Frame], bool]


class Link:
    """A python-can bus plus a canopen Network sharing it (for canopen's SDO client)."""

    LOG_LIMIT = 2000

    def __init__(self, bus: can.BusABC, own_bus: bool = False):
        self.bus = bus
        self._own_bus = own_bus
        self._rx: queue.Queue[Frame] = queue.Queue()
        self.network = canopen.Network(bus)
        # canopen's list type is inferred from its first listener; can.Notifier takes any callable
        self.network.listeners.append(self._on_message)  # type: ignore[arg-type]
        self.network.NOTIFIER_CYCLE = (
            0.1  # closing the link waits up to one cycle for the receive thread
        )
        self.network.connect()
        self.log: list[tuple[float, str, Frame]] = []
        self._t0 = time.time()

    @classmethod
    def open(cls, interface: str, channel: str, bitrate: int | None = None) -> Link:
        """Open the bus as ``fieldgate run`` does: a bad interface, channel or driver is one
        line (PluginStartError), e.g. ``unknown CAN interface 'pcann' (python-can knows: ...)``."""
        from fieldgate.can.adapter import open_bus

        return cls(open_bus(interface, channel, bitrate or None), own_bus=True)

    def close(self) -> None:
        self.network.disconnect() if self._own_bus else self._stop_notifier()

    def _stop_notifier(self) -> None:
        if self.network.notifier is not None:
            self.network.notifier.stop()
            self.network.notifier = None

    # -- log -----------------------------------------------------------------
    def start_log(self) -> None:
        self.log = []
        self._t0 = time.time()

    def _record(self, direction: str, frame: Frame) -> None:
        if len(self.log) < self.LOG_LIMIT:
            self.log.append((frame.timestamp - self._t0, direction, frame))

    def log_lines(self, last: int = 40) -> list[str]:
        lines = [f"{t:+8.3f}s {d} {f}" for t, d, f in self.log[-last:]]
        if len(self.log) > last:
            lines.insert(0, f"({len(self.log) - last} earlier frames not shown)")
        return lines

    # -- traffic -------------------------------------------------------------
    def _on_message(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        frame = Frame(
            msg.arbitration_id,
            bytes(msg.data),
            msg.is_remote_frame,
            msg.dlc,
            msg.timestamp or time.time(),
        )
        self._rx.put(frame)

    def send(
        self, cob: int, data: bytes | list[int] = b"", rtr: bool = False, dlc: int | None = None
    ) -> Frame:
        data = bytes(data)
        msg = can.Message(
            arbitration_id=cob,
            data=b"" if rtr else data,
            is_extended_id=False,
            is_remote_frame=rtr,
            dlc=dlc if dlc is not None else len(data),
        )
        frame = Frame(cob, bytes(msg.data or b""), rtr, msg.dlc, time.time())
        self.bus.send(msg)
        self._record("→", frame)
        return frame

    def flush(self) -> None:
        """Drop frames received so far (they stay in the log)."""
        while True:
            try:
                self._record("←", self._rx.get_nowait())
            except queue.Empty:
                return

    def recv(self, timeout: float) -> Frame | None:
        try:
            frame = self._rx.get(timeout=max(timeout, 0.0))
        except queue.Empty:
            return None
        self._record("←", frame)
        return frame

    def expect(self, match: Match | int, timeout: float) -> Frame | None:
        """The first frame that matches (a COB-ID or a predicate) within ``timeout``; others are skipped."""
        pred = _matcher(match)
        deadline = time.monotonic() + timeout
        while True:
            frame = self.recv(deadline - time.monotonic())
            if frame is None:
                return None
            if pred(frame):
                return frame

    def collect(self, match: Match | int | None, duration: float) -> list[Frame]:
        """Every matching frame seen during ``duration`` seconds."""
        pred = _matcher(match) if match is not None else (lambda f: True)
        deadline = time.monotonic() + duration
        out = []
        while (left := deadline - time.monotonic()) > 0:
            frame = self.recv(left)
            if frame is not None and pred(frame):
                out.append(frame)
        return out


def _matcher(match: Match | int) -> Match:
    if isinstance(match, int):
        cob = match
        return lambda f: f.cob == cob and not f.rtr
    return match
