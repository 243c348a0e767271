"""The modbus-tcp front against hostile and clumsy clients on a real socket (issue 29: D3,
D5, D6, the limits, writes acknowledged once applied). Raw sockets build the MBAP frames by
hand; pymodbus's client is the independent well-behaved peer."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
from collections.abc import AsyncIterator, Mapping
from typing import Any

import pytest
from netkit import free_port, wait_until
from pymodbus.client import AsyncModbusTcpClient

from fieldgate import Gateway, load_registry
from fieldgate.testing import in_this_process

from .test_modbus_tcp_server import topology

# these tests reach into the front (its connections, its map) or stand in for the fieldbus
# side (set_outputs): it is built in this process. Every gateway runs it in a child process
# of its own: tests/opcua/test_plant_northbound_e2e.py, tests/http/test_http_northbound.py and
# tests/faults/test_modbus_tcp_attacks.py (against `fieldgate run`) go that way.
REGISTRY = in_this_process(load_registry(), "modbus-tcp")
READ = struct.pack(">BHH", 3, 0, 1)
SERVED = {1, 2, 3, 4, 5, 6, 15, 16, 23}


def mbap(pdu: bytes, tid: int = 1, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


@contextlib.asynccontextmanager
async def serve(**front: Any) -> AsyncIterator[Gateway]:
    port = free_port()
    gw = Gateway.load(topology(port, **front), registry=REGISTRY, simulate=True)
    gw.port = port  # type: ignore[attr-defined]
    await gw.start()
    try:
        yield gw
    finally:
        await gw.stop()


async def connect(gw: Gateway, source: str | None = None) -> tuple[Any, Any]:
    local = (source, 0) if source else None
    return await asyncio.open_connection("127.0.0.1", gw.port, local_addr=local)  # type: ignore[attr-defined]


async def read_frame(reader: asyncio.StreamReader, timeout: float = 3.0) -> tuple[int, bytes]:
    async with asyncio.timeout(timeout):
        head = await reader.readexactly(7)
        tid, proto, length, _unit = struct.unpack(">HHHB", head)
        assert proto == 0
        return tid, await reader.readexactly(length - 1)


async def closed_by_server(reader: asyncio.StreamReader, timeout: float = 3.0) -> bool:
    """True when the server closes (EOF or reset) within ``timeout`` without answering."""
    try:
        async with asyncio.timeout(timeout):
            data = await reader.read(4096)
    except TimeoutError:
        return False
    except ConnectionError:
        return True
    return data == b""


async def fresh_read(gw: Gateway, source: str | None = None) -> bool:
    client = AsyncModbusTcpClient(
        "127.0.0.1",
        port=gw.port,  # type: ignore[attr-defined]
        timeout=2,
        retries=0,
        source_address=(source, 0) if source else None,
    )
    try:
        if not await client.connect():
            return False
        answer = await client.read_holding_registers(0, count=1, device_id=1)
        return not answer.isError()
    finally:
        client.close()


async def still_open(conns: list[tuple[Any, Any]]) -> int:
    async def is_open(reader: asyncio.StreamReader) -> bool:
        return not await closed_by_server(reader, 0.05)

    return sum(await asyncio.gather(*(is_open(r) for r, _ in conns)))


def counters(gw: Gateway) -> dict[str, int]:
    return dict(gw.status()["fronts"]["mb"]["counters"])


# -- D3: admission --------------------------------------------------------------------------
async def test_silent_connections_no_longer_lock_every_client_out():
    """D3: max_clients silent sockets held every slot for as long as they liked."""
    async with serve(max_clients=4) as gw:
        silent = [await connect(gw) for _ in range(20)]
        await asyncio.sleep(0.2)
        assert [await fresh_read(gw) for _ in range(5)] == [True] * 5
        assert await still_open(silent) <= 4
        assert len(gw.component("mb").connections()) <= 4
        assert counters(gw)["closed_evicted"] >= 16
        for _, writer in silent:
            writer.close()


async def test_one_address_is_held_to_its_own_cap():
    async with serve(max_clients=8, max_clients_per_peer=2) as gw:
        mine = [await connect(gw) for _ in range(6)]
        other = await connect(gw, source="127.0.0.2")
        await asyncio.sleep(0.2)
        assert await still_open(mine) == 2
        assert await still_open([other]) == 1  # 127.0.0.1's crowd never evicted it
        assert await fresh_read(gw, source="127.0.0.3")
        status = gw.status()["fronts"]["mb"]
        assert status["limits"]["max_clients_per_peer"] == 2
        for _, writer in [*mine, other]:
            writer.close()


async def test_a_connection_being_served_is_never_evicted_and_a_newcomer_waits_its_turn():
    async with serve(max_clients=2) as gw:
        release = asyncio.Event()
        real = gw.context.set_outputs

        async def slow(values: Mapping[str, Any], origin: str) -> None:
            await release.wait()
            await real(values, origin=origin)

        gw.context.set_outputs = slow  # type: ignore[method-assign]
        busy = [await connect(gw) for _ in range(2)]
        for i, (_, writer) in enumerate(busy):
            writer.write(mbap(struct.pack(">BHH", 6, 1 + i, 40 + i), tid=9))
        await wait_until(lambda: gw.component("mb").server._tasks)
        await asyncio.sleep(0.1)
        reader, _ = await connect(gw)
        assert await closed_by_server(reader)  # refused: every slot is being served
        assert counters(gw)["refused_busy"] == 1
        release.set()
        for i, (r, _) in enumerate(busy):
            assert await read_frame(r) == (9, struct.pack(">BHH", 6, 1 + i, 40 + i))
        assert (gw.read("rs485/m4/ao1"), gw.read("rs485/m4/ao2")) == (40, 41)
        for _, writer in busy:
            writer.close()


async def test_idle_and_half_sent_connections_are_closed():
    async with serve(idle_timeout_s=1.0, request_timeout_s=0.5) as gw:
        loop = asyncio.get_running_loop()
        idle_r, idle_w = await connect(gw)
        idle_w.write(mbap(READ))
        await read_frame(idle_r)
        idle_since = loop.time()
        slow_r, slow_w = await connect(gw)
        slow_w.write(mbap(READ)[:5])  # a header never finished
        slow_since = loop.time()
        assert await closed_by_server(slow_r, 3.0)
        slow_after = loop.time() - slow_since
        assert await closed_by_server(idle_r, 3.0)
        idle_after = loop.time() - idle_since
        assert slow_after > 0.35 and idle_after > 0.8  # not before their time (the client
        # sees its answer a little after the server sent it); within 3 s: closed_by_server
        c = counters(gw)
        assert (c["closed_request_timeout"], c["closed_idle_timeout"]) == (1, 1)
        assert await fresh_read(gw)
        for writer in (idle_w, slow_w):
            writer.close()


# -- D5: malformed MBAP ----------------------------------------------------------------------
@pytest.mark.parametrize(
    "data",
    [
        struct.pack(">HHHB", 1, 0, 0, 1),
        struct.pack(">HHHB", 1, 0, 1, 1),
        struct.pack(">HHHB", 1, 0, 255, 1) + bytes(16),
        struct.pack(">HHHB", 1, 0, 65535, 1) + bytes(16),
        struct.pack(">HHHB", 1, 1, 6, 1) + READ,
        b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",
    ],
    ids=["length-0", "length-1", "length-255", "length-65535", "protocol-1", "http"],
)
async def test_a_malformed_header_closes_the_connection(data):
    """D5: neither answered nor closed before."""
    async with serve() as gw:
        reader, writer = await connect(gw)
        writer.write(data)
        assert await closed_by_server(reader, 2.0)
        assert counters(gw)["closed_malformed"] == 1
        assert await fresh_read(gw)
        writer.close()


async def test_length_0_does_not_desynchronise_the_stream():
    """D5: the request after a length-0 header got a reply built from leftover bytes."""
    async with serve() as gw:
        reader, writer = await connect(gw)
        writer.write(struct.pack(">HHHB", 1, 0, 0, 1) + mbap(READ, tid=2))
        assert await closed_by_server(reader, 2.0)  # and nothing answered
        writer.close()


# -- D6: function codes ----------------------------------------------------------------------
async def test_every_function_code_outside_the_served_set_answers_exception_01():
    """D6: FC 8 echoed, FC 17 answered "Pymodbus", FC 24 FIFO values 0,1,2,3, FC 43 ..."""
    async with serve() as gw:
        reader, writer = await connect(gw)
        outside = [fc for fc in range(256) if fc not in SERVED]
        for fc in outside:
            body = b"\x0e\x01\x00" if fc == 43 else bytes(4)  # FC 43/14: device identification
            writer.write(mbap(bytes([fc]) + body, tid=fc))
            assert await read_frame(reader) == (fc, bytes([fc | 0x80, 0x01])), fc
        assert counters(gw)["unknown_function"] == len(outside) == 247
        writer.close()


# -- pipelining and clients that do not read -------------------------------------------------
async def test_pipelined_requests_are_all_answered_in_order():
    """pymodbus 3.16.1 answered the first request of a segment and dropped the others."""
    async with serve(max_pending_requests=4) as gw:
        reader, writer = await connect(gw)
        n = 60
        write, read = ">BHH", struct.pack(">BHH", 3, 1, 1)  # FC6 / FC3 of holding register 1
        frames = [
            mbap(struct.pack(write, 6, 1, 1000 + i) if i % 2 else read, tid=i)
            for i in range(1, n + 1)
        ]
        writer.write(b"".join(frames))
        for i in range(1, n + 1):
            tid, pdu = await read_frame(reader)
            assert tid == i
            if i % 2 == 0:  # the read after each write sees it
                assert pdu == struct.pack(">BBH", 3, 2, 1000 + i - 1)
        assert counters(gw)["pipeline_full"] >= 1
        writer.close()


async def test_a_client_that_never_reads_holds_a_bounded_amount_and_is_closed():
    async with serve(idle_timeout_s=1.0) as gw:
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.setblocking(False)
        loop = asyncio.get_running_loop()
        await loop.sock_connect(sock, ("127.0.0.1", gw.port))  # type: ignore[attr-defined]
        sending = asyncio.create_task(
            loop.sock_sendall(sock, b"".join(mbap(READ, tid=i) for i in range(20_000)))
        )
        conns = gw.component("mb").connections
        await wait_until(lambda: any(c.write_paused and c.reading_paused for c in conns()))
        conn = conns()[0]  # its answers wait in 16 KiB, its requests in the kernel
        assert conn.transport.get_write_buffer_size() <= 16 * 1024 + 260
        assert conn.engine.pending <= 16
        assert await fresh_read(gw)
        await wait_until(lambda: counters(gw).get("closed_idle_timeout") == 1, timeout=4)
        sending.cancel()
        await asyncio.gather(sending, return_exceptions=True)
        sock.close()


# -- writes ----------------------------------------------------------------------------------
async def test_a_write_is_answered_only_once_applied_in_one_batch():
    async with serve() as gw:
        release = asyncio.Event()
        calls: list[tuple[dict[str, Any], str]] = []
        real = gw.context.set_outputs

        async def held(values: Mapping[str, Any], origin: str) -> None:
            calls.append((dict(values), origin))
            await release.wait()
            await real(values, origin=origin)

        gw.context.set_outputs = held  # type: ignore[method-assign]
        reader, writer = await connect(gw)
        writer.write(mbap(struct.pack(">BHHBHHH", 16, 1, 3, 6, 7, 8, 9), tid=5))
        with pytest.raises(TimeoutError):
            await read_frame(reader, timeout=0.3)  # not before the image applied it
        assert gw.read("rs485/m4/ao1") != 7
        release.set()
        assert await read_frame(reader) == (5, struct.pack(">BHH", 16, 1, 3))
        assert calls == [({"rs485/m4/ao1": 7, "rs485/m4/ao2": 8, "rs485/m4/ao3": 9}, "mb")]
        assert [gw.read(f"rs485/m4/ao{i}") for i in (1, 2, 3)] == [7, 8, 9]
        writer.close()


async def test_read_write_multiple_registers_writes_first_then_reads():
    """FC23 (section 6.17): one batch written, then the read answered, after it applied."""
    async with serve() as gw:
        reader, writer = await connect(gw)
        request = struct.pack(">BHHHHBHH", 23, 0, 4, 2, 2, 4, 222, 333)  # write ao2-3, read 0-3
        writer.write(mbap(request, tid=3))
        tid, pdu = await read_frame(reader)
        assert tid == 3 and pdu[:2] == bytes([23, 8])
        assert struct.unpack(">4h", pdu[2:])[2:] == (222, 333)
        assert (gw.read("rs485/m4/ao2"), gw.read("rs485/m4/ao3")) == (222, 333)
        writer.write(mbap(struct.pack(">BHHHHBH", 23, 3, 2, 1, 1, 2, 9), tid=4))  # read 3-4
        assert await read_frame(reader) == (4, bytes([0x97, 0x02]))
        assert gw.read("rs485/m4/ao1") != 9  # refused whole: nothing written
        writer.close()


@pytest.mark.parametrize(
    ("error", "code"),
    [(KeyError("no channel"), 0x02), (ValueError("out of range"), 0x03), (OSError("gone"), 0x04)],
)
async def test_a_write_the_gateway_refuses_is_an_exception_and_writes_nothing(error, code):
    async with serve() as gw:

        async def refuse(values: Mapping[str, Any], origin: str) -> None:
            raise error

        gw.context.set_outputs = refuse  # type: ignore[method-assign]
        before = gw.read("rs485/m4/ao1")
        reader, writer = await connect(gw)
        writer.write(mbap(struct.pack(">BHH", 6, 1, 77)))
        assert await read_frame(reader) == (1, bytes([0x86, code]))
        assert gw.read("rs485/m4/ao1") == before
        writer.write(mbap(READ, tid=2))  # the connection goes on
        assert (await read_frame(reader))[0] == 2
        writer.close()
