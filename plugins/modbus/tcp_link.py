"""One Modbus TCP client connection: MBAP framing, transaction ids, pipelined requests.

The ``modbus-tcp-client`` back opens at most ``max_connections`` of these to a host and
shares them among the host's unit ids (:mod:`.tcp_back`). A request is framed with its own
transaction id; a reader task matches each answer to its request by that id, so several
requests may be in flight on one connection (``pipeline`` > 1, where the device allows) and
an answer that comes after its request timed out is recognised and dropped (``late``)
instead of being taken for the next one. The request PDUs are the RTU codec's
(:mod:`.codec`), the answers are decoded by pymodbus (pinned 3.16.1) and checked as the RTU
link checks them (:class:`.client.Transactions`).

Failures:

* no answer within ``timeout_ms``: :class:`~fieldgate.polling.CommError` ``timeout`` (the
  module's health counts it; the connection stays);
* an exception response: :class:`.client.ModbusExceptionError`;
* a frame that breaks MBAP (protocol id not 0, a length outside 2..254): the stream cannot
  be re-synchronised, the connection is closed: every request on it fails with
  :class:`~fieldgate.polling.LineLost`, as does every request while it is down, until the
  back has connected it again (with back-off);
* the connection closed or reset by the peer: the same.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import struct
import time
from collections.abc import Callable
from typing import Any

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError, LineLost

from .client import Transactions
from .codec import Request

log = logging.getLogger("fieldgate.modbus.tcp")

MBAP = struct.Struct(">HHHB")  # transaction id, protocol id, length, unit id
MAX_LENGTH = 254  # unit id + a PDU of at most 253 bytes


class ModbusTcpLink(Transactions):
    """A connection to ``host:port``; ``connect()`` (again after a loss) before requests."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        timeout: float = 1.0,
        connect_timeout: float = 3.0,
        clock: Callable[[], float] = time.monotonic,
    ):
        super().__init__()
        self.host = host
        self.port = port
        self.timeout = timeout
        self.connect_timeout = connect_timeout
        self.clock = clock
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._pending: dict[int, tuple[int, asyncio.Future[bytes]]] = {}  # tid -> (unit, answer)
        self._next_tid = 0
        self.lost_reason = "not connected yet"
        self.attempts = 0  # connects tried
        self.connects = 0  # connects made
        self.losses = 0
        self.late = 0  # answers that came after their request timed out
        self.in_flight_max = 0
        self.lock = asyncio.Lock()  # one (re)connect at a time (the back's lanes share a link)

    @property
    def name(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    @property
    def connected(self) -> bool:
        return self._writer is not None

    # -- the connection -----------------------------------------------------------------------
    async def connect(self) -> None:
        """Open the connection; OSError (refused, unreachable) or TimeoutError on failure."""
        self.close()
        self.attempts += 1
        async with asyncio.timeout(self.connect_timeout):
            reader, writer = await asyncio.open_connection(self.host, self.port)
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._reader, self._writer = reader, writer
        self.connects += 1
        self._task = asyncio.get_running_loop().create_task(
            self._read_answers(reader), name=f"modbus-tcp-client {self.name}"
        )

    def close(self, reason: str = "closed") -> None:
        """Close now; every request in flight fails with LineLost (``reason``)."""
        writer, self._writer, self._reader = self._writer, None, None
        task, self._task = self._task, None
        if task is not None and task is not asyncio.current_task():
            task.cancel()
        if writer is not None:
            writer.close()
        self._fail_pending(reason)

    def _lost(self, reason: str) -> None:
        if self._writer is not None:
            self.losses += 1
            log.debug("%s: connection lost: %s", self.name, reason)
        self.lost_reason = reason
        self.close(reason)

    def _fail_pending(self, reason: str) -> None:
        pending, self._pending = self._pending, {}
        for _unit, answer in pending.values():
            if not answer.done():
                answer.set_exception(LineLost(f"{self.name}: {reason}"))

    async def _read_answers(self, reader: asyncio.StreamReader) -> None:
        try:
            while True:
                header = await reader.readexactly(MBAP.size)
                tid, protocol, length, unit = MBAP.unpack(header)
                if protocol != 0 or not 2 <= length <= MAX_LENGTH:
                    self.stats.errors[ErrorKind.GARBAGE] += 1
                    self._lost(f"malformed MBAP header {header.hex(' ')}")
                    return
                pdu = await reader.readexactly(length - 1)
                entry = self._pending.pop(tid, None)
                if entry is None:
                    self.late += 1  # its request timed out (or was never ours): dropped
                    continue
                asked_unit, answer = entry
                if not answer.done():
                    if unit != asked_unit:
                        answer.set_exception(
                            CommError(
                                ErrorKind.WRONG_ADDRESS,
                                f"answer from unit {unit}, not {asked_unit}",
                            )
                        )
                    else:
                        answer.set_result(pdu)
        except asyncio.IncompleteReadError:
            self._lost("closed by the device")
        except OSError as exc:
            self._lost(exc.strerror or str(exc))

    # -- transactions ----------------------------------------------------------------------------
    async def _transact(self, request: Request) -> Any:
        writer = self._writer
        if writer is None:
            raise LineLost(f"{self.name}: {self.lost_reason}")
        function = request.function
        pdu = request.encode()[1:-2]  # the RTU ADU without unit and CRC
        tid = self._next_tid
        self._next_tid = (tid + 1) & 0xFFFF
        answer: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        self._pending[tid] = (request.unit, answer)
        self.in_flight_max = max(self.in_flight_max, len(self._pending))
        self.stats.requests[function] += 1
        started = self.clock()
        try:
            writer.write(MBAP.pack(tid, 0, len(pdu) + 1, request.unit) + pdu)
            async with asyncio.timeout(self.timeout):
                data = await answer
        except TimeoutError:
            self._pending.pop(tid, None)
            raise self._fail(ErrorKind.TIMEOUT, "no reply") from None
        except LineLost:
            self.stats.errors[ErrorKind.IO] += 1
            raise
        except CommError as exc:
            self.stats.errors[exc.kind] += 1
            raise
        except OSError as exc:  # writing to a connection the device reset
            self._pending.pop(tid, None)
            self._lost(exc.strerror or str(exc))
            self.stats.errors[ErrorKind.IO] += 1
            raise LineLost(f"{self.name}: {self.lost_reason}") from None
        self.stats.last_rtt = self.clock() - started
        return self._decoded(function, data, data)

    def status(self) -> dict[str, Any]:
        return {
            "connected": self.connected,
            "attempts": self.attempts,
            "connects": self.connects,
            "losses": self.losses,
            "last_loss": None if self.connected else self.lost_reason,
            "in_flight": len(self._pending),
            "in_flight_max": self.in_flight_max,
            "late_answers": self.late,
        }
