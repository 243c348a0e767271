"""DCON framing, checksum and reply parsing (sans-I/O).

A DCON frame is printable ASCII ended by CR::

    command:  leading char ($ # @ % ~) + AA (2 hex address) + command [+ CHK] + CR
    reply:    leading char (! ? >)     [+ AA]               + data    [+ CHK] + CR

The optional checksum is the sum of every character before it (the CR excluded),
modulo 256, as two upper-case hex digits (``$012`` -> ``$012B7``). It is enabled for
a whole line: modules with checksum on ignore frames without one, and we reject
replies whose checksum is wrong.

Only the addressed module answers; a syntax error, a wrong checksum or an unknown
address gets **no answer at all**, so a timeout is the ordinary failure. Every
parse failure raises :class:`~fieldgate.polling.CommError` with the kind the
health model counts: CRC (bad checksum), GARBAGE (not a DCON frame, truncated),
WRONG_ADDRESS (another module answered), EXCEPTION (``?``: command refused),
WATCHDOG (``!`` to an output write: the module sits in host-watchdog timeout).
"""

from __future__ import annotations

from dataclasses import dataclass

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError

CR = b"\r"
COMMAND_LEADS = "$#@%~"
REPLY_LEADS = "!?>"
HOST_OK = "~**"  # broadcast, no reply


def checksum(text: str) -> str:
    """The two upper-case hex digits of the DCON checksum of ``text``."""
    return f"{sum(text.encode('ascii')) & 0xFF:02X}"


def frame(text: str, use_checksum: bool) -> bytes:
    """A command (or reply) ready for the wire: text [+ checksum] + CR."""
    return (text + (checksum(text) if use_checksum else "")).encode("ascii") + CR


def unframe(raw: bytes, use_checksum: bool) -> str:
    """The text of one received frame, checksum verified and removed.

    ``raw`` is what arrived up to and including the CR. Raises CommError GARBAGE for
    anything that is not printable ASCII ended by CR, CRC for a wrong checksum.
    """
    if not raw.endswith(CR):
        raise CommError(ErrorKind.GARBAGE, f"frame not ended by CR: {raw[:40]!r}")
    body = raw[:-1]
    if not body or any(b < 0x20 or b > 0x7E for b in body):
        raise CommError(ErrorKind.GARBAGE, f"not a DCON frame: {raw[:40]!r}")
    text = body.decode("ascii")
    if use_checksum:
        if len(text) < 3:
            raise CommError(ErrorKind.GARBAGE, f"frame too short for a checksum: {text!r}")
        text, received = text[:-2], text[-2:]
        if received.upper() != checksum(text) or not _is_hex(received):
            raise CommError(
                ErrorKind.CRC, f"bad checksum in {text + received!r}: expected {checksum(text)}"
            )
    return text


def _is_hex(text: str) -> bool:
    return bool(text) and all(c in "0123456789ABCDEFabcdef" for c in text)


def hex2(value: int) -> str:
    return f"{value & 0xFF:02X}"


# -- commands -------------------------------------------------------------------
def command(lead: str, address: int, body: str = "") -> str:
    """``lead`` + AA + body, e.g. command('$', 1, '2') == '$012'."""
    if lead not in COMMAND_LEADS:
        raise ValueError(f"not a DCON command lead: {lead!r}")
    if not 0 <= address <= 0xFF:
        raise ValueError(f"DCON address {address} outside 0..255")
    return f"{lead}{address:02X}{body}"


def set_do_group(address: int, group: int, value: int) -> str:
    """``#AABBDD``: write one output group (BB = 00, 0A or 0B) with DD."""
    return command("#", address, f"{group:02X}{value & 0xFF:02X}")


def set_do_channel(address: int, channel: int, on: bool) -> str:
    """``#AA1cDD`` (channel 0-7) / ``#AABcDD`` (8-15): set or clear one output."""
    if not 0 <= channel <= 15:
        raise ValueError(f"#AABBDD addresses channels 0-15, not {channel}")
    bb = f"1{channel:X}" if channel < 8 else f"B{channel - 8:X}"
    return command("#", address, f"{bb}{'01' if on else '00'}")


def watchdog_setup(address: int, enabled: bool, timeout_ms: int) -> str:
    """``~AA3EVV``: E = 1/0, VV = timeout in 0.1 s (01..FF)."""
    tenths = max(1, min(0xFF, round(timeout_ms / 100)))
    return command("~", address, f"3{1 if enabled else 0}{tenths:02X}")


