"""How a serial back reads a reply off a half-duplex RS-485 line, sans-I/O.

Every RS-485 back shares one timing model (the Modbus and DCON backs, third parties):

* **response timeout** (``timeout_ms``): from the end of the request on the wire until the
  *first byte* of the reply. A long reply that starts in time is never cut: at 9600 baud a
  125-register Modbus reply is 255 bytes, 266 ms on the wire, and it is read whole with
  ``timeout_ms: 200`` (libmodbus's *response timeout*);
* **inter-byte timeout** (``byte_timeout_ms``): silence inside a reply that ends it. A frame
  whose length is known (Modbus) or that ends with its terminator (DCON's CR) completes at
  once; the inter-byte timeout only ends a broken one. Its default is
  :func:`default_byte_timeout`: 8 character times, at least :data:`BYTE_TIMEOUT_FLOOR_S`,
  because a USB-RS485 adapter hands bytes over in USB transfers: an FTDI chip's latency
  timer (16 ms by default) shows up as a 16 ms gap inside a frame, which must not end it
  (libmodbus's *byte timeout*);
* **line silence after a failure**: after a timeout, a broken or unexpected reply, the next
  request waits until no byte has arrived for :attr:`LineTiming.silence` (3.5 character
  times, and at least the inter-byte timeout, so an adapter's latency does not fake
  silence), so a late answer is never read as the reply to the next request;
* **echo** (``echo: true|false|auto``): a 2-wire adapter that hears its own transmission
  puts the request in front of every reply. With echo on, the first bytes must be the
  request (compared, then dropped); they never count as the reply, so the echo of a Modbus
  FC5/FC6 write (which is byte for byte what the reply would be) is not taken for the
  answer. ``auto`` checks every exchange: bytes that begin with the whole request are its
  echo (a reply never does, except an FC5/FC6 reply: for those, what the line showed last
  decides, and before anything is known a second copy behind the first).

:class:`Exchange` is the state machine of one request and its reply: fed the received
bytes with the time they arrived, it returns the outcome and its next deadline. The I/O
side (``fieldgate.serial_link.AsyncSerial.exchange``) only writes, reads and keeps the
clock; tests drive an Exchange with numbers for the time.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

BYTE_TIMEOUT_FLOOR_S = 0.030
"""Least default inter-byte timeout: above a USB adapter's latency timer (FTDI: 16 ms)."""

BYTE_TIMEOUT_CHARS = 8
"""Default inter-byte timeout in character times, where that exceeds the floor (slow lines)."""

SILENCE_CHARS = 3.5
"""Line silence that ends a failure, in character times (the Modbus RTU t3.5)."""

LONGEST_FRAME = 256
"""Bytes of the longest reply frame a serial back reads (a Modbus RTU ADU: 256)."""

EchoSetting = Literal[True, False, "auto"]


def bits_per_char(bytesize: int = 8, parity: str = "N", stopbits: int = 1) -> int:
    """Bits on the wire per character: start, data, parity (if any), stop."""
    return 1 + bytesize + (0 if parity == "N" else 1) + stopbits


def char_time(baudrate: int, bits: int = 11) -> float:
    """Seconds per character on the wire (11 bits by default: start + 8 data + parity/stop)."""
    return bits / baudrate


def default_byte_timeout(baudrate: int, bits: int = 11) -> float:
    """The inter-byte timeout a line gets unless ``byte_timeout_ms`` says otherwise."""
    return max(BYTE_TIMEOUT_FLOOR_S, BYTE_TIMEOUT_CHARS * char_time(baudrate, bits))


@dataclass(frozen=True)
class LineTiming:
    """The timing of one line, in seconds."""

    response: float  # end of request -> first byte of the reply
    byte: float  # silence that ends a frame
    char: float  # one character on the wire

    @classmethod
    def of(
        cls,
        baudrate: int,
        timeout_ms: float,
        byte_timeout_ms: float | None = None,
        bits: int = 11,
    ) -> LineTiming:
        byte = (
            default_byte_timeout(baudrate, bits)
            if byte_timeout_ms is None
            else byte_timeout_ms / 1000
        )
        return cls(timeout_ms / 1000, byte, char_time(baudrate, bits))

    @property
    def silence(self) -> float:
        """Quiet time the line must show after a failure before the next request."""
        return max(SILENCE_CHARS * self.char, self.byte)

    @property
    def silence_limit(self) -> float:
        """Longest wait for silence: a reply of :data:`LONGEST_FRAME` bytes that began just
        now, then the silence; a line that talks longer than that is babbling."""
        return self.response + self.wire_time(LONGEST_FRAME) + self.silence

    def wire_time(self, nbytes: int) -> float:
        return nbytes * self.char


class Result(enum.Enum):
    REPLY = "reply"  # a complete frame (its CRC/checksum is the codec's business)
    TIMEOUT = "timeout"  # no byte of a reply within the response timeout
    TRUNCATED = "truncated"  # bytes, but no complete frame before the inter-byte timeout
    ECHO_MISMATCH = "echo mismatch"  # echo on, and the first bytes are not the request
    NO_ECHO = "no echo"  # echo on, and the request never came back


@dataclass
class Outcome:
    result: Result
    frame: bytes = b""  # the reply frame (REPLY), or what arrived after the echo
    rest: bytes = b""  # bytes after a complete frame
    echo_seen: bool | None = None  # what this exchange showed about an echo (auto detection)

    def describe(self) -> str:
        shown = self.frame[:32].hex(" ") + (" ..." if len(self.frame) > 32 else "")
        return {
            Result.REPLY: f"reply {shown}",
            Result.TIMEOUT: "no reply",
            Result.TRUNCATED: f"incomplete reply, then silence: {shown}",
            Result.ECHO_MISMATCH: f"the echo differs from the request (a collision?): {shown}",
            Result.NO_ECHO: "the request was not echoed (is echo: true right for this adapter?)",
        }[self.result]


