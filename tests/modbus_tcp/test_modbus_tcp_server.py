"""The modbus-tcp front on a socket: pymodbus's client and a raw-socket client of our own.

A gateway with the modbus back on simulated modules and the modbus-tcp front on a free
loopback port. The raw client builds MBAP frames by hand (Modbus Messaging on TCP/IP
Implementation Guide V1.0b), so it shares nothing with pymodbus's framer.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import subprocess
import sys
from typing import Any

import pytest
from netkit import free_port, wait_until
from pymodbus.client import AsyncModbusTcpClient

from fieldgate import Gateway, Quality, load_registry
from fieldgate.plugins.modbus_tcp.map import (
    COILS,
    DISCRETE_INPUTS,
    HOLDING_REGISTERS,
    INPUT_REGISTERS,
)
from fieldgate.testing import in_this_process

# these tests reach into the front (its connections, its map) or stand in for the fieldbus
# side (set_outputs): it is built in this process. Every gateway runs it in a child process
# of its own: tests/opcua/test_plant_northbound_e2e.py, tests/http/test_http_northbound.py and
# tests/faults/test_modbus_tcp_attacks.py (against `fieldgate run`) go that way.
REGISTRY = in_this_process(load_registry(), "modbus-tcp")


def topology(port: int, **front: Any) -> dict[str, Any]:
    return {
        "gateway": {"name": "cell"},
        "fronts": [
            {
                "name": "mb",
                "type": "modbus-tcp",
                "listen": f"127.0.0.1:{port}",
                "writable": ["rs485/m3/do*", "rs485/m4/ao*"],
                **front,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 20,
                "timeout_ms": 50,
                "modules": [
                    {"address": 1, "model": "M-7052D"},  # 8 DI
                    {"address": 3, "model": "M-7055D"},  # 8 DI, 8 DO (writable)
                    {"address": 4, "model": "M-7024"},  # 4 AO (writable)
                    {"address": 5, "model": "M-7017R"},  # 8 AI
                    {"address": 6, "model": "M-7055D", "counts": {"di": 0}},  # 8 DO, read-only here
                ],
            }
        ],
    }


@pytest.fixture
async def gateway():
    port = free_port()
    gw = Gateway.load(topology(port), registry=REGISTRY, simulate=True)
    gw.port = port  # type: ignore[attr-defined]
    await gw.start()
    await wait_until(
        lambda: all(c.quality is Quality.GOOD for c in gw.image if not c.kind.is_output)
    )
    try:
        yield gw
    finally:
        await gw.stop()


def front_map(gw: Gateway) -> Any:
    return gw.component("mb").map


async def test_pymodbus_client_reads_every_table_in_maximal_blocks_and_writes_every_writable(
    gateway,
):
    sim = gateway.bench.simulator("rs485")
    for i in range(8):
        sim.set_input(f"rs485/m1/di{i}", i % 3 == 0)
        sim.set_input(f"rs485/m5/ai{i}", -1000 * i)
    await wait_until(lambda: gateway.read("rs485/m5/ai7") == -7000)
    m = front_map(gateway)
    client = AsyncModbusTcpClient("127.0.0.1", port=gateway.port, timeout=2, retries=0)
    assert await client.connect()
    try:
        # FC1-4: each table in one request (all fit in one maximal block here)
        coils = await client.read_coils(0, count=m.size(COILS), device_id=1)
        dis = await client.read_discrete_inputs(0, count=m.size(DISCRETE_INPUTS), device_id=1)
        hrs = await client.read_holding_registers(0, count=m.size(HOLDING_REGISTERS), device_id=1)
        irs = await client.read_input_registers(0, count=m.size(INPUT_REGISTERS), device_id=1)
        for response in (coils, dis, hrs, irs):
            assert not response.isError(), response
        di_points = [p for p in m.points if p.table == DISCRETE_INPUTS]
        assert dis.bits[: len(di_points)] == [gateway.read(p.channel_id) for p in di_points]
        ai = {
            p.channel_id: p.address for p in m.points if p.table == INPUT_REGISTERS and p.channel_id
        }
        assert [irs.registers[ai[f"rs485/m5/ai{i}"]] for i in range(8)] == [
            (-1000 * i) & 0xFFFF for i in range(8)
        ]
        status = [p for p in m.points if p.what == "rs485/m5 status"][0]
        assert irs.registers[status.address] == 0b11  # online, every input good
        # FC5 / FC15 on every writable coil, FC6 / FC16 on every writable holding register
        writable_coils = [p for p in m.points if p.table == COILS and p.writable]
        assert len(writable_coils) == 8
        first = writable_coils[0].address
        assert not (await client.write_coil(first, True, device_id=1)).isError()
        values = [bool(i % 2) for i in range(1, 8)]
        assert not (await client.write_coils(first + 1, values, device_id=1)).isError()
        regs = [p for p in m.points if p.table == HOLDING_REGISTERS and p.writable]
        assert not (await client.write_register(regs[0].address, 0xFFFF, device_id=1)).isError()
        assert not (
            await client.write_registers(regs[1].address, [100, 200, 300], device_id=1)
        ).isError()
        expected = {"rs485/m3/do0": True, **{f"rs485/m3/do{i}": bool(i % 2) for i in range(1, 8)}}
        expected |= {
            "rs485/m4/ao0": -1,
            "rs485/m4/ao1": 100,
            "rs485/m4/ao2": 200,
            "rs485/m4/ao3": 300,
        }
        for cid, value in expected.items():
            assert gateway.read(cid) == value, cid
            assert gateway.image[cid].written_by == "mb"
        await wait_until(lambda: all(sim.get_output(cid) == v for cid, v in expected.items()))
        # exceptions: unmapped (02) and read-only (01) addresses, a wrong unit (0B)
        beyond = await client.read_input_registers(
            m.size(INPUT_REGISTERS) - 1, count=2, device_id=1
        )
        assert beyond.isError() and beyond.exception_code == 0x02
        read_only = [p for p in m.points if p.table == COILS and not p.writable][0]  # m6's DO
        refused = await client.write_coil(read_only.address, True, device_id=1)
        assert refused.isError() and refused.exception_code == 0x01
        assert gateway.read(read_only.channel_id) is False
        other_unit = await client.read_coils(0, count=1, device_id=9)
        assert other_unit.isError() and other_unit.exception_code == 0x0B
        assert not (await client.read_coils(0, count=1, device_id=0)).isError()  # "this device"
    finally:
        client.close()
    status = gateway.status()["fronts"]["mb"]
    assert status["counters"]["writes"] == 4 and status["counters"]["exception_01"] == 1
    rows = {(r[0], tuple(sorted(r[4].items()))): r[3] for r in gateway.component("mb").metrics()}
    assert rows[("modbus_tcp_exceptions_total", (("code", "02"), ("front", "mb")))] == 1


class RawClient:
    """Modbus TCP by hand: MBAP header + PDU, one request at a time."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=3)
        self.tid = 0

    def request(self, pdu: bytes, unit: int = 1) -> bytes:
        self.tid += 1
        self.sock.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, unit) + pdu)
        head = self._exactly(7)
        tid, proto, length, got_unit = struct.unpack(">HHHB", head)
        assert (tid, proto, got_unit) == (self.tid, 0, unit)
        return self._exactly(length - 1)

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            assert chunk, "connection closed"
            data += chunk
        return data

    def close(self) -> None:
        self.sock.close()


