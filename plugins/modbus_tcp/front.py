"""The ``modbus-tcp`` front: the process image as a Modbus TCP server (pymodbus 3.16.1).

pymodbus does the TCP/TLS transport, MBAP framing and PDU decoding; every request reaches
:class:`ImageContext`, which answers from the process image through the front's
:class:`~.map.ModbusMap` (the map and the exception rules live there, without I/O). Reads never
wait for an RS-485 transaction; a write goes to the process image and the back writes it to
the module on its next turn.
"""

from __future__ import annotations

import ipaddress
import ssl
import struct
from collections import Counter
from pathlib import Path
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.bit_message import (
    ReadCoilsRequest,
    ReadDiscreteInputsRequest,
    WriteMultipleCoilsRequest,
    WriteSingleCoilRequest,
)
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    WriteMultipleRegistersRequest,
)
from pymodbus.server import ModbusTcpServer, ModbusTlsServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType as SimType
from pymodbus.simulator import SimData, SimDevice

from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.metric_samples import counter, gauge
from fieldgate.plugin import Front, GatewayContext, PluginStartError

from .config import ModbusTcpFrontConfig
from .map import TABLE_OF_FC, ModbusMap

THIS_DEVICE = (0, 255)  # unit ids a Modbus TCP server answers as itself


class ImageContext:
    """What pymodbus's request handler calls (in place of its SimCore): reads and writes on the map."""

    def __init__(self, front: ModbusTcpFront, modbus_map: ModbusMap):
        self.front = front
        self.map = modbus_map

    def device_ids(self) -> list[int]:
        return [self.front.config.unit_id]

    def _check(self, device_id: int) -> None:
        if device_id != self.front.config.unit_id and device_id not in THIS_DEVICE:
            self.front.counters["unknown_unit"] += 1
            raise NoSuchIdException(f"unit id {device_id}")

    async def async_getValues(
        self, device_id: int, func_code: int, address: int, count: int = 1
    ) -> Any:
        self._check(device_id)
        if func_code not in TABLE_OF_FC:
            return ExcCodes.ILLEGAL_FUNCTION
        result = self.map.read(
            func_code, address, count, self.front.context.image, self.front.context.health
        )
        if isinstance(result, int):
            self.front.counters[f"exception_{result:02x}"] += 1
            return ExcCodes(result)
        self.front.counters["reads"] += 1
        return result

    async def async_setValues(
        self, device_id: int, func_code: int, address: int, values: list[Any]
    ) -> Any:
        self._check(device_id)
        if func_code not in TABLE_OF_FC:
            return ExcCodes.ILLEGAL_FUNCTION
        result = self.map.write(func_code, address, list(values), self.front.write)
        if result is not None:
            self.front.counters[f"exception_{result:02x}"] += 1
            return ExcCodes(result)
        self.front.counters["writes"] += 1
        return None


class StrictWriteSingleCoil(WriteSingleCoilRequest):
    """FC5 with the value the standard allows: FF00 (on) or 0000 (off); anything else is
    exception 03. pymodbus 3.16.1 takes any non-zero value as "on", so a garbled request
    would switch an output on."""

    raw_value = 0

    def decode(self, data: bytes) -> None:
        self.address, self.raw_value = struct.unpack(">HH", data[:4])
        self.bits = [self.raw_value == 0xFF00]

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        if self.raw_value not in (0xFF00, 0x0000):
            return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_VALUE)
        return await super().datastore_update(context, device_id)


def _counted(base: type[ModbusPDU]) -> type[ModbusPDU]:
    """``base`` answering a quantity outside its limits (FC1/2: 2000 bits, FC3/4: 125 registers,
    FC15: 1968, FC16: 123) with exception 03, as the standard says; pymodbus 3.16.1 fails to
    decode such a request and answers function code 0x80 with exception 01."""

    class Counted(base):  # type: ignore[valid-type,misc]  # a class made from a variable base
        bad_count = False

        def decode(self, data: bytes) -> None:
            try:
                super().decode(data)
            except ValueError:
                self.bad_count = True

        async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
            if self.bad_count:
                return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_VALUE)
            result: ModbusPDU = await super().datastore_update(context, device_id)
            return result

    Counted.__name__ = f"Counted{base.__name__}"
    return Counted


STRICT_PDUS = [
    StrictWriteSingleCoil,
    *(
        _counted(base)
        for base in (
            ReadCoilsRequest,
            ReadDiscreteInputsRequest,
            ReadHoldingRegistersRequest,
            ReadInputRegistersRequest,
            WriteMultipleCoilsRequest,
            WriteMultipleRegistersRequest,
        )
    ),
]


def _handler_class(front: ModbusTcpFront) -> type[ServerRequestHandler]:
    class Handler(ServerRequestHandler):
        def connection_made(self, transport: Any) -> None:
            peer = transport.get_extra_info("peername")
            host = peer[0] if isinstance(peer, tuple) else ""
            if not front.peer_allowed(host):
                front.counters["refused_peer"] += 1
                front.log.warning(
                    "Modbus TCP connection from %s refused: not in allowed_peers", host
                )
                self._refuse(transport)
                return
            if len(front.connections()) > front.config.max_clients:
                front.counters["refused_busy"] += 1
                self._refuse(transport)
                return
            front.counters["connections"] += 1
            super().connection_made(transport)

        def _refuse(self, transport: Any) -> None:
            transport.close()  # (pymodbus never saw it open: forget it here)
            listener = getattr(self, "listener", None)
            if listener is not None:
                listener.active_connections.pop(self.unique_id, None)

        def callback_data(self, data: bytes, addr: tuple[str, int] | None = None) -> int:
            """An unknown function code gets exception 01 with that code (pymodbus 3.16.1
            answers function code 0x80); everything else is pymodbus's."""
            if len(data) >= 8:
                tid, proto, length, unit = struct.unpack(">HHHB", data[:7])
                fc = data[7]
                if (
                    proto == 0
                    and fc < 0x80
                    and fc not in self.server.decoder.pdu_table
                    and len(data) >= 6 + length
                ):
                    front.counters["exception_01"] += 1
                    transport: Any = self.transport
                    if transport is not None:
                        transport.write(struct.pack(">HHHBBB", tid, 0, 3, unit, fc | 0x80, 1))
                    return int(6 + length)
            return int(super().callback_data(data, addr))

    return Handler


