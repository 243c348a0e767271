"""Simulated Modbus RTU modules on a serial port (or one end of a pseudo-terminal pair).

Our own RTU responder, not pymodbus's server: pymodbus 3.16.1 answers requests for unit
ids it does not serve (exception 4, even with ``ignore_missing_devices``), which no real
multi-drop line does, and fault injection needs control of every byte. The responder
(:class:`RtuResponder`) is sans-I/O; :class:`ModbusSimulator` is its serial shell.

* Every module of a back config is served with the same points as the back (so the same
  model presets); addresses outside them answer exception 2 (illegal data address).
* ``set_input`` / ``get_output`` by channel id; ``inject`` faults per module: no answer,
  bad CRC, exception code, delay, garbage, truncated frame, reply from a wrong address.
* ``animate=True`` makes inputs move (DI count in binary, AI ramp up and down) and wires
  outputs to inputs like the I-7232D demo bench: DO of a module with outputs to the DI of
  an input-only module (M-7055D -> M-7052D), AO to an AI-only module (M-7024 -> M-7017R).
  A wired input moves on its own until the gateway first writes to the module that
  drives it, then follows that output, so a user sees the loop through the gateway.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from fieldgate.image import DataType, Kind, Value, integer_range
from fieldgate.plugin import Simulator
from fieldgate.serial_link import PortServer, cancel_task, char_time

from . import values as regvalues
from .codec import (
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
    ExceptionCode,
    Request,
    crc_ok,
    exception_response,
    parse_request,
    read_bits_response,
    read_registers_response,
    request_length,
    write_response,
)
from .codec import (
    frame as rtu_frame,
)
from .config import ModbusBackConfig
from .points import Point, Table

log = logging.getLogger("fieldgate.modbus.simulator")

MAX_ADU = 256
FAULT_KINDS = ("no_answer", "crc", "exception", "delay", "garbage", "truncate", "wrong_address")

_TABLE_OF = {
    1: Table.COILS,
    2: Table.DISCRETE_INPUTS,
    3: Table.HOLDING_REGISTERS,
    4: Table.INPUT_REGISTERS,
    5: Table.COILS,
    6: Table.HOLDING_REGISTERS,
    15: Table.COILS,
    16: Table.HOLDING_REGISTERS,
}


@dataclass
class Fault:
    """A misbehaviour of one simulated module.

    ``count`` replies are affected (None: until cleared); ``table``/``address`` limit it
    to requests that touch that address.
    """

    kind: str
    count: int | None = None
    code: int = ExceptionCode.SERVER_DEVICE_FAILURE
    delay: float = 0.5
    table: Table | None = None
    address: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault '{self.kind}'; one of: {', '.join(FAULT_KINDS)}")

    def matches(self, request: Request) -> bool:
        if self.table is not None and _TABLE_OF.get(request.function) is not self.table:
            return False
        return (
            self.address is None
            or request.address <= self.address < request.address + request.count
        )


@dataclass
class Reply:
    frame: bytes
    delay: float = 0.0


class SimModule:
    """The memory of one module: sparse tables holding exactly the cells its points use."""

    def __init__(self, address: int, points: list[Point]):
        self.address = address
        self.points = points
        self.tables: dict[Table, dict[int, int | bool]] = {t: {} for t in Table}
        self.faults: list[Fault] = []
        self.on_write: Callable[[SimModule], None] | None = None
        for p in points:
            for a in range(p.address, p.end):
                self.tables[p.table][a] = False if p.table.is_bits else 0

    # -- values by point ------------------------------------------------------------
    def set_point(self, p: Point, value: Value) -> None:
        """Set a point to a raw value (as the device holds it: before any scaling)."""
        cells = self.tables[p.table]
        if p.table.is_bits:
            cells[p.address] = bool(value)
        elif p.bit is not None:
            cells[p.address] = regvalues.set_field(int(cells[p.address]), p.bit, p.bits, value)
        else:
            for i, word in enumerate(regvalues.encode(p.dtype, value, p.order, p.length)):
                cells[p.address + i] = word

    def get_point(self, p: Point) -> Value:
        """A point's raw value (before any scaling)."""
        cells = self.tables[p.table]
        if p.table.is_bits:
            return cells[p.address]
        if p.bit is not None:
            return regvalues.get_field(int(cells[p.address]), p.bit, p.bits)
        return regvalues.decode(
            p.dtype, [int(cells[p.address + i]) for i in range(p.width)], p.order, p.length
        )

    # -- requests -------------------------------------------------------------------
    def handle(self, req: Request) -> bytes:
        fc = req.function
        table = _TABLE_OF.get(fc)
        if table is None:
            return exception_response(self.address, fc, ExceptionCode.ILLEGAL_FUNCTION)
        limit = {
            1: MAX_READ_BITS,
            2: MAX_READ_BITS,
            3: MAX_READ_REGISTERS,
            4: MAX_READ_REGISTERS,
            15: MAX_WRITE_BITS,
            16: MAX_WRITE_REGISTERS,
        }.get(fc, 1)
        if not 1 <= req.count <= limit:
            return exception_response(self.address, fc, ExceptionCode.ILLEGAL_DATA_VALUE)
        cells = self.tables[table]
        span = range(req.address, req.address + req.count)
        if any(a not in cells for a in span):
            return exception_response(self.address, fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
        if fc in (1, 2):
            return read_bits_response(self.address, fc, [bool(cells[a]) for a in span])
        if fc in (3, 4):
            return read_registers_response(self.address, fc, [cells[a] for a in span])
        before = {a: cells[a] for a in span}
        for a, v in zip(span, req.values, strict=True):  # the codec checks count == len(values)
            cells[a] = bool(v) if table.is_bits else v
        if not self._values_valid(
            table, span
        ):  # e.g. a float32 pair that is NaN: refused, as a module would
            cells.update(before)
            return exception_response(self.address, fc, ExceptionCode.ILLEGAL_DATA_VALUE)
        if self.on_write is not None:
            self.on_write(self)
        return write_response(req)

    def _values_valid(self, table: Table, span: range) -> bool:
        """Every point the write touched still holds a value of its type."""
        for p in self.points:
            if p.table is table and p.address < span.stop and span.start < p.end:
                try:
                    self.get_point(p)
                except ValueError:
                    return False
        return True

    def take_fault(self, req: Request) -> Fault | None:
        for fault in self.faults:
            if fault.matches(req):
                if fault.count is not None:
                    fault.count -= 1
                    if fault.count <= 0:
                        self.faults.remove(fault)
                return fault
        return None


class RtuResponder:
    """Slave side of an RTU line, sans-I/O: ``feed(bytes, now)`` returns the replies to send.

    Requests are framed by content (length from the function code); bytes that do not
    form a request with a good CRC are dropped, as is any partial frame older than the
    inter-frame ``gap``. Requests for unit ids not served get no answer at all.
    """

    def __init__(self, modules: dict[int, SimModule], gap: float = 0.05):
        self.modules = modules
        self.gap = gap
        self.buffer = bytearray()
        self.last_rx = -math.inf
        self.log: deque[Request] = deque(maxlen=1000)
        self.dropped = 0  # bad frames
        self.served = 0

    def feed(self, data: bytes, now: float) -> list[Reply]:
        if self.buffer and now - self.last_rx > self.gap:
            self.buffer.clear()  # a partial frame followed by silence is dead
            self.dropped += 1
        self.last_rx = now
        self.buffer += data
        replies = []
        while self.buffer:
            try:
                length = request_length(self.buffer)
            except ValueError:  # a function we do not know: answer it once the frame is whole
                if crc_ok(self.buffer):
                    replies.extend(self._unknown_function(bytes(self.buffer)))
                    self.buffer.clear()
                elif len(self.buffer) > MAX_ADU:
                    self._drop()
                break
            if length is None or len(self.buffer) < length:
                break
            adu = bytes(self.buffer[:length])
            del self.buffer[:length]
            if not crc_ok(adu):
                self._drop()
                break
            try:
                req = parse_request(adu)
            except ValueError:
                reply = self._malformed(adu)
                if reply is not None:
                    replies.append(reply)
                continue
            reply = self._answer(req)
            if reply is not None:
                replies.append(reply)
        return replies

    def _drop(self) -> None:
        self.buffer.clear()
        self.dropped += 1

    def _unknown_function(self, adu: bytes) -> list[Reply]:
        if adu[0] not in self.modules:
            return []
        return [Reply(exception_response(adu[0], adu[1], ExceptionCode.ILLEGAL_FUNCTION))]

    def _malformed(self, adu: bytes) -> Reply | None:
        module = self.modules.get(adu[0])
        return (
            None
            if module is None
            else Reply(exception_response(adu[0], adu[1], ExceptionCode.ILLEGAL_DATA_VALUE))
        )

    def _answer(self, req: Request) -> Reply | None:
        self.log.append(req)
        module = self.modules.get(req.unit)
        if module is None:
            return None  # not ours: a real line stays silent
        fault = module.take_fault(req)
        if fault is not None and fault.kind == "exception":
            return Reply(exception_response(req.unit, req.function, fault.code))
        self.served += 1
        frame = module.handle(req)
        if fault is None:
            return Reply(frame)
        return _distort(fault, frame)


def _distort(fault: Fault, frame: bytes) -> Reply | None:
    if fault.kind == "no_answer":
        return None
    if fault.kind == "crc":
        return Reply(frame[:-1] + bytes([frame[-1] ^ 0xFF]))
    if fault.kind == "delay":
        return Reply(frame, fault.delay)
    if fault.kind == "garbage":
        return Reply(bytes([0x55, 0xAA, 0x00, 0xFF, 0x13]))
    if fault.kind == "truncate":
        return Reply(frame[: max(2, len(frame) // 2)])
    if fault.kind == "wrong_address":
        return Reply(rtu_frame((frame[0] % 247) + 1, frame[1:-2]))
    return Reply(frame)


class ChannelSimulator(Simulator):
    """Channels of simulated modules by id, as the process image shows them (the RTU and TCP
    simulators both): ``channels`` maps an id to its module and point."""

    channels: dict[str, tuple[SimModule, Point]]

    def _lookup(self, channel_id: str) -> tuple[SimModule, Point]:
        try:
            return self.channels[channel_id]
        except KeyError:
            raise KeyError(
                f"no simulated channel {channel_id!r} (have e.g. {next(iter(self.channels), '-')})"
            ) from None

    def set_input(self, channel_id: str, value: Value) -> None:
        """An input as the process image shows it (engineering units where the channel scales):
        the module holds its raw value."""
        module, point = self._lookup(channel_id)
        if point.kind.is_output:
            raise ValueError(f"{channel_id} is an output; the gateway writes it")
        module.set_point(point, _raw(point, value))

    def get_output(self, channel_id: str) -> Value:
        """An output as the process image shows it (what the gateway wrote, converted back)."""
        module, point = self._lookup(channel_id)
        return _image_value(point, module.get_point(point))

    def get(self, channel_id: str) -> Value:
        """Any channel's current value in the simulated module (inputs too), as the image shows it."""
        module, point = self._lookup(channel_id)
        return _image_value(point, module.get_point(point))


class ModbusSimulator(ChannelSimulator):
    """The modules of one ``modbus`` back, served on ``port``."""

    def __init__(
        self,
        config: ModbusBackConfig,
        port: str,
        animate: bool = False,
        *,
        animate_period: float = 0.25,
    ):
        self.config = config
        self.port_name = port
        self.animate = animate
        self.animate_period = animate_period
        self.modules: dict[int, SimModule] = {}
        self.channels: dict[str, tuple[SimModule, Point]] = {}
        for address, points in config.points().items():
            module = SimModule(address, points)
            self.modules[address] = module
            for p in points:
                self.channels[p.channel] = (module, p)
        gap = max(
            0.02, 4 * 3.5 * char_time(config.baudrate)
        )  # four t3.5 without the fixed 1.75 ms cap
        self.responder = RtuResponder(self.modules, gap)
        self.wiring = demo_wiring(config) if animate else []
        self._source_of = {dst: src for src, dst in self.wiring}
        self._driven: set[int] = set()  # modules the gateway has written to
        for module in self.modules.values():
            module.on_write = self._propagate
        c = config
        self.server = PortServer(
            port,
            self._received,
            baudrate=c.baudrate,
            bytesize=c.bytesize,
            parity=c.parity,
            stopbits=c.stopbits,
        )
        self._task: asyncio.Task[None] | None = None
        self.output_listeners: list[Callable[[str, object], None]] = []
        self._outputs_seen = {
            cid: _image_value(p, m.get_point(p))
            for cid, (m, p) in self.channels.items()
            if p.kind.is_output
        }

    # -- life cycle -----------------------------------------------------------------
    async def start(self) -> None:
        self.server.open()
        self._propagate(None)
        if self.animate:
            self._task = asyncio.create_task(self._animate(), name=f"modbus-sim-{self.config.name}")

    async def stop(self) -> None:
        await cancel_task(self._task)
        self._task = None
        self.server.close()

    def _received(self, data: bytes, now: float) -> None:
        for reply in self.responder.feed(data, now):
            if reply.delay:
                self.server.send_later(reply.delay, reply.frame)
            else:
                self.server.send(reply.frame)

    # -- the Simulator API: set_input, get_output, get (ChannelSimulator) ---------------
    def registers(self, address: int, table: Table, start: int, count: int) -> list[int | bool]:
        """The raw cells of a module (what a Modbus client reads there)."""
        cells = self.modules[address].tables[table]
        return [cells[a] for a in range(start, start + count)]

    def inject(self, address: int, fault: Fault) -> None:
        if address not in self.modules:
            raise KeyError(f"no simulated module at address {address}")
        self.modules[address].faults.append(fault)

    def clear_faults(self, address: int | None = None) -> None:
        for a, module in self.modules.items():
            if address is None or a == address:
                module.faults.clear()

    # -- fieldgate simulate modbus: the simulator's own commands ------------------------
    def command(self, words: list[str]) -> str | None:
        """``fault ADDRESS KIND [COUNT] [code=N] [delay=S] [address=N]`` and ``clear [ADDRESS]``."""
        cmd, rest = words[0].lower(), words[1:]
        if cmd == "fault" and len(rest) >= 2:
            options = {k: v for k, _, v in (w.partition("=") for w in rest[2:] if "=" in w)}
            counts = [int(w) for w in rest[2:] if w.isdigit()]
            address = int(options["address"]) if "address" in options else None
            fault = Fault(
                rest[1],
                count=counts[0] if counts else None,
                code=int(options.get("code", 4)),
                delay=float(options.get("delay", 0.5)),
                address=address,
            )
            self.inject(int(rest[0]), fault)
            where = "" if address is None else f" on requests touching address {address}"
            return f"module {rest[0]}: {fault.kind}{where}" + (
                f" for {fault.count} replies" if fault.count else " until cleared"
            )
        if cmd == "clear":
            self.clear_faults(int(rest[0]) if rest else None)
            return "faults cleared"
        return None

    def commands_help(self) -> str:
        return (
            f"fault ADDRESS {{{'|'.join(FAULT_KINDS)}}} [COUNT] [code=N] [delay=S] [address=N]"
            " | clear [ADDRESS]"
        )

    @property
    def requests(self) -> deque[Request]:
        return self.responder.log

    # -- wiring and animation --------------------------------------------------------
    def _is_driven(self, output_channel: str) -> bool:
        return self.channels[output_channel][0].address in self._driven

    def _propagate(self, module: SimModule | None) -> None:
        if module is not None:
            self._driven.add(module.address)
        for src, dst in self.wiring:
            if not self._is_driven(src):
                continue  # until the gateway writes the outputs, their inputs animate
            src_module, src_point = self._lookup(src)
            dst_module, dst_point = self._lookup(dst)
            value = src_module.get_point(src_point)  # raw to raw, as wires carry them
            if isinstance(value, str) or dst_point.dtype is DataType.STRING:
                continue
            if dst_point.dtype.is_integer:
                low, high = integer_range(dst_point.dtype)
                if dst_point.bit is not None:
                    low, high = 0, (1 << dst_point.bits) - 1
                value = max(low, min(high, int(value)))
            elif dst_point.dtype.is_float:
                value = float(value)
            dst_module.set_point(dst_point, value)
        for cid, (module, p) in self.channels.items():
            if p.kind.is_output:
                value = _image_value(p, module.get_point(p))
                if self._outputs_seen.get(cid) != value:
                    self._outputs_seen[cid] = value
                    for listener in self.output_listeners:
                        listener(cid, value)

    async def _animate(self) -> None:
        tick = 0
        while True:
            await asyncio.sleep(self.animate_period)
            tick += 1
            for cid, (module, p) in self.channels.items():
                source = self._source_of.get(cid)
                if p.kind.is_output or (source is not None and self._is_driven(source)):
                    continue
                module.set_point(p, _animated_value(p, tick))


def _raw(p: Point, value: Value) -> Value:
    """The raw value a module holds for an image value (ValueError when it does not fit)."""
    if p.dtype is DataType.STRING:
        return DataType.STRING.check(value)
    raw = p.raw_of(p.image_type.check(value))
    if p.dtype.is_float:
        return float(raw)  # type: ignore[arg-type]  # (a number: raw_of of a number)
    return p.dtype.check(raw)


def _image_value(p: Point, raw: Value) -> Value:
    value = p.value_of(raw)
    return value[0] if isinstance(value, tuple) else value  # type: ignore[return-value]  # (a Value)


def _animated_value(p: Point, tick: int) -> Value:
    """A raw value that moves (text does not)."""
    if p.kind is Kind.SI:  # a counter block: the tick count, little-endian, every 4 bytes
        return tick >> 8 * (p.index % 4) & 0xFF
    if p.kind is Kind.DI:
        return bool(
            (tick // 4) >> p.index & 1
        )  # a binary count, one step a second at the default period
    if p.dtype is DataType.STRING:
        return f"SIM {p.index}"[: p.length or 0]
    phase = (tick + 8 * p.index) % 80 / 80
    wave = 1 - abs(2 * phase - 1)  # triangle 0..1..0 over 20 s
    if p.dtype.is_float:
        return round(10 * wave, 3)
    if p.bit is not None:
        return int(wave * ((1 << p.bits) - 1))
    high = 0xFFFF if p.dtype in (DataType.UINT16, DataType.UINT32, DataType.UINT64) else 0x7FFF
    return int(wave * high)


def demo_wiring(config: ModbusBackConfig) -> list[tuple[str, str]]:
    """Output -> input pairs of the I-7232D demo bench, found in any topology.

    Modules with DO are paired, in address order, with modules that have DI and no
    outputs; the same for AO and AI-only modules. Channel n drives channel n.
    """
    points = config.points()

    def having(kind: Kind, without: Kind | None = None) -> list[list[Point]]:
        out = []
        for address in sorted(points):
            pts = points[address]
            if any(p.kind is kind for p in pts) and not (
                without and any(p.kind.is_output for p in pts)
            ):
                out.append([p for p in pts if p.kind is kind])
        return out

    pairs: list[tuple[str, str]] = []
    for out_kind, in_kind in ((Kind.DO, Kind.DI), (Kind.AO, Kind.AI)):
        # modules and channels pair up as far as both sides go; the rest have no partner
        for outs, ins in zip(having(out_kind), having(in_kind, without=out_kind), strict=False):
            pairs.extend((o.channel, i.channel) for o, i in zip(outs, ins, strict=False))
    return pairs