def bits(payload: bytes, count: int) -> list[bool]:
    return [bool(payload[i // 8] >> (i % 8) & 1) for i in range(count)]


async def test_raw_socket_client_function_codes_and_exceptions(gateway):
    m = front_map(gateway)
    loop = asyncio.get_running_loop()
    raw = RawClient(gateway.port)

    async def ask(pdu: bytes, unit: int = 1) -> bytes:
        return await loop.run_in_executor(None, raw.request, pdu, unit)

    try:
        n_di = m.size(DISCRETE_INPUTS)
        answer = await ask(struct.pack(">BHH", 2, 0, n_di))
        assert answer[0] == 2 and answer[1] == (n_di + 7) // 8
        assert bits(answer[2:], n_di)[:8] == [gateway.read(f"rs485/m1/di{i}") for i in range(8)]
        n_ir = m.size(INPUT_REGISTERS)
        answer = await ask(struct.pack(">BHH", 4, 0, n_ir))
        assert answer[:2] == bytes([4, 2 * n_ir])
        coil = [p for p in m.points if p.table == COILS and p.writable][2]
        assert await ask(struct.pack(">BHH", 5, coil.address, 0xFF00)) == struct.pack(
            ">BHH", 5, coil.address, 0xFF00
        )
        assert gateway.read(coil.channel_id) is True
        assert (await ask(struct.pack(">BHH", 5, coil.address, 0x1234)))[:2] == bytes(
            [0x85, 0x03]
        )  # FC5 value
        answer = await ask(struct.pack(">BHH", 1, 0, m.size(COILS)))
        assert bits(answer[2:], m.size(COILS))[coil.address] is True
        reg = [p for p in m.points if p.table == HOLDING_REGISTERS and p.writable][3]
        assert await ask(struct.pack(">BHH", 6, reg.address, 0x8000)) == struct.pack(
            ">BHH", 6, reg.address, 0x8000
        )
        assert gateway.read(reg.channel_id) == -32768
        first = [p for p in m.points if p.table == COILS and p.writable][0].address
        answer = await ask(struct.pack(">BHHBB", 15, first, 8, 1, 0b1010_0101))
        assert answer == struct.pack(">BHH", 15, first, 8)
        assert [gateway.read(f"rs485/m3/do{i}") for i in range(8)] == bits(bytes([0b1010_0101]), 8)
        answer = await ask(struct.pack(">BHHB", 16, 0, 2, 4) + struct.pack(">HH", 7, 8))
        assert answer == struct.pack(">BHH", 16, 0, 2)
        assert (gateway.read("rs485/m4/ao0"), gateway.read("rs485/m4/ao1")) == (7, 8)
        answer = await ask(struct.pack(">BHH", 3, 0, 4))
        assert struct.unpack(">4h", answer[2:]) == (7, 8, gateway.read("rs485/m4/ao2"), -32768)
        # exceptions
        assert await ask(struct.pack(">BHH", 3, m.size(HOLDING_REGISTERS), 1)) == bytes(
            [0x83, 0x02]
        )
        assert await ask(struct.pack(">BHH", 2, 0, n_di + 1)) == bytes([0x82, 0x02])
        ro = [p for p in m.points if p.table == COILS and not p.writable][0]
        assert await ask(struct.pack(">BHH", 5, ro.address, 0xFF00)) == bytes([0x85, 0x01])
        assert await ask(struct.pack(">BHH", 6, m.size(HOLDING_REGISTERS), 1)) == bytes(
            [0x86, 0x02]
        )
        assert (await ask(struct.pack(">BHH", 1, 0, 2001)))[:2] == bytes(
            [0x81, 0x03]
        )  # over 2000 bits
        assert (await ask(bytes([0x2B, 0x0E, 0x01, 0x00])))[0] in (
            0x2B,
            0xAB,
        )  # device id: an answer
        assert (await ask(bytes([0x41])))[:2] == bytes([0xC1, 0x01])  # unknown function code
        assert await ask(struct.pack(">BHH", 1, 0, 1), unit=7) == bytes([0x81, 0x0B])
        # the connection and the server survive all of it
        assert (await ask(struct.pack(">BHH", 1, 0, 1)))[0] == 1
    finally:
        raw.close()


async def test_allowed_peers_refuses_other_addresses(tmp_path):
    port = free_port()
    gw = Gateway.load(topology(port, allowed_peers=["127.0.0.2"]), registry=REGISTRY, simulate=True)
    await gw.start()
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(struct.pack(">HHHB", 1, 0, 6, 1) + struct.pack(">BHH", 1, 0, 1))
        await writer.drain()
        assert await asyncio.wait_for(reader.read(100), 3) == b""  # closed without an answer
        writer.close()
        assert gw.status()["fronts"]["mb"]["counters"]["refused_peer"] == 1
        await asyncio.sleep(0.05)
        assert gw.component("mb").connections() == []  # a refused connection is forgotten
    finally:
        await gw.stop()


def test_validate_refuses_an_open_listener_and_warns_about_allowed_peers(tmp_path):
    from ruamel.yaml import YAML

    yaml = YAML()
    for extra, rc, text in (
        ({"listen": "0.0.0.0:502"}, 1, "Modbus TCP has no authentication; give tls"),
        (
            {"listen": "0.0.0.0:502", "allowed_peers": ["10.0.0.0/24"]},
            0,
            "warning: listen 0.0.0.0:502 without TLS",
        ),
    ):
        data = topology(502, **extra)
        data["backs"][0]["port"] = "/dev/ttyUSB0"
        path = tmp_path / "t.yaml"
        with path.open("w") as f:
            yaml.dump(data, f)
        done = subprocess.run(
            [sys.executable, "-m", "fieldgate", "validate", str(path)],
            capture_output=True,
            text=True,
        )
        assert done.returncode == rc and text in done.stdout + done.stderr, (
            done.stdout + done.stderr
        )


def test_fieldgate_map_prints_the_map_of_the_example():
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "fieldgate",
            "map",
            "examples/plant-northbound.yaml",
            "--front",
            "modbus",
        ],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("# Modbus map of front modbus")
    assert "coil (FC1 / FC5, FC15)              8        rs485/m6/do0" in done.stdout
    wrong = subprocess.run(
        [
            sys.executable,
            "-m",
            "fieldgate",
            "map",
            "examples/plant-northbound.yaml",
            "--front",
            "x",
        ],
        capture_output=True,
        text=True,
    )
    assert wrong.returncode == 1 and "no modbus-tcp front named 'x'" in wrong.stderr


class ChildContext:
    """What a north-facing front has of the gateway in a child process of its own
    (core/plugin.py, docs/architecture.md): these and nothing else (no ``backs``)."""

    ALLOWED = frozenset(
        (
            "image",
            "health",
            "masters",
            "events",
            "topology",
            "front_channels",
            "set_outputs",
            "point_locations",
        )
    )

    def __init__(self, real: Any):
        self._real = real
        self.used: set[str] = set()

    def __getattr__(self, name: str) -> Any:
        if name not in self.ALLOWED:
            raise AttributeError(f"{name!r} is not available to a front in a child process")
        self.used.add(name)
        return getattr(self._real, name)


async def test_the_front_needs_only_what_a_child_process_has():
    from fieldgate.plugin import GatewayContext
    from fieldgate.topology import load_topology

    port = free_port()
    topo = load_topology(topology(port), REGISTRY)
    real = GatewayContext.build(topo)
    context = ChildContext(real)
    front_type = REGISTRY.lookup("front", "modbus-tcp")
    front = front_type.factory(topo.fronts[0], context)
    await front.start()
    serving = asyncio.create_task(front.run())
    try:
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        assert await client.connect()
        assert not (await client.write_registers(1, [11, 12], device_id=1)).isError()
        assert (await client.read_holding_registers(1, count=2, device_id=1)).registers == [11, 12]
        client.close()
        assert (real.image.value("rs485/m4/ao1"), real.image.value("rs485/m4/ao2")) == (11, 12)
        assert front.status()["counters"]["writes"] == 1 and front.point_locations()
        assert {"set_outputs", "image", "front_channels"} <= context.used
    finally:
        serving.cancel()
        await asyncio.gather(serving, return_exceptions=True)
        await front.stop()
