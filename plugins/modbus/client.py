"""The Modbus RTU master's link: one transaction at a time on an RS-485 line.

The wire timing is core's (``fieldgate.serial_timing``, shared with the DCON back):
``timeout_ms`` is the *response timeout* until the first byte of the reply, an inter-byte
timeout ends a broken frame, a good frame ends as soon as its length is complete (known
from its third byte), the line must fall silent after a failure before the next request,
and an echo of the request (``echo: true|auto``) is compared and dropped, never taken for
the reply. pymodbus's own client cannot do this: it has one timeout for the whole reply
(a 266 ms reply at 9600 baud with ``timeout_ms: 200`` was cut, the next request went out
into it and both modules went offline) and its RTU framer takes the echo of an FC5/FC6
write for the answer. So the link does the I/O on :class:`fieldgate.serial_link.AsyncSerial`
and pymodbus (pinned 3.16.1) decodes the reply PDU (``DecodePDU``); our codec builds the
request ADU and checks the frame (CRC, unit).

What else it adds:

* the RTU inter-frame silence (3.5 character times, 1.75 ms above 19200 baud) kept
  before every request;
* precise failure kinds: :func:`codec.diagnose` classifies the bytes that arrived
  (timeout, CRC, wrong address, garbage);
* replies checked against the request (function, quantity), exception responses turned
  into :class:`ModbusExceptionError` with the code;
* Modbus statistics per line (requests by function, errors by kind, exception codes).

Retries are the line scheduler's business (``retries`` of the back).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from pymodbus.pdu import DecodePDU

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError, LineLost
from fieldgate.serial_link import AsyncSerial
from fieldgate.serial_timing import EchoSetting, EchoState, Exchange, LineTiming, Outcome, Result

from .codec import Function, Request, crc_ok, diagnose, inter_frame_gap, response_length

__all__ = ["ModbusExceptionError", "ModbusLink", "ModbusStats", "inter_frame_gap"]

log = logging.getLogger("fieldgate.modbus")
logging.getLogger("pymodbus").setLevel(
    logging.CRITICAL
)  # we log failures ourselves, once per burst


class ModbusExceptionError(CommError):
    """The module answered with a Modbus exception response."""

    def __init__(self, function: int, code: int):
        super().__init__(ErrorKind.EXCEPTION, f"exception code {code} for function {function}")
        self.function = function
        self.code = code


@dataclass
class ModbusStats:
    requests: Counter[int] = field(default_factory=Counter)  # by function code
    errors: Counter[ErrorKind] = field(default_factory=Counter)
    exception_codes: Counter[int] = field(default_factory=Counter)
    last_rtt: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "requests": {f"fc{k}": v for k, v in sorted(self.requests.items())},
            "errors": {str(k): v for k, v in self.errors.items()},
            "exception_codes": dict(sorted(self.exception_codes.items())),
            "last_rtt_ms": None if self.last_rtt is None else round(self.last_rtt * 1000, 3),
        }


class Transactions:
    """What a module asks of its link (reads, writes) on top of one ``_transact``, and the
    reply checks every link shares: pymodbus decodes the PDU, exception responses become
    :class:`ModbusExceptionError`, a reply that does not answer the request is garbage."""

    def __init__(self) -> None:
        self.stats = ModbusStats()
        self._decoder = DecodePDU(False)

    async def _transact(self, request: Request) -> Any:
        raise NotImplementedError

    async def read_bits(self, unit: int, function: int, address: int, count: int) -> list[bool]:
        reply = await self._transact(Request(unit, function, address, count))
        bits = list(getattr(reply, "bits", []))
        if len(bits) < count:
            raise self._bad(function, f"reply carries {len(bits)} bits, {count} asked")
        return bits[:count]

    async def read_registers(self, unit: int, function: int, address: int, count: int) -> list[int]:
        reply = await self._transact(Request(unit, function, address, count))
        registers = list(getattr(reply, "registers", []))
        if len(registers) != count:
            raise self._bad(function, f"reply carries {len(registers)} registers, {count} asked")
        return registers

    async def write(self, unit: int, function: int, address: int, values: list[Any]) -> None:
        if function in (Function.WRITE_SINGLE_COIL, Function.WRITE_MULTIPLE_COILS):
            values = [bool(v) for v in values]
        count = len(values) if function in (15, 16) else 1
        reply = await self._transact(Request(unit, function, address, count, tuple(values)))
        if getattr(reply, "address", address) != address:
            raise self._bad(function, f"write echo names address {reply.address}, not {address}")

    def _decoded(self, function: int, pdu: bytes, frame: bytes) -> Any:
        """The reply PDU decoded and checked (garbage, an exception, another function);
        ``frame``: what arrived, for the message."""
        reply = self._decoder.decode(pdu)
        if reply is None:
            raise self._fail(ErrorKind.GARBAGE, _describe(ErrorKind.GARBAGE, frame))
        if reply.isError():
            code = getattr(reply, "exception_code", 0)
            self.stats.errors[ErrorKind.EXCEPTION] += 1
            self.stats.exception_codes[code] += 1
            raise ModbusExceptionError(function, code)
        if reply.function_code != function:
            raise self._bad(function, f"reply has function {reply.function_code}")
        return reply

    def _fail(self, kind: ErrorKind, text: str) -> CommError:
        self.stats.errors[kind] += 1
        return CommError(kind, text)

    def _bad(self, function: int, text: str) -> CommError:
        return self._fail(ErrorKind.GARBAGE, f"FC{function}: {text}")


class ModbusLink(Transactions):
    """One RS-485 line of Modbus RTU modules. One transaction at a time (the scheduler's rule)."""

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 9600,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: int = 1,
        timeout: float = 0.2,
        inter_frame: float | None = None,
        byte_timeout: float | None = None,
        echo: EchoSetting = "auto",
    ):
        self.port = port
        self.timeout = timeout
        self.gap = inter_frame_gap(baudrate) if inter_frame is None else inter_frame
        bits = 1 + bytesize + (0 if parity == "N" else 1) + stopbits
        self.timing = LineTiming.of(
            baudrate, timeout * 1000, None if byte_timeout is None else byte_timeout * 1000, bits
        )
        self.echo = EchoState(echo)
        super().__init__()
        self._settings: dict[str, Any] = {
            "baudrate": baudrate,
            "bytesize": bytesize,
            "parity": parity,
            "stopbits": stopbits,
        }
        self.serial: AsyncSerial | None = None
        self._quiet_since = 0.0
        self._quiet_since_at = 0.0  # the same on the real clock (AsyncSerial.keep_silence)
        self._after_failure = False

    @classmethod
    def from_config(cls, config: Any) -> ModbusLink:
        gap = None if config.inter_frame_ms is None else config.inter_frame_ms / 1000
        return cls(
            config.port,
            baudrate=config.baudrate,
            bytesize=config.bytesize,
            parity=config.parity,
            stopbits=config.stopbits,
            timeout=config.timeout_ms / 1000,
            inter_frame=gap,
            byte_timeout=None if config.byte_timeout_ms is None else config.byte_timeout_ms / 1000,
            echo=config.echo,
        )

    async def open(self) -> None:
        """Open the port (again, after a loss); PluginStartError with a one-line cause."""
        self.close()
        self.serial = await AsyncSerial.open(self.port, **self._settings)
        self.echo.reset()
        self._after_failure = True  # whatever the line carries now is not ours

    def close(self) -> None:
        if self.serial is not None:
            self.serial.close_now()
            self.serial = None

    # -- transactions -----------------------------------------------------------
    async def _transact(self, request: Request) -> Any:
        """One request and its reply, timed as fieldgate.serial_timing says; failures classified."""
        serial = self.serial
        if serial is None:
            raise CommError(ErrorKind.IO, "the port is not open")
        unit, function = request.unit, request.function
        adu = request.encode()
        try:
            await self._quiet_line(serial)
            self.stats.requests[function] += 1
            exchange = Exchange(
                adu,
                self.timing,
                lambda data: _frame_end(function, data),
                echo=self.echo.expect,
                assume=self.echo.assume,
                ambiguous=function in (Function.WRITE_SINGLE_COIL, Function.WRITE_SINGLE_REGISTER),
            )
            started = serial.now
            outcome = await serial.exchange(adu, exchange)
        except LineLost:
            self.stats.errors[ErrorKind.IO] += 1
            raise
        self._quiet_since = serial.now
        self._quiet_since_at = time.monotonic()
        if self.echo.learn(outcome):
            log.info("%s: %s", self.port, self.echo.describe())
        if outcome.result is not Result.REPLY or outcome.rest:
            self._after_failure = True  # a late or unexpected byte may still come
        if outcome.result is not Result.REPLY:
            raise self._failed(unit, function, outcome)
        self.stats.last_rtt = self._quiet_since - started
        frame = outcome.frame
        if not crc_ok(frame) or frame[0] != unit:
            self._after_failure = True
            kind = diagnose(unit, function, frame)
            raise self._fail(kind, _describe(kind, frame))
        try:
            return self._decoded(function, frame[1:-2], frame)
        except CommError as exc:
            if exc.kind is ErrorKind.GARBAGE and not isinstance(exc, ModbusExceptionError):
                self._after_failure = True
            raise

    async def _quiet_line(self, serial: AsyncSerial) -> None:
        """Before a request: after a failure, line silence; always the t3.5 inter-frame gap."""
        if self._after_failure:
            self._after_failure = False
            await serial.wait_silence(self.timing.silence, self.timing.silence_limit)
        await serial.keep_silence(self.gap, self._quiet_since_at)

    def _failed(self, unit: int, function: int, outcome: Outcome) -> CommError:
        if outcome.result is Result.TIMEOUT:
            return self._fail(ErrorKind.TIMEOUT, "no reply")
        if outcome.result is Result.TRUNCATED:
            kind = diagnose(unit, function, outcome.frame)
            return self._fail(kind, _describe(kind, outcome.frame))
        return self._fail(ErrorKind.GARBAGE, outcome.describe())


def _frame_end(function: int, data: bytes) -> int | None:
    """Length of the reply frame to ``function`` at the start of ``data``, once known
    (from its third byte for a read); anything else ends on the inter-byte timeout."""
    return response_length(function, data)


def _describe(kind: ErrorKind, data: bytes) -> str:
    if kind is ErrorKind.TIMEOUT:
        return "no reply"
    return f"{kind}: received {data[:32].hex(' ')}{' ...' if len(data) > 32 else ''}"
