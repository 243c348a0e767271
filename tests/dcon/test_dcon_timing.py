"""The serial timing model on a real wire for the DCON back: ptys paced byte by byte at the
baud rate by the test's own relay (tests/paced_wire.py), against the plugin's simulator."""

from __future__ import annotations

import pytest
from paced_wire import PacedWire, SimulatorProcess

from fieldgate import Gateway, Quality

MODULES = [
    {"address": 1, "model": "I-7017"},  # 8 AI in hex: a 34-byte reply
    {"address": 2, "model": "I-7055"},
]


def topology(port: str, echo) -> dict:
    back = {"port": port, "baudrate": 2400, "timeout_ms": 100, "poll_ms": 10, "echo": echo}
    # the test's relay is a process that a loaded CI host may pause for tens of ms inside a
    # frame (a wire does not): a pause above the inter-byte timeout would end the frame early
    back["byte_timeout_ms"] = 150
    return {
        "gateway": {"name": "dcon-timing"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [{"name": "rs485", "type": "dcon", **back, "modules": MODULES}],
    }


@pytest.mark.parametrize("echo", [False, True, "auto"])
async def test_replies_longer_than_the_timeout_and_an_echo_keep_every_module_online(
    dcon_registry, wait_for, echo
):
    # 2400 baud: the I-7017's reply takes 142 ms on the wire, its response timeout is 100 ms
    with (
        PacedWire(2400, echo=echo is not False) as wire,
        SimulatorProcess(
            "dcon",
            "--port",
            wire.b,
            "--baudrate",
            "2400",
            "--module",
            "1:I-7017",
            "--module",
            "2:I-7055",
        ),
    ):
        gateway = Gateway.load(topology(wire.a, echo), registry=dcon_registry)
        await gateway.start()
        try:
            ai, dio = gateway.health.get("rs485", 1), gateway.health.get("rs485", 2)
            await wait_for(lambda: ai.requests >= 4 and dio.requests >= 4, timeout=20)
            gateway.write("rs485/m2/do3", True)
            back = gateway.component("rs485")
            await wait_for(lambda: back.scheduler.pending_writes == 0, timeout=10)
            assert ai.online and dio.online
            assert ai.error_counter == 0 and dio.error_counter == 0, ai.last_error or dio.last_error
            assert gateway.image["rs485/m1/ai7"].quality is Quality.GOOD
            line = gateway.component("rs485").dcon
            assert line.echo.detected is (echo is not False)
        finally:
            await gateway.stop()
