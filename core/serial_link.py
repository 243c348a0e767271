"""Serial ports for back ends and simulators, and pseudo-terminal pairs for tests.

:class:`AsyncSerial` wraps a pyserial port (a device path or a pyserial URL such as
``socket://host:port``) for asyncio: reads are woken by ``loop.add_reader`` on the
port's file descriptor, so a poller never blocks the event loop (and so never delays
a CAN answer). A port that fails (read EIO or "readable but no data": the device is gone)
raises :class:`~fieldgate.polling.LineLost` from every later read and write, so the line
scheduler takes all its modules offline at once and the back re-opens the path.

:class:`PtyPair` gives two tty paths joined by a relay thread, the way a null-modem
cable joins two real ports: a back end opens one end, a simulator the other, and both
run their real serial code. The relay can pace bytes at a baud rate and inject faults.
"""

from __future__ import annotations

import asyncio
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from typing import Any

import serial

from .plugin import PluginStartError, PortUnavailable
from .polling import LineLost
from .serial_timing import Exchange, Outcome, char_time

__all__ = ["AsyncSerial", "PtyPair", "PluggablePty", "PortServer", "cancel_task", "char_time"]

_PARITY = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}


class AsyncSerial:
    def __init__(self, port: serial.SerialBase):
        self.port = port
        self._buffer = bytearray()
        self._data = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self._fd = port.fileno()
        self._loop.add_reader(self._fd, self._readable)
        self.closed = False
        self.lost: str | None = None  # why the port failed; it stays failed until re-opened
        self.last_rx = self._loop.time()  # when the last byte arrived (line silence)
        self.last_rx_at = time.monotonic()  # the same on the real clock (keep_silence)

    @classmethod
    async def open(
        cls, url: str, baudrate: int = 9600, bytesize: int = 8, parity: str = "N", stopbits: int = 1
    ) -> AsyncSerial:
        """Open a port; failures become PluginStartError with a one-line cause."""
        try:
            port = serial.serial_for_url(
                url,
                baudrate=baudrate,
                bytesize=bytesize,
                parity=_PARITY[parity],
                stopbits=stopbits,
                timeout=0,
                write_timeout=2,
            )
        except serial.SerialException as exc:
            raise PortUnavailable(f"cannot open serial port {url}: {_cause(exc)}") from None
        except ValueError as exc:
            raise PluginStartError(f"invalid serial settings for {url}: {exc}") from None
        return cls(port)

    def _drain(self) -> None:
        if not self.closed and self.lost is None:
            self._readable()

    def _readable(self) -> None:
        try:
            chunk = self.port.read(4096)
        except (serial.SerialException, OSError) as exc:
            chunk = b""
            self.lost = f"read failed: {exc}"
            self._loop.remove_reader(self._fd)
        if chunk:
            self._buffer += chunk
            self.last_rx = self._loop.time()
            self.last_rx_at = time.monotonic()
        self._data.set()

    @property
    def now(self) -> float:
        """The loop's clock, the one every time of this port is read on."""
        return self._loop.time()

    async def sleep(self, seconds: float) -> None:
        self._check_lost()
        await asyncio.sleep(seconds)

    async def keep_silence(self, gap: float, since: float = 0.0) -> None:
        """Wait until ``gap`` seconds of real time have passed since the last byte arrived (or
        since ``since``, a ``time.monotonic()`` stamp, when that is later): the Modbus RTU
        t3.5 before a request. The real clock decides, not the loop's timer: uvloop's timers
        and ``loop.time()`` are whole milliseconds of a clock read once a loop turn, and a
        1.75 ms ``asyncio.sleep`` there ended after 1.18 ms (issue 33), a t3.5 cut short."""
        self._check_lost()
        end = max(self.last_rx_at, since) + gap
        while (left := end - time.monotonic()) > 0:
            await asyncio.sleep(left)
        self._check_lost()

    @property
    def pending(self) -> int:
        """Bytes received and not yet consumed (a truncated reply, after a timeout)."""
        return len(self._buffer)

    def reset_input(self) -> None:
        """Drop whatever arrived unsolicited (late replies, line noise)."""
        self._buffer.clear()

    async def write(self, data: bytes) -> None:
        self._check_lost()
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            self.lost = f"write failed: {exc}"
            self._check_lost()

    def _check_lost(self) -> None:
        if self.lost is not None:
            raise LineLost(f"port {self.port.name}: {self.lost}")

    async def read_until(self, terminator: bytes, timeout: float) -> bytes:
        """Bytes up to and including ``terminator``; TimeoutError when it does not come."""
        deadline = self._loop.time() + timeout
        while True:
            end = self._buffer.find(terminator)
            if end >= 0:
                frame = bytes(self._buffer[: end + len(terminator)])
                del self._buffer[: end + len(terminator)]
                return frame
            await self._wait(deadline)

    async def read_frame(self, timeout: float, gap: float) -> bytes:
        """Bytes of one frame ended by a silent ``gap`` (Modbus RTU t3.5 framing)."""
        deadline = self._loop.time() + timeout
        while not self._buffer:
            await self._wait(deadline)
        while True:
            size = len(self._buffer)
            try:
                await self._wait(self._loop.time() + gap)
            except TimeoutError:
                if len(self._buffer) == size:
                    frame = bytes(self._buffer)
                    self._buffer.clear()
                    return frame

    async def exchange(self, request: bytes, exchange: Exchange) -> Outcome:
        """Send ``request`` and read the reply as ``exchange`` (fieldgate.serial_timing) says.

        Whatever arrived before the request is dropped. The exchange gets each chunk with
        the loop time it was read at and decides: reply, timeout, truncated, echo trouble.
        """
        self.reset_input()
        await self.write(request)
        exchange.sent(self._loop.time())
        while True:
            if self._buffer:
                data = bytes(self._buffer)
                self._buffer.clear()
                outcome = exchange.feed(data, self.last_rx)
            else:
                outcome = exchange.check(self._loop.time())
            if outcome is not None:
                return outcome
            try:
                await self._wait(exchange.deadline())
            except TimeoutError:
                # a deadline is about bytes on the wire, not about when this loop got round
                # to them: take what the port holds before the exchange concludes anything
                self._drain()

    async def wait_silence(self, silence: float, limit: float) -> bool:
        """Wait until no byte has arrived for ``silence`` seconds (at most ``limit`` seconds),
        then drop what came. True when the line fell silent, False when it kept talking."""
        give_up = self._loop.time() + limit
        while True:
            self._drain()  # bytes the loop has not read yet are not silence
            quiet_at = self.last_rx + silence
            now = self._loop.time()
            if now >= quiet_at:
                self.reset_input()
                return True
            if now >= give_up:
                self.reset_input()
                return False
            try:
                await self._wait(min(quiet_at, give_up))
            except TimeoutError:
                pass

    async def _wait(self, deadline: float) -> None:
        self._check_lost()
        remaining = deadline - self._loop.time()
        if remaining <= 0:
            raise TimeoutError
        self._data.clear()
        # asyncio.timeout, not wait_for: on Python 3.11 wait_for can swallow a cancellation
        # that arrives together with the data, and the poller then never stops
        async with asyncio.timeout(remaining):
            await self._data.wait()
        self._check_lost()

    async def close(self) -> None:
        self.close_now()

    def close_now(self) -> None:
        """Close at once (from synchronous code too)."""
        if not self.closed:
            self.closed = True
            try:
                self._loop.remove_reader(self._fd)
            except (ValueError, OSError):
                pass
            self.port.close()