# -- replies --------------------------------------------------------------------
@dataclass(frozen=True)
class Reply:
    lead: str  # '!', '?' or '>'
    text: str  # everything after the lead


def parse(text: str) -> Reply:
    if not text or text[0] not in REPLY_LEADS:
        raise CommError(ErrorKind.GARBAGE, f"not a DCON reply: {text[:40]!r}")
    return Reply(text[0], text[1:])


def addressed(text: str, address: int) -> str:
    """Data of an ``!AA(data)`` reply; ``?AA`` -> EXCEPTION, other AA -> WRONG_ADDRESS."""
    reply = parse(text)
    aa = reply.text[:2]
    if len(aa) < 2 or not _is_hex(aa):
        raise CommError(ErrorKind.GARBAGE, f"reply without address: {text!r}")
    if int(aa, 16) != address:
        raise CommError(
            ErrorKind.WRONG_ADDRESS, f"reply from {aa} to a command for {address:02X}: {text!r}"
        )
    if reply.lead == "?":
        raise CommError(ErrorKind.EXCEPTION, f"module {address:02X} refused the command ({text!r})")
    if reply.lead != "!":
        raise CommError(ErrorKind.GARBAGE, f"expected '!{address:02X}...', got {text!r}")
    return reply.text[2:]


def data(text: str, address: int | None = None) -> str:
    """Data of a ``>(data)`` reply (``#AA`` and ``@AA`` reads); ``?AA`` -> EXCEPTION."""
    return _unaddressed(text, ">", address)


def status_data(text: str, address: int | None = None) -> str:
    """Data of a ``!(data)`` reply without address (``$AA6`` of digital modules)."""
    return _unaddressed(text, "!", address)


def _unaddressed(text: str, lead: str, address: int | None) -> str:
    reply = parse(text)
    if reply.lead == "?":
        _check_refusal_address(reply, address)
        raise CommError(ErrorKind.EXCEPTION, f"module refused the command ({text!r})")
    if reply.lead != lead:
        raise CommError(ErrorKind.GARBAGE, f"expected '{lead}(data)', got {text!r}")
    return reply.text


def write_ack(text: str) -> None:
    """Reply to an output write: ``>`` done, ``?`` refused, ``!`` ignored (host-watchdog timeout)."""
    reply = parse(text)
    if reply.lead == ">" and not reply.text:
        return
    if reply.lead == "!" and not reply.text:
        raise CommError(ErrorKind.WATCHDOG, "output write ignored: module in host-watchdog timeout")
    if reply.lead == "?":
        raise CommError(ErrorKind.EXCEPTION, f"output write refused ({text!r})")
    raise CommError(ErrorKind.GARBAGE, f"unexpected reply to an output write: {text!r}")


def _check_refusal_address(reply: Reply, address: int | None) -> None:
    aa = reply.text[:2]
    if address is not None and len(aa) == 2 and _is_hex(aa) and int(aa, 16) != address:
        raise CommError(
            ErrorKind.WRONG_ADDRESS, f"refusal from {aa} to a command for {address:02X}"
        )


def hex_field(text: str, what: str) -> int:
    if not _is_hex(text):
        raise CommError(ErrorKind.GARBAGE, f"{what}: expected hex digits, got {text!r}")
    return int(text, 16)


@dataclass(frozen=True)
class ModuleConfigReply:
    """``$AA2`` -> ``!AATTCCFF``."""

    type_code: int
    baud_code: int
    format_byte: int

    @property
    def data_format(self) -> int:
        return self.format_byte & 0x03

    @property
    def checksum(self) -> bool:
        return bool(self.format_byte & 0x40)


def parse_config(text: str, address: int) -> ModuleConfigReply:
    body = addressed(text, address)
    if len(body) != 6:
        raise CommError(
            ErrorKind.GARBAGE, f"$AA2 reply has {len(body)} data characters, expected 6: {text!r}"
        )
    return ModuleConfigReply(
        hex_field(body[0:2], "type code"),
        hex_field(body[2:4], "baud code"),
        hex_field(body[4:6], "format"),
    )


BAUD_CODES = {
    0x03: 1200,
    0x04: 2400,
    0x05: 4800,
    0x06: 9600,
    0x07: 19200,
    0x08: 38400,
    0x09: 57600,
    0x0A: 115200,
}
BAUD_TO_CODE = {v: k for k, v in BAUD_CODES.items()}