class ModbusTcpFront(Front):
    def __init__(self, config: ModbusTcpFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.config: ModbusTcpFrontConfig = config
        self.map: ModbusMap | None = None
        self.server: Any = None
        self.counters: Counter[str] = Counter()
        self._networks = [ipaddress.ip_network(p, strict=False) for p in config.allowed_peers or []]

    def peer_allowed(self, host: str) -> bool:
        if not self._networks:
            return True
        try:
            address = ipaddress.ip_address(host.split("%")[0])
        except ValueError:
            return False
        return any(address in net for net in self._networks)

    def write(self, channel_id: str, value: bool | int | float) -> None:
        self.context.image.write_output(channel_id, value, origin=self.name)

    def connections(self) -> list[Any]:
        server = self.server
        return list(server.active_connections.values()) if server is not None else []

    async def start(self) -> None:
        cfg = self.config
        self.map = ModbusMap.from_channels(
            self.context.front_channels(cfg),
            cfg.writable,
            cfg.word_order,
            cfg.comm_fault == "exception",
        )
        host, port = cfg.host_port
        placeholder = SimDevice(cfg.unit_id, simdata=[SimData(0, datatype=SimType.REGISTERS)])
        kwargs: dict[str, Any] = {
            "context": placeholder,
            "address": (host, port),
            "custom_pdu": STRICT_PDUS,
        }
        if cfg.tls is not None:
            kwargs["sslctx"] = self._ssl_context()
            server: Any = ModbusTlsServer(**kwargs)
        else:
            server = ModbusTcpServer(**kwargs)
        server.context = ImageContext(self, self.map)
        handler = _handler_class(self)
        server.callback_new_connection = lambda: handler(
            server, server.trace_packet, server.trace_pdu, server.trace_connect
        )
        try:
            await server.serve_forever(background=True)
        except (RuntimeError, OSError) as exc:
            raise PluginStartError(f"cannot listen on {cfg.listen}: {exc}") from None
        self.server = server
        sizes = ", ".join(
            f"{self.map.size(t)} {t}s"
            for t in ("coil", "discrete input", "holding register", "input register")
        )
        self.log.info(
            "Modbus TCP server on %s%s, unit %d: %s",
            cfg.listen,
            " (TLS)" if cfg.tls else "",
            cfg.unit_id,
            sizes,
        )

    def _ssl_context(self) -> ssl.SSLContext:
        tls = self.config.tls
        assert tls is not None
        base = self.context.topology.base_dir
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.minimum_version = ssl.TLSVersion.TLSv1_2
        try:
            ctx.load_cert_chain(_resolve(base, tls.cert_file), _resolve(base, tls.key_file))
            ctx.load_verify_locations(_resolve(base, tls.client_ca_file))
        except (OSError, ssl.SSLError) as exc:
            raise PluginStartError(f"tls: {exc}") from None
        ctx.verify_mode = ssl.CERT_REQUIRED
        return ctx

    async def run(self) -> None:
        assert self.server is not None
        await self.server.serving

    async def stop(self) -> None:
        server, self.server = self.server, None
        if server is not None:
            await server.shutdown()

    # -- observability -----------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        if self.map is None:
            return {}
        clients = []
        for conn in self.connections():
            transport = getattr(conn, "transport", None)
            peer = transport.get_extra_info("peername") if transport is not None else None
            if isinstance(peer, tuple):
                clients.append({"peer": f"{peer[0]}:{peer[1]}"})
        return {
            "state": "listening" if self.server is not None else "stopped",
            "endpoint": f"{'modbus+tls' if self.config.tls else 'modbus'}://{self.config.listen}",
            "unit_id": self.config.unit_id,
            "clients": clients,
            "counters": dict(sorted(self.counters.items())),
        }

    def metrics(self) -> list[MetricSample]:
        if self.map is None:
            return []
        front = self.name
        rows = [
            gauge(
                "modbus_tcp_clients",
                "client connections open",
                len(self.connections()),
                front=front,
            ),
            counter(
                "modbus_tcp_reads_total",
                "read requests answered",
                self.counters["reads"],
                front=front,
            ),
            counter(
                "modbus_tcp_writes_total",
                "write requests applied",
                self.counters["writes"],
                front=front,
            ),
        ]
        rows += [
            counter(
                "modbus_tcp_exceptions_total",
                "exception responses, by code",
                n,
                front=front,
                code=key.split("_")[1],
            )
            for key, n in sorted(self.counters.items())
            if key.startswith("exception_")
        ]
        rows += [
            counter(
                "modbus_tcp_refused_total",
                "connections refused, by reason",
                self.counters[f"refused_{r}"],
                front=front,
                reason=r,
            )
            for r in ("peer", "busy")
        ]
        return rows

    def point_locations(self) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for table, span, what, _dtype, _access in self.map.rows() if self.map else []:
            out.setdefault(what, []).append(f"{table.split(' (')[0]} {span}")
        return out


def _resolve(base: Path, name: str) -> Path:
    path = Path(name)
    return path if path.is_absolute() else base / path
