"""Our thin adapter over pymodbus's async RTU client (pymodbus pinned to 3.16.1).

What it adds to pymodbus:

* the RTU inter-frame silence (3.5 character times, 1.75 ms above 19200 baud) kept
  before every request; pymodbus does not enforce it;
* precise failure kinds: pymodbus reports a reply with a bad CRC, a reply from another
  unit and no reply at all as the same timeout. The adapter records the bytes that
  arrived (pymodbus's ``trace_packet`` hook) and :func:`codec.diagnose` classifies them;
* replies checked against the request (function, quantity), exception responses turned
  into :class:`ModbusExceptionError` with the code;
* Modbus statistics per line (requests by function, errors by kind, exception codes).

Retries are the line scheduler's business (``retries`` of the back), so pymodbus runs
with ``retries=0``; its own error log lines are silenced (the scheduler logs once per
burst).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import serial
from pymodbus import FramerType
from pymodbus.client import AsyncModbusSerialClient
from pymodbus.exceptions import ConnectionException, ModbusException
from pymodbus.pdu import ModbusPDU

from fieldgate.health import ErrorKind
from fieldgate.plugin import PluginStartError
from fieldgate.polling import CommError, LineLost
from fieldgate.serial_link import char_time

from .codec import Function, diagnose

if TYPE_CHECKING:
    from .config import ModbusBackConfig

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


def inter_frame_gap(baudrate: int, bits_per_char: int = 11) -> float:
    """t3.5 of the Modbus serial line spec: 3.5 characters, fixed 1.75 ms above 19200 baud."""
    return 0.00175 if baudrate > 19200 else 3.5 * char_time(baudrate, bits_per_char)


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


class ModbusLink:
    """One RS-485 line spoken to through pymodbus. One transaction at a time (the scheduler's rule)."""

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
    ):
        self.port = port
        self.timeout = timeout
        self.gap = inter_frame_gap(baudrate) if inter_frame is None else inter_frame
        self.stats = ModbusStats()
        self._settings: dict[str, Any] = {
            "baudrate": baudrate,
            "bytesize": bytesize,
            "parity": parity,
            "stopbits": stopbits,
        }
        self._client: AsyncModbusSerialClient | None = None
        self._rx = bytearray()
        self._rx_last = b""
        self._quiet_since = 0.0

    @classmethod
    def from_config(cls, config: ModbusBackConfig) -> ModbusLink:
        gap = None if config.inter_frame_ms is None else config.inter_frame_ms / 1000
        return cls(
            config.port,
            baudrate=config.baudrate,
            bytesize=config.bytesize,
            parity=config.parity,
            stopbits=config.stopbits,
            timeout=config.timeout_ms / 1000,
            inter_frame=gap,
        )

    async def open(self) -> None:
        _check_port(self.port, self._settings)
        self._client = AsyncModbusSerialClient(
            self.port,
            framer=FramerType.RTU,
            timeout=self.timeout,
            retries=0,
            reconnect_delay=0,
            trace_packet=self._trace,
            **self._settings,
        )
        if not await self._client.connect():
            raise PluginStartError(f"cannot open serial port {self.port}")

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if not sending:
            # pymodbus passes its whole receive buffer each time; keep only what is new
            new = (
                data[len(self._rx_last) :]
                if self._rx_last and data.startswith(self._rx_last)
                else data
            )
            self._rx += new
            self._rx_last = data
        return data

    # -- transactions -----------------------------------------------------------
    @property
    def _open_client(self) -> AsyncModbusSerialClient:
        if self._client is None:
            raise CommError(ErrorKind.IO, "the port is not open")
        return self._client

    async def read_bits(self, unit: int, function: int, address: int, count: int) -> list[bool]:
        client = self._open_client
        call = client.read_coils if function == Function.READ_COILS else client.read_discrete_inputs
        reply = await self._transact(
            unit, function, lambda: call(address, count=count, device_id=unit)
        )
        bits = list(getattr(reply, "bits", []))
        if len(bits) < count:
            raise self._bad(function, f"reply carries {len(bits)} bits, {count} asked")
        return bits[:count]

    async def read_registers(self, unit: int, function: int, address: int, count: int) -> list[int]:
        client = self._open_client
        call = (
            client.read_holding_registers
            if function == Function.READ_HOLDING_REGISTERS
            else client.read_input_registers
        )
        reply = await self._transact(
            unit, function, lambda: call(address, count=count, device_id=unit)
        )
        registers = list(getattr(reply, "registers", []))
        if len(registers) != count:
            raise self._bad(function, f"reply carries {len(registers)} registers, {count} asked")
        return registers

    async def write(
        self, unit: int, function: int, address: int, values: list[bool] | list[int]
    ) -> None:
        c = self._open_client

        def request() -> Awaitable[ModbusPDU]:
            if function == Function.WRITE_SINGLE_COIL:
                return c.write_coil(address, bool(values[0]), device_id=unit)
            if function == Function.WRITE_SINGLE_REGISTER:
                return c.write_register(address, values[0], device_id=unit)
            if function == Function.WRITE_MULTIPLE_COILS:
                return c.write_coils(address, [bool(v) for v in values], device_id=unit)
            return c.write_registers(address, list(values), device_id=unit)

        reply = await self._transact(unit, function, request)
        if getattr(reply, "address", address) != address:
            raise self._bad(function, f"write echo names address {reply.address}, not {address}")

    async def _transact(
        self, unit: int, function: int, request: Callable[[], Awaitable[ModbusPDU | None]]
    ) -> ModbusPDU:
        """Run one pymodbus request with t3.5 silence before it; classify failures."""
        if self._client is None:
            raise CommError(ErrorKind.IO, "the port is not open")
        if not self._client.connected:  # pymodbus saw the port fail (read EIO, hang-up)
            raise self._lost("the port failed")
        wait = self._quiet_since + self.gap - time.monotonic()
        if wait > 0:
            await asyncio.sleep(wait)
        self._rx.clear()
        self._rx_last = b""
        self.stats.requests[function] += 1
        started = time.monotonic()
        try:
            reply: ModbusPDU | None = await request()  # (None: pymodbus gave up without a reply)
        except ConnectionException as exc:
            raise self._lost(f"port failed: {exc}") from None
        except ModbusException:
            if not self._client.connected:  # the port failed while we waited
                raise self._lost("the port failed during the request") from None
            kind = diagnose(unit, function, bytes(self._rx))
            raise self._fail(kind, _describe(kind, bytes(self._rx))) from None
        except (OSError, serial.SerialException) as exc:
            raise self._lost(f"port failed: {exc}") from None
        finally:
            self._quiet_since = time.monotonic()
        self.stats.last_rtt = self._quiet_since - started
        if reply is None:
            if not self._client.connected:
                raise self._lost("the port failed during the request")
            raise self._fail(ErrorKind.TIMEOUT, "no reply")
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

    def _lost(self, text: str) -> LineLost:
        self.stats.errors[ErrorKind.IO] += 1
        return LineLost(f"{self.port}: {text}")

    def _bad(self, function: int, text: str) -> CommError:
        return self._fail(ErrorKind.GARBAGE, f"FC{function}: {text}")


def _describe(kind: ErrorKind, data: bytes) -> str:
    if kind is ErrorKind.TIMEOUT:
        return "no reply"
    return f"{kind}: received {data[:32].hex(' ')}{' ...' if len(data) > 32 else ''}"


def _check_port(port: str, settings: dict[str, Any]) -> None:
    """Open and close the port once, so a missing device gives a one-line cause."""
    try:
        serial.serial_for_url(port, **settings, timeout=0).close()
    except serial.SerialException as exc:
        text = str(exc)
        cause = (
            "no such device"
            if "No such file" in text or exc.errno == 2
            else "permission denied"
            if exc.errno == 13
            else text
        )
        raise PluginStartError(f"cannot open serial port {port}: {cause}") from None
    except ValueError as exc:
        raise PluginStartError(f"invalid serial settings for {port}: {exc}") from None