def _cause(exc: serial.SerialException) -> str:
    inner = exc.args[1] if len(exc.args) > 1 else None
    if exc.errno == 2 or "No such file" in str(exc):
        return "no such device"
    if exc.errno == 13 or "Permission denied" in str(exc):
        return "permission denied"
    return str(inner or exc)


class PtyPair:
    """Two pseudo-terminals joined by a relay: ``a`` and ``b`` are tty paths.

    ``baudrate`` paces the relay like a wire (10 bits a byte); ``fault`` is a callable
    applied to each chunk going b → a (simulator to back), returning the bytes to
    deliver (``b""`` drops them). Use as a context manager, or call ``close()``.
    """

    def __init__(self, baudrate: int | None = None):
        self._ends: list[tuple[int, int]] = []
        try:
            for _ in range(2):
                master, slave = os.openpty()
                self._ends.append((master, slave))
                tty.setraw(master)
                tty.setraw(slave)
        except OSError:  # no pseudo-terminals: raise without leaking the first pair
            self._close_ends()
            raise
        self.a = os.ttyname(self._ends[0][1])
        self.b = os.ttyname(self._ends[1][1])
        self.baudrate = baudrate
        self.fault: Callable[[bytes], bytes] | None = None
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(
                target=self._pump, args=(self._ends[0][0], self._ends[1][0], False), daemon=True
            ),
            threading.Thread(
                target=self._pump, args=(self._ends[1][0], self._ends[0][0], True), daemon=True
            ),
        ]
        for t in self._threads:
            t.start()

    def _pump(self, src: int, dst: int, to_a: bool) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([src], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(src, 4096)
            except OSError:
                return
            if to_a and self.fault is not None:
                data = self.fault(data)
            if self.baudrate:
                time.sleep(len(data) * 10 / self.baudrate)
            if data:
                try:
                    os.write(dst, data)
                except OSError:
                    return

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=1)
        self._close_ends()

    def _close_ends(self) -> None:
        for master, slave in self._ends:
            for fd in (master, slave):
                try:
                    os.close(fd)
                except OSError:
                    pass

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _raw_pty() -> tuple[int, int]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave


