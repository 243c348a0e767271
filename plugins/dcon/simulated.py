"""Simulated DCON modules (sans-I/O): the command interpreter the simulator serves.

A :class:`SimModule` answers one command text (checksum already checked) at a time
and keeps the module's state: inputs, outputs, type code and format, host watchdog,
safe and power-on values. :class:`SimBus` is a line of them: it splits the byte
stream at CR, checks checksums (a bad one gets silence, as on a real line), sends
``~**`` to everyone and applies fault injection. Time is passed in, never read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fieldgate.polling import CommError

from . import codec
from .formats import DataFormat, ao_text_to_raw, engineering_to_raw, raw_to_engineering, raw_to_text
from .profiles import AIDIO, AO_SINGLE, DIO, Profile
from .tables import DIO_TYPE_CODE, TABLES, TypeRange

FIRMWARE = "B1.0"


def _mask(n: int) -> int:
    return (1 << n) - 1


class SimModule:
    def __init__(
        self,
        profile: Profile,
        address: int,
        *,
        type_code: int | None = None,
        data_format: DataFormat = DataFormat.HEX,
        checksum: bool = False,
        baud_code: int = 0x06,
    ):
        self.profile = profile
        self.address = address
        key = profile.ai_table or profile.ao_table
        table = TABLES[key] if key else None
        self.table = table
        self.type_code = (
            type_code if type_code is not None else (table.default if table else DIO_TYPE_CODE)
        )
        self.data_format = data_format
        self.checksum = checksum
        self.baud_code = baud_code
        self.name = profile.model[2:]  # what $AAM answers: "7017" for an I-7017
        self.di_bits = 0
        self.do_bits = 0
        self.ai_raw = [0] * profile.ai
        self.ao_raw = [0] * profile.ao
        self.safe_do = 0
        self.power_on_do = 0
        self.safe_ao = [0] * profile.ao
        self.power_on_ao = [0] * profile.ao
        self.watchdog_enabled = False
        self.watchdog_tenths = 0
        self.timed_out = False
        self.last_host_ok = 0.0
        self.reset_flag = True  # $AA5 answers 1 once after power-on
        self.commands = 0
        self.ignored_writes = 0

    @property
    def range(self) -> TypeRange | None:
        return self.table.get(self.type_code) if self.table else None

    # -- time -----------------------------------------------------------------------
    def host_ok(self, now: float) -> None:
        self.last_host_ok = now

    def tick(self, now: float) -> bool:
        """Apply a host-watchdog timeout if due. True when it fired now."""
        if (
            self.watchdog_enabled
            and not self.timed_out
            and now - self.last_host_ok > self.watchdog_tenths / 10
        ):
            self.timed_out = True
            self.do_bits = self.safe_do
            self.ao_raw = list(self.safe_ao)
            return True
        return False

    def power_cycle(self, now: float) -> None:
        """Power off and on: outputs at power-on values, or safe values while the timeout flag is set."""
        self.do_bits = self.safe_do if self.timed_out else self.power_on_do
        self.ao_raw = list(self.safe_ao if self.timed_out else self.power_on_ao)
        self.reset_flag = True
        self.last_host_ok = now

    # -- commands ---------------------------------------------------------------------
    def handle(self, text: str, now: float) -> str | None:
        """The reply text to one command addressed to this module, or None (silence)."""
        self.commands += 1
        lead, body = text[0], text[3:]
        try:
            handler = {
                "$": self._dollar,
                "#": self._hash,
                "@": self._at,
                "~": self._tilde,
                "%": self._percent,
            }[lead]
            return handler(body, now)
        except (ValueError, IndexError, OverflowError, CommError):
            return None  # malformed data: a real module stays silent

    def _ok(self, data: str = "") -> str:
        return f"!{self.address:02X}{data}"

    def _refuse(self) -> str:
        return f"?{self.address:02X}"

    def _dollar(self, body: str, now: float) -> str | None:
        p = self.profile
        if body == "2":
            fmt = (self.data_format.value if (p.ai or p.ao) else 0) | (0x40 if self.checksum else 0)
            return self._ok(f"{self.type_code:02X}{self.baud_code:02X}{fmt:02X}")
        if body == "M":
            return self._ok(self.name)
        if body == "F":
            return self._ok(FIRMWARE)
        if body == "5":
            flag, self.reset_flag = self.reset_flag, False
            return self._ok("1" if flag else "0")
        if body == "6" and p.digital == DIO:
            return "!" + p.encode_dio(self.do_bits, self.di_bits) + "00"
        if body == "6" and p.ai:
            return self._ok(f"{_mask(p.ai):02X}")
        if p.ao and body[:1] == "6" and self.range is not None:  # $AA6 / $AA6N: last output value
            (ch,) = self._ao_channels(body[1:])
            return self._ok(
                raw_to_text(
                    self.ao_raw[ch],
                    self.data_format,
                    self.range,
                    hex_width=p.ao_hex_width,
                    signed_text=p.ao_signed_text,
                )
            )
        if p.ao and body[:1] == "4":  # $AA4 / $AA4N: current output becomes the power-on value
            for ch in self._ao_channels(body[1:]):
                self.power_on_ao[ch] = self.ao_raw[ch]
            return self._ok()
        return None

    def _ao_channels(self, rest: str) -> list[int]:
        if self.profile.ao_style == AO_SINGLE:
            if rest:
                raise ValueError(rest)
            return [0]
        channel = int(rest, 16)
        if not 0 <= channel < self.profile.ao:
            raise ValueError(rest)
        return [channel]

    def _hash(self, body: str, now: float) -> str | None:
        p, rng = self.profile, self.range
        if p.ai:
            if rng is None:
                return None
            if body == "":
                return ">" + "".join(self._ai_text(i) for i in range(p.ai))
            if len(body) == 1 and body in "0123456789":
                channel = int(body)
                return ">" + self._ai_text(channel) if channel < p.ai else self._refuse()
            return None
        if p.ao:
            if rng is None:
                return None
            channel, text = (0, body) if p.ao_style == AO_SINGLE else (int(body[0], 16), body[1:])
            if channel >= p.ao or not text:
                return "?"
            if self.timed_out:
                self.ignored_writes += 1
                return "!"
            raw, quality = ao_text_to_raw(text, self.data_format, rng)
            if quality.value != "good":
                return "?"
            self.ao_raw[channel] = raw
            return ">"
        if p.digital == DIO and len(body) == 4:
            return self._set_group(body[:2], int(body[2:], 16))
        return None

    def _set_group(self, bb: str, dd: int) -> str:
        if self.timed_out:
            self.ignored_writes += 1
            return "!"
        bb = bb.upper()
        if bb in ("00", "0A"):
            self.do_bits = (self.do_bits & ~0xFF | dd) & _mask(self.profile.do)
        elif bb == "0B":
            self.do_bits = (self.do_bits & 0xFF | dd << 8) & _mask(self.profile.do)
        elif bb[0] in "1AB" and dd in (0, 1):
            channel = int(bb[1], 16) + (8 if bb[0] == "B" else 0)
            if channel >= self.profile.do:
                return "?"
            self.do_bits = self.do_bits | 1 << channel if dd else self.do_bits & ~(1 << channel)
        else:
            return "?"
        return ">"

    def _ai_text(self, channel: int) -> str:
        assert self.range is not None
        return raw_to_text(self.ai_raw[channel], self.data_format, self.range)

    def _at(self, body: str, now: float) -> str | None:
        p = self.profile
        if p.digital == DIO:
            if body == "":
                return ">" + p.encode_dio(self.do_bits, self.di_bits)
            if len(body) != p.do_chars or not p.do:
                return None if not p.do else "?"
            value = int(body, 16)
            if value > _mask(p.do):
                return "?"
            if self.timed_out:
                self.ignored_writes += 1
                return "!"
            self.do_bits = value
            return ">"
        if p.digital == AIDIO:
            if body == "DI":
                return self._ok(f"0{self.do_bits:02X}{self.di_bits:02X}")
            if body.startswith("DO") and len(body) == 4:
                value = int(body[2:], 16)
                if value > _mask(p.do):
                    return self._refuse()
                if self.timed_out:
                    self.ignored_writes += 1
                else:
                    self.do_bits = value
                return self._ok()
        return None

    def _tilde(self, body: str, now: float) -> str | None:
        p = self.profile
        if body == "0":
            return self._ok(
                f"{(0x04 if self.timed_out else 0) | (0x80 if self.watchdog_enabled else 0):02X}"
            )
        if body == "1":
            # the flag only: the watchdog keeps counting from the last ~** (so a clear
            # sent while ~** is paused is followed by a new timeout at once)
            self.timed_out = False
            return self._ok()
        if body == "2":
            return self._ok(f"{1 if self.watchdog_enabled else 0}{self.watchdog_tenths:02X}")
        if body[:1] == "3" and len(body) == 4 and body[1] in "01":
            tenths = int(body[2:], 16)
            if body[1] == "1" and tenths == 0:
                return self._refuse()
            self.watchdog_enabled, self.watchdog_tenths, self.last_host_ok = (
                body[1] == "1",
                tenths,
                now,
            )
            return self._ok()
        if p.digital == DIO and p.do and body in ("4P", "4S"):
            return self._ok(
                f"{self.power_on_do if body[1] == 'P' else self.safe_do:0{max(2, p.do_chars)}X}"
            )
        if p.digital == DIO and p.do and body in ("5P", "5S"):
            if body[1] == "P":
                self.power_on_do = self.do_bits
            else:
                self.safe_do = self.do_bits
            return self._ok()
        if p.digital == AIDIO and body == "4":
            return self._ok(f"{self.power_on_do:02X}{self.safe_do:02X}")
        if p.digital == AIDIO and body[:1] == "5" and len(body) == 5:
            self.power_on_do, self.safe_do = (
                int(body[1:3], 16) & _mask(p.do),
                int(body[3:5], 16) & _mask(p.do),
            )
            return self._ok()
        if p.ao and body[:1] == "5":  # ~AA5 / ~AA5N: current output becomes the safe value
            for ch in self._ao_channels(body[1:]):
                self.safe_ao[ch] = self.ao_raw[ch]
            return self._ok()
        return None

    def _percent(self, body: str, now: float) -> str | None:
        """``%AANNTTCCFF``: new address, type code, baud code, format."""
        if len(body) != 8:
            return None
        new_address, type_code, baud, fmt = (int(body[i : i + 2], 16) for i in range(0, 8, 2))
        if self.table is not None and self.table.get(type_code) is None:
            return self._refuse()
        if self.table is None and type_code != DIO_TYPE_CODE:
            return self._refuse()
        self.address, self.type_code, self.baud_code = new_address, type_code, baud
        self.data_format, self.checksum = DataFormat(fmt & 0x03), bool(fmt & 0x40)
        return f"!{new_address:02X}"

    # -- engineering-unit helpers for tests and wiring ---------------------------------------
    def set_ai_engineering(self, channel: int, value: float) -> None:
        assert self.range is not None
        self.ai_raw[channel] = engineering_to_raw(value, self.range)[0]

    def ao_engineering(self, channel: int) -> float:
        assert self.range is not None
        return raw_to_engineering(self.ao_raw[channel], self.range)


@dataclass
class Fault:
    """Fault injection for one module (or the whole line when address is None)."""

    kind: str  # silence | bad-checksum | garbage | delay | truncate | wrong-address
    address: int | None = None
    delay: float = 0.0
    count: int | None = None  # how many replies to spoil; None = until cleared


@dataclass
class Wire:
    """An output wired to an input, like the manuals' demo benches."""

    source: tuple[int, str, int]  # (address, 'do'|'ao', index)
    target: tuple[int, str, int]  # (address, 'di'|'ai', index)
    invert: bool = False


