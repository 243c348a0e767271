"""The serial timing model on a real wire for the DCON back: ptys paced byte by byte at the
baud rate by the test's own relay (tests/paced_wire.py), against the plugin's simulator."""

from __future__ import annotations

import pytest
from paced_wire import PacedWire

from fieldgate import Gateway, Quality
from fieldgate.plugins.dcon.simulator import DconSimulator

MODULES = [
    {"address": 1, "model": "I-7017", "data_format": "engineering"},  # 8 AI: a 58-byte reply
    {"address": 2, "model": "I-7055"},
]


def topology(port: str, echo) -> dict:
    back = {"port": port, "baudrate": 2400, "timeout_ms": 100, "poll_ms": 10, "echo": echo}
    return {
        "gateway": {"name": "dcon-timing"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [{"name": "rs485", "type": "dcon", **back, "modules": MODULES}],
    }


@pytest.mark.parametrize("echo", [False, True, "auto"])
async def test_replies_longer_than_the_timeout_and_an_echo_keep_every_module_online(
    dcon_registry, wait_for, echo
):
    # 2400 baud: the I-7017's reply takes 242 ms on the wire, its response timeout is 100 ms
    with PacedWire(2400, echo=echo is not False) as wire:
        gateway = Gateway.load(topology(wire.a, echo), registry=dcon_registry)
        sim = DconSimulator.from_config(gateway.topology.backs[0], wire.b)
        await sim.start()
        sim.bus.modules[1].ai_raw[7] = 0x1234
        await gateway.start()
        try:
            ai, dio = gateway.health.get("rs485", 1), gateway.health.get("rs485", 2)
            await wait_for(lambda: ai.requests >= 4 and dio.requests >= 4, timeout=20)
            gateway.write("rs485/m2/do3", True)
            await wait_for(lambda: sim.bus.modules[2].do_bits == 0x08, timeout=10)
            assert ai.online and dio.online
            assert ai.error_counter == 0 and dio.error_counter == 0, ai.last_error or dio.last_error
            assert gateway.image["rs485/m1/ai7"].quality is Quality.GOOD
            line = gateway.component("rs485").dcon
            assert line.echo.detected is (echo is not False)
        finally:
            await gateway.stop()
            await sim.stop()