class PluggablePty:
    """A pty pair whose end ``a`` is a path that can be unplugged and plugged back, the way
    a USB-RS485 adapter's ``/dev/serial/by-id/...`` link comes and goes (fault tests).

    ``a`` is ``link``, a symlink to the current pseudo-terminal; ``b`` is the other end (a
    simulator's). :meth:`unplug` removes the link and hangs up the pseudo-terminal (a port
    open on it reads EIO, as a pulled adapter does); :meth:`plug` makes a new one and points
    the link at it. ``fault`` transforms the bytes going b → a (garbage); ``echo`` sends
    what a writes back to a as well (a 2-wire RS-485 adapter that hears itself).
    """

    def __init__(self, link: str | os.PathLike[str]) -> None:
        self.link = os.fspath(link)
        self.a = self.link
        self._b = _raw_pty()
        self.b = os.ttyname(self._b[1])
        self._a: tuple[int, int] | None = None
        self.fault: Callable[[bytes], bytes] | None = None
        self.echo = False
        self.plugged_in = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.plug()
        self._thread = threading.Thread(target=self._relay, daemon=True)
        self._thread.start()

    def plug(self) -> None:
        """A new pseudo-terminal under the same path (the adapter is back)."""
        with self._lock:
            if self._a is not None:
                return
            self._a = _raw_pty()
            tmp = f"{self.link}.new"
            os.symlink(os.ttyname(self._a[1]), tmp)
            os.replace(tmp, self.link)
            self.plugged_in += 1

    def unplug(self) -> None:
        """The path disappears and the open port hangs up."""
        with self._lock:
            if self._a is None:
                return
            try:
                os.unlink(self.link)
            except FileNotFoundError:
                pass
            for fd in self._a:
                os.close(fd)
            self._a = None

    def _relay(self) -> None:
        b_master = self._b[0]
        while not self._stop.is_set():
            a = self._a
            fds = [b_master] + ([a[0]] if a else [])
            try:
                ready, _, _ = select.select(fds, [], [], 0.02)
            except (OSError, ValueError):
                continue  # end a was unplugged while we waited
            with self._lock:
                a_master = self._a[0] if self._a else None
                for fd in ready:
                    if fd != b_master and fd != a_master:
                        continue
                    try:
                        data = os.read(fd, 4096)
                    except OSError:
                        continue
                    try:
                        if fd == b_master:
                            if a_master is not None:
                                data = self.fault(data) if self.fault else data
                                os.write(a_master, data)
                        else:
                            os.write(b_master, data)
                            if self.echo and a_master is not None:
                                os.write(a_master, data)
                    except OSError:
                        pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1)
        self.unplug()
        for fd in self._b:
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PluggablePty:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PortServer:
    """The serving end of a serial port, for module simulators.

    Received bytes go to ``on_data(data, now)`` on the event loop; replies are written
    at once (:meth:`send`) or after a delay (:meth:`send_later`, for fault injection).
    """

    def __init__(
        self,
        port: str,
        on_data: Callable[[bytes, float], None],
        *,
        baudrate: int = 9600,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: int = 1,
    ):
        self.port_name = port
        self.on_data = on_data
        self.settings: dict[str, Any] = dict(
            baudrate=baudrate, bytesize=bytesize, parity=_PARITY[parity], stopbits=stopbits
        )
        self.sent = 0  # replies written
        self._port: serial.SerialBase | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timers: set[asyncio.TimerHandle] = set()

    def open(self) -> None:
        """Open the port and start serving; PluginStartError with the cause on failure."""
        try:
            self._port = serial.serial_for_url(self.port_name, timeout=0, **self.settings)
        except (serial.SerialException, ValueError) as exc:
            raise PluginStartError(f"simulator cannot open {self.port_name}: {exc}") from None
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self._port.fileno(), self._readable)

    @property
    def now(self) -> float:
        assert self._loop is not None
        return self._loop.time()

    def _readable(self) -> None:
        assert self._port is not None and self._loop is not None
        try:
            data = self._port.read(4096)
        except (serial.SerialException, OSError):
            self._loop.remove_reader(self._port.fileno())
            return
        if data:
            self.on_data(data, self._loop.time())

    def send(self, data: bytes) -> None:
        if self._port is None:
            return
        try:
            self._port.write(data)
            self.sent += 1
        except (serial.SerialException, OSError):
            pass  # the other end went away: a simulator keeps serving

    def send_later(self, delay: float, data: bytes) -> None:
        assert self._loop is not None

        def fire() -> None:
            self._timers.discard(timer)
            self.send(data)

        timer = self._loop.call_later(delay, fire)
        self._timers.add(timer)

    def close(self) -> None:
        for timer in self._timers:
            timer.cancel()
        self._timers.clear()
        if self._port is not None:
            if self._loop is not None:
                try:
                    self._loop.remove_reader(self._port.fileno())
                except (ValueError, OSError):
                    pass
            self._port.close()
            self._port = None


async def cancel_task(task: asyncio.Task[Any] | None) -> None:
    """Cancel a background task and wait until it has ended."""
    if task is not None:
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            pass