@dataclass
class SimBus:
    """A line of simulated modules: feed it bytes, get replies (with a delay) back."""

    modules: dict[int, SimModule] = field(default_factory=dict)
    checksum: bool = False
    faults: list[Fault] = field(default_factory=list)
    wires: list[Wire] = field(default_factory=list)
    _buffer: bytearray = field(default_factory=bytearray)
    dropped: int = 0

    def add(self, module: SimModule) -> SimModule:
        module.checksum = self.checksum
        self.modules[module.address] = module
        return module

    def feed(self, data: bytes, now: float) -> list[tuple[bytes, float]]:
        """Bytes from the master -> [(reply bytes, delay in s)]."""
        self._buffer += data
        replies = []
        while (end := self._buffer.find(codec.CR)) >= 0:
            raw = bytes(self._buffer[: end + 1])
            del self._buffer[: end + 1]
            reply = self.command(raw, now)
            if reply is not None:
                replies.append(reply)
        if len(self._buffer) > 256:  # a CR never came: line noise
            self._buffer.clear()
            self.dropped += 1
        return replies

    def _checksum_of(self, raw: bytes) -> bool:
        """The checksum setting of the module a frame addresses (each module has its own, as
        on a real line; the bus's for a broadcast or an unknown address)."""
        try:
            module = self.modules.get(int(raw[1:3], 16))
        except ValueError:
            module = None
        return self.checksum if module is None else module.checksum

    def command(self, raw: bytes, now: float) -> tuple[bytes, float] | None:
        self.tick(now)
        checksum = self._checksum_of(raw)
        try:
            text = codec.unframe(raw, checksum)
        except CommError:
            self.dropped += 1
            return None  # bad checksum or noise: silence
        if text == codec.HOST_OK:
            for each in self.modules.values():
                each.host_ok(now)
            return None
        if len(text) < 3 or text[0] not in codec.COMMAND_LEADS:
            self.dropped += 1
            return None
        module: SimModule | None
        try:
            module = self.modules.get(int(text[1:3], 16))
        except ValueError:
            module = None
        if module is None:
            return None
        old_address = module.address
        reply = module.handle(text, now)
        if module.address != old_address:  # %AANNTTCCFF moved it
            self.modules.pop(old_address, None)
            self.modules[module.address] = module
        self.propagate()
        if reply is None:
            return None
        return self._spoil(module.address, codec.frame(reply, checksum))

    def _spoil(self, address: int, frame: bytes) -> tuple[bytes, float] | None:
        for fault in list(self.faults):
            if fault.address not in (None, address):
                continue
            if fault.kind == "wrong-address" and not (frame[:1] in (b"!", b"?") and len(frame) > 3):
                continue  # '>' replies carry no address
            if fault.count is not None:
                fault.count -= 1
                if fault.count <= 0:
                    self.faults.remove(fault)
            if fault.kind == "silence":
                return None
            if fault.kind == "delay":
                return frame, fault.delay
            if fault.kind == "bad-checksum":
                return (
                    frame[:-3] + (b"00" if frame[-3:-1] != b"00" else b"01") + codec.CR
                    if self.checksum
                    else frame[:1] + b"\x7f" + frame[2:]
                ), 0.0
            if fault.kind == "garbage":
                return b"\x00\xff#%&\r", 0.0
            if fault.kind == "truncate":
                return frame[: max(1, len(frame) // 2)], 0.0
            if fault.kind == "wrong-address":
                other = f"{(address + 1) & 0xFF:02X}".encode()
                text = frame[:1] + other + frame[3 : -1 - (2 if self.checksum else 0)]
                return codec.frame(text.decode("ascii"), self.checksum), 0.0
        return frame, 0.0

    def tick(self, now: float) -> list[int]:
        """Fire due host-watchdog timeouts; returns the addresses that timed out now."""
        fired = [m.address for m in self.modules.values() if m.tick(now)]
        if fired:
            self.propagate()
        return fired

    def propagate(self) -> None:
        """Copy wired outputs to their inputs."""
        for wire in self.wires:
            src, dst = self.modules.get(wire.source[0]), self.modules.get(wire.target[0])
            if src is None or dst is None:
                continue
            if wire.source[1] == "do":
                bit = bool(src.do_bits >> wire.source[2] & 1) != wire.invert
                dst.di_bits = (
                    dst.di_bits | 1 << wire.target[2]
                    if bit
                    else dst.di_bits & ~(1 << wire.target[2])
                )
            elif src.range is not None and dst.range is not None:
                dst.set_ai_engineering(wire.target[2], src.ao_engineering(wire.source[2]))

    def animate(self, now: float) -> None:
        """Visible, slow changes: a walking bit on DI, a sine on AI."""
        step = int(now)
        for module in self.modules.values():
            if module.profile.di:
                module.di_bits = 1 << (step % module.profile.di)
            rng = module.range
            if module.profile.ai and rng is not None:
                for ch in range(module.profile.ai):
                    span = (rng.fmax - rng.fmin) / 2
                    module.set_ai_engineering(
                        ch, rng.fmin + span + 0.8 * span * math.sin(now / 5 + ch)
                    )
