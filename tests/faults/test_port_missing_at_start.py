"""A serial port missing when the gateway starts: the gateway starts anyway (the CAN node
boots), the line's modules are offline with COMM_FAULT, the CANopen front reports EMCY
``00 50 81 03`` (the I-7232D's "COM port access error") until the port appears; the back
opens it with back-off and its modules come back, with no component restart.
"""

from __future__ import annotations

import asyncio
import uuid

import can
import port_faults  # scripts/faults (see conftest)
import pytest

from fieldgate import Gateway, Quality, load_registry
from fieldgate.events import PORT_BACK, PORT_LOST
from fieldgate.serial_link import PluggablePty

NODE = port_faults.NODE_ID
COM_PORT_ERROR = bytes.fromhex("0050810300000000")


@pytest.fixture(scope="module")
def registry():
    return load_registry()


async def frames(bus: can.BusABC, seconds: float) -> dict[int, list[bytes]]:
    """Every frame for ``seconds``, by CAN-ID."""
    loop = asyncio.get_running_loop()
    end, got = loop.time() + seconds, {}
    while loop.time() < end:
        msg = await asyncio.to_thread(bus.recv, 0.02)
        if msg is not None:
            got.setdefault(msg.arbitration_id, []).append(bytes(msg.data))
    return got


@pytest.mark.parametrize("back", ["modbus", "dcon"])
async def test_the_gateway_starts_without_its_port_and_recovers_when_it_appears(
    back, registry, tmp_path
):
    co, dn = f"pm-co-{uuid.uuid4().hex[:8]}", f"pm-dn-{uuid.uuid4().hex[:8]}"
    pty = PluggablePty(tmp_path / "ttyUSB0")
    pty.unplug()  # the USB-RS485 adapter is not plugged in at start
    gateway = Gateway.load(port_faults.topology(back, pty.a, tmp_path, co, dn), registry=registry)
    back_cfg = gateway.topology.backs[0]
    simulator = registry.simulators[back_cfg.type](back_cfg, pty.b, False)
    await simulator.start()
    bus = can.Bus(interface="virtual", channel=co, receive_own_messages=False)
    events: list = []
    gateway.context.events.subscribe(events.append)
    try:
        await gateway.start()  # no GatewayStartError: the front starts, the node boots
        seen = await frames(bus, 0.5)
        assert seen[0x700 + NODE][:1] == [b"\x00"]
        emcys = seen.get(0x80 + NODE, [])
        assert COM_PORT_ERROR in emcys, emcys  # beside the modules' 00 FF 81 0B <address>
        addresses = [m.address for m in back_cfg.modules]
        assert {bytes([0x00, 0xFF, 0x81, 0x0B, a, 0, 0, 0]) for a in addresses} <= set(emcys)
        assert [gateway.health.get("rs485", a).online for a in addresses] == [False] * len(
            addresses
        )
        assert {c.quality for c in gateway.image.channels(back="rs485")} == {Quality.COMM_FAULT}
        status = gateway.status()["backs"]["rs485"]
        assert status["port"]["lost"] is True
        assert gateway.health.ports_lost.keys() == {"rs485"}
        assert [e.kind for e in events if e.kind in (PORT_LOST, PORT_BACK)] == [PORT_LOST]
        node = gateway.component("plc").node
        assert node.emcy.is_active(0x5000) and node.emcy.register & 0x81 == 0x81

        pty.plug()  # the port appears: opened at the next back-off try (<= offline_probe_ms)
        await port_faults.wait_until(
            lambda: all(gateway.health.get("rs485", a).online for a in addresses), 5, "online"
        )
        await port_faults.wait_until(lambda: not node.emcy.is_active(0x5000), 2, "EMCY cleared")
        after = (await frames(bus, 0.3)).get(0x80 + NODE, [])
        assert bytes(8) in after  # the last error ended: error reset
        status = gateway.status()["backs"]["rs485"]
        assert status["port"]["lost"] is False and status["restarts"] == 0
        assert not gateway.health.ports_lost
        assert [e.kind for e in events if e.kind in (PORT_LOST, PORT_BACK)] == [
            PORT_LOST,
            PORT_BACK,
        ]
    finally:
        await gateway.stop()
        await simulator.stop()
        bus.shutdown()
        pty.close()


async def test_wrong_settings_still_stop_the_start(registry, tmp_path):
    """A port that cannot be right later (an invalid pyserial URL) is a start error, as before."""
    topo = port_faults.topology("modbus", "nosuchscheme://x", tmp_path, "a", "b")
    gateway = Gateway.load(topo, registry=registry)
    with pytest.raises(Exception) as err:
        await gateway.start()
    assert "rs485" in str(err.value)
