"""The ``modbus-tcp`` front: the process image as a Modbus TCP server.

Our own server (docs/modbus-tcp.md, "Why our own server"): :mod:`.server` does the sockets
and TLS, :mod:`.mbap` the framing, admission and timers (no I/O), :mod:`.pdu` the requests
and answers, :mod:`.map` the map and its exception rules. This module answers each request:
reads from the process image, in the loop turn the request arrived in (never an RS-485
transaction); writes through ``context.set_outputs``, one batch per request, answered once
the fieldbus side applied it.

The front uses only what a north-facing front may use in a child process of its own:
``context.image``, ``health``, ``topology``, ``front_channels`` and ``set_outputs``.
"""

from __future__ import annotations

import ssl
from collections import Counter
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

from fieldgate.image import Value
from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.metric_samples import counter, gauge
from fieldgate.plugin import Front, GatewayContext, PluginStartError

from .config import ModbusTcpFrontConfig
from .map import ModbusMap
from .mbap import Frame, Limits
from .pdu import (
    GATEWAY_NO_RESPONSE,
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    SERVER_DEVICE_FAILURE,
    Read,
    ReadWrite,
    Write,
    decode,
    encode_read,
    encode_write,
    exception,
)
from .server import ModbusTcpServer, ServerLimits

THIS_DEVICE = (0, 255)  # unit ids a Modbus TCP server answers as itself
CLOSE_REASONS = ("evicted", "idle_timeout", "request_timeout", "malformed")


class ModbusTcpFront(Front):
    def __init__(self, config: ModbusTcpFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.config: ModbusTcpFrontConfig = config
        self.map: ModbusMap | None = None
        self.server: ModbusTcpServer | None = None
        self.counters: Counter[str] = Counter()
        self._write_errors_logged: set[str] = set()

    def connections(self) -> list[Any]:
        return list(self.server.connections) if self.server is not None else []

    def build(self) -> ModbusTcpServer:
        """The map and the server, not yet listening (the fuzz target feeds it directly)."""
        cfg = self.config
        self.map = ModbusMap.from_channels(
            self.context.front_channels(cfg),
            cfg.writable,
            cfg.byte_order,
            cfg.comm_fault == "exception",
            cfg.scaled_values,
        )
        host, port = cfg.host_port
        limits = ServerLimits(
            cfg.max_clients,
            cfg.max_clients_per_peer,
            Limits(cfg.idle_timeout_s, cfg.request_timeout_s, cfg.max_pending_requests),
        )
        return ModbusTcpServer(
            self.handle,
            host,
            port,
            limits,
            ssl_context=self._ssl_context() if cfg.tls is not None else None,
            allowed_peers=cfg.allowed_peers,
            counters=self.counters,
            log=self.log,
        )

    async def start(self) -> None:
        cfg = self.config
        server = self.build()
        assert self.map is not None
        try:
            await server.start()
        except OSError as exc:
            raise PluginStartError(
                f"cannot listen on {cfg.listen}: {exc.strerror or exc}"
            ) from None
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
        await self.server.serve_forever()

    async def stop(self) -> None:
        server, self.server = self.server, None
        if server is not None:
            await server.stop()

    # -- requests ----------------------------------------------------------------------------
    def handle(self, frame: Frame) -> bytes | Coroutine[Any, Any, bytes]:
        """The answer PDU to one request; a write's is a coroutine (answered once applied)."""
        fc = frame.pdu[0]
        unit = frame.unit
        if unit != self.config.unit_id and unit not in THIS_DEVICE:
            self.counters["unknown_unit"] += 1
            return self._refuse(fc, GATEWAY_NO_RESPONSE)
        request = decode(frame.pdu)
        if isinstance(request, int):
            if request == ILLEGAL_FUNCTION:
                self.counters["unknown_function"] += 1
            return self._refuse(fc, request)
        if isinstance(request, Read):
            return self._read(request)
        assert self.map is not None
        write = request.write if isinstance(request, ReadWrite) else request
        values = self.map.write(write.fc, write.address, write.values)
        if isinstance(values, int):
            return self._refuse(fc, values)
        if isinstance(request, ReadWrite):
            read = request.read
            error = self.map.read_error(read.fc, read.address, read.count)
            if error is not None:
                return self._refuse(fc, error)  # refused whole, before anything is written
        return self._write(request, values, frame.pdu)

    def _read(self, request: Read) -> bytes:
        assert self.map is not None
        result = self.map.read(
            request.fc, request.address, request.count, self.context.image, self.context.health
        )
        if isinstance(result, int):
            return self._refuse(request.fc, result)
        self.counters["reads"] += 1
        return encode_read(request.fc, result)

    async def _write(
        self, request: Write | ReadWrite, values: dict[str, Value], pdu: bytes
    ) -> bytes:
        try:
            await self.context.set_outputs(values, origin=self.name)
        except (KeyError, ValueError) as exc:
            code = ILLEGAL_ADDRESS if isinstance(exc, KeyError) else ILLEGAL_VALUE
            self._log_write_error(str(exc).strip("'\""))
            return self._refuse(request.fc, code)
        except Exception as exc:  # noqa: BLE001  (the fieldbus side could not be reached)
            self._log_write_error(f"{type(exc).__name__}: {exc}")
            return self._refuse(request.fc, SERVER_DEVICE_FAILURE)
        self.counters["writes"] += 1
        if isinstance(request, ReadWrite):
            return self._read(request.read)
        return encode_write(request, pdu)

    def _log_write_error(self, reason: str) -> None:
        if reason not in self._write_errors_logged and len(self._write_errors_logged) < 20:
            self._write_errors_logged.add(reason)
            self.log.warning("Modbus TCP write refused by the gateway: %s", reason)

    def _refuse(self, fc: int, code: int) -> bytes:
        self.counters[f"exception_{code:02x}"] += 1
        return exception(fc, code)

    # -- observability -----------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        if self.map is None:
            return {}
        cfg = self.config
        return {
            "state": "listening" if self.server is not None else "stopped",
            "endpoint": f"{'modbus+tls' if cfg.tls else 'modbus'}://{cfg.listen}",
            "unit_id": cfg.unit_id,
            "clients": [c.state() for c in self.connections()],
            "limits": {
                "max_clients": cfg.max_clients,
                "max_clients_per_peer": min(cfg.max_clients_per_peer, cfg.max_clients),
                "idle_timeout_s": cfg.idle_timeout_s,
                "request_timeout_s": cfg.request_timeout_s,
                "max_pending_requests": cfg.max_pending_requests,
            },
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
        rows += [
            counter(
                "modbus_tcp_closed_total",
                "connections the server closed, by reason",
                self.counters[f"closed_{r}"],
                front=front,
                reason=r,
            )
            for r in CLOSE_REASONS
        ]
        rows.append(
            counter(
                "modbus_tcp_pipeline_full_total",
                "times a connection's reading was paused at max_pending_requests",
                self.counters["pipeline_full"],
                front=front,
            )
        )
        return rows

    def point_locations(self) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for table, span, what, _dtype, _access in self.map.rows() if self.map else []:
            out.setdefault(what, []).append(f"{table.split(' (')[0]} {span}")
        return out


def _resolve(base: Path, name: str) -> Path:
    path = Path(name)
    return path if path.is_absolute() else base / path