FrameEnd = Callable[[bytes], "int | None"]
"""Length of the complete frame at the start of the bytes, or None while more are needed."""


@dataclass
class Exchange:
    """One request and its reply. ``echo``: True (the request must come back first), False
    (no echo handling), None (auto: a request that comes back is an echo, dropped).

    ``ambiguous``: the reply to this request may be byte for byte the request (Modbus
    FC5/FC6), so the echo cannot be told from the reply by content alone; in auto mode
    ``assume`` says what the line has shown so far (None: nothing yet: wait one inter-byte
    timeout for a second copy).
    """

    request: bytes
    timing: LineTiming
    frame_end: FrameEnd
    sent_at: float = 0.0  # when the request was handed to the port (see :meth:`sent`)
    echo: bool | None = False
    ambiguous: bool = False
    assume: bool | None = None
    buffer: bytearray = field(default_factory=bytearray)
    last_byte: float | None = None
    echo_seen: bool | None = None
    _echo_done: bool = False

    def __post_init__(self) -> None:
        self.sent(self.sent_at)
        if self.echo is False:
            self._echo_done = True

    def sent(self, now: float) -> None:
        """The request was written at ``now``; it is on the wire for its length in characters."""
        self.sent_at = now
        self.sent_done = now + self.timing.wire_time(len(self.request))

    def feed(self, data: bytes, now: float) -> Outcome | None:
        """Bytes received at ``now``; the outcome once there is one."""
        if data:
            self.buffer += data
            self.last_byte = now
        return self.check(now)

    def check(self, now: float) -> Outcome | None:
        """The outcome if one is due at ``now`` (call at :meth:`deadline`)."""
        if not self._echo_done:
            outcome = self._echo_stage(now)
            if outcome is not None or not self._echo_done:
                return outcome
        reply = bytes(self.buffer)
        if reply:
            n = self.frame_end(reply)
            if n is not None and n <= len(reply):
                return self._outcome(Result.REPLY, reply[:n], reply[n:])
            assert self.last_byte is not None
            if now >= self.last_byte + self.timing.byte:
                return self._outcome(Result.TRUNCATED, reply)
            return None
        if now >= self.sent_done + self.timing.response:
            return self._outcome(Result.TIMEOUT)
        return None

    def deadline(self) -> float:
        """When :meth:`check` must run next if no byte arrives before."""
        if self.buffer and self.last_byte is not None:
            return self.last_byte + self.timing.byte
        return self.sent_done + self.timing.response

    def _echo_stage(self, now: float) -> Outcome | None:
        req, buf = self.request, bytes(self.buffer)
        n = min(len(buf), len(req))
        if buf[:n] != req[:n]:
            if self.echo is True:
                return self._outcome(Result.ECHO_MISMATCH, buf)
            self.echo_seen = False  # auto: a reply that is not the request: no echo here
            self._echo_done = True
            return None
        if len(buf) < len(req):
            if not buf and self.echo is True and now >= self.sent_done + self.timing.response:
                return self._outcome(Result.NO_ECHO)
            if buf and self.echo is True and now >= (self.last_byte or now) + self.timing.byte:
                return self._outcome(Result.ECHO_MISMATCH, buf)
            if not buf and now >= self.sent_done + self.timing.response:
                return self._outcome(Result.TIMEOUT)  # auto: nothing at all
            if buf and self.echo is None and now >= (self.last_byte or now) + self.timing.byte:
                self._echo_done = True  # auto: a short reply that began like the request
            return None
        # the whole request came back
        if self.echo is True or not self.ambiguous or len(buf) > len(req) or self.assume:
            self._take_echo()
            return None
        if self.assume is False:
            self._echo_done = True  # auto, FC5/FC6 on a line without echo: it is the reply
            return None
        # auto, FC5/FC6, nothing known yet: the echo or the reply? Wait for a second copy
        if now >= (self.last_byte or now) + self.timing.byte:
            self._echo_done = True  # nothing behind it: it is the reply; echo still unknown
        return None

    def _take_echo(self) -> None:
        del self.buffer[: len(self.request)]
        self.echo_seen = True
        self._echo_done = True

    def _outcome(self, result: Result, frame: bytes = b"", rest: bytes = b"") -> Outcome:
        return Outcome(result, frame, rest, self.echo_seen)


class EchoState:
    """A line's echo setting and what ``auto`` has found out so far."""

    def __init__(self, setting: EchoSetting = "auto") -> None:
        self.setting = setting
        self.detected: bool | None = None if setting == "auto" else bool(setting)

    @property
    def expect(self) -> bool | None:
        """An Exchange's ``echo``: True, False, or None (auto: checked on every exchange)."""
        return None if self.setting == "auto" else bool(self.setting)

    @property
    def assume(self) -> bool | None:
        """An Exchange's ``assume``: what auto has seen last (None: nothing yet)."""
        return self.detected

    def learn(self, outcome: Outcome) -> bool:
        """Take what an exchange showed; True when auto's finding changed just now."""
        if self.setting == "auto" and outcome.echo_seen is not None:
            changed = outcome.echo_seen != self.detected
            self.detected = outcome.echo_seen
            return changed
        return False

    def reset(self) -> None:
        """A re-opened port may be another adapter: detect again."""
        if self.setting == "auto":
            self.detected = None

    def describe(self) -> str:
        if self.setting != "auto":
            return "on" if self.setting else "off"
        return {None: "auto (not known yet)", True: "auto: echo detected", False: "auto: no echo"}[
            self.detected
        ]
