"""The serial timing model on a real wire: ptys paced byte by byte at the baud rate by the
test's own relay (tests/paced_wire.py), the back against the plugin's simulator.

A 125-register reply at 9600 baud is 255 bytes, 266 ms on the wire: longer than the
default ``timeout_ms: 200``. The response timeout runs to the first byte only, so the
reply is read whole and no module goes offline (before: both modules of the line did).
"""

from __future__ import annotations

import asyncio
import contextlib

import pytest
from paced_wire import PacedWire, SimulatorProcess

from fieldgate import Gateway, Quality
from fieldgate.health import ErrorKind
from fieldgate.plugins.modbus.client import ModbusLink
from fieldgate.plugins.modbus.codec import read_registers_response
from fieldgate.polling import CommError

BIG = {
    "address": 1,
    "channels": [{"kind": "ai", "table": "input_registers", "address": 0, "count": 125}],
}
SMALL = {"address": 2, "model": "M-7052D"}


async def wait_for(condition, timeout=15.0):
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        assert loop.time() < deadline, "condition not met in time"
        await asyncio.sleep(0.02)


def topology(port: str, modules: list[dict] | None = None, **back) -> dict:
    return {
        "gateway": {"name": "timing"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": port,
                "baudrate": 9600,
                "timeout_ms": 200,  # the default: shorter than the 266 ms reply
                # the test's relay is a process a loaded CI host may pause inside a frame
                "byte_timeout_ms": 150,
                "poll_ms": 0,
                "modules": modules or [BIG, SMALL],
                **back,
            }
        ],
    }


async def test_a_266_ms_reply_with_timeout_200_keeps_every_module_online(registry, tmp_path):
    assert len(read_registers_response(1, 4, [0] * 125)) == 255  # 255 x 10 bits at 9600: 266 ms
    sets = ("rs485/m1/ai124=4321", "rs485/m2/di5=1")
    with (
        PacedWire(9600) as wire,
        SimulatorProcess.modbus(topology(wire.b), wire.b, str(tmp_path), sets),
    ):
        gateway = Gateway.load(topology(wire.a), registry=registry)
        await gateway.start()
        try:
            big, small = gateway.health.get("rs485", 1), gateway.health.get("rs485", 2)
            await wait_for(lambda: big.requests >= 6 and small.requests >= 6)
            assert big.online and small.online
            assert big.error_counter == 0 and small.error_counter == 0, (
                big.last_error or small.last_error
            )
            assert gateway.read("rs485/m1/ai124") == 4321
            assert gateway.image["rs485/m1/ai124"].quality is Quality.GOOD
            assert gateway.read("rs485/m2/di5") is True
        finally:
            await gateway.stop()


@contextlib.asynccontextmanager
async def link_on(wire: PacedWire, folder, modules: list[dict], **link):
    """A ModbusLink on end a of the wire, the simulator in its own process on end b."""
    with SimulatorProcess.modbus(topology(wire.b, modules=modules), wire.b, str(folder)) as sim:
        modbus = ModbusLink(wire.a, baudrate=9600, **link)
        await modbus.open()
        try:
            yield modbus, sim
        finally:
            modbus.close()


async def test_a_reply_that_starts_before_the_response_timeout_is_read_whole(tmp_path):
    with PacedWire(9600) as wire:
        async with link_on(wire, tmp_path, [BIG], timeout=0.2) as (link, sim):
            sim.command("set rs485/m1/ai124 -5")
            sim.command("fault 1 delay 1 delay=0.05")  # starts ~80 ms, ends ~350 ms
            registers = await link.read_registers(1, 4, 0, 125)
            assert registers[124] == 0xFFFB and link.stats.errors == {}


async def test_after_a_broken_frame_the_next_request_waits_for_line_silence(tmp_path):
    with PacedWire(9600) as wire:
        async with link_on(wire, tmp_path, [BIG, SMALL], timeout=0.2) as (link, sim):
            sim.command("set rs485/m2/di0 1")
            wire.corrupt(after=2, value=0x10)  # byte count 250 arrives as 16
            with pytest.raises(CommError) as info:
                await link.read_registers(1, 4, 0, 125)
            assert info.value.kind is ErrorKind.CRC  # a 21-byte frame with a bad CRC
            # the rest of that reply (234 bytes, 244 ms) is still coming: the next request
            # waits until the line is quiet, so its reply is not mixed with that tail
            assert (await link.read_bits(2, 2, 32, 8))[0] is True
            assert link.stats.errors == {ErrorKind.CRC: 1}


@pytest.mark.parametrize("echo", [True, "auto"])
async def test_an_echoing_adapter_the_echo_of_an_fc6_write_is_not_taken_for_the_reply(
    echo, tmp_path
):
    with PacedWire(9600, echo=True) as wire:
        modules = [SMALL, {"address": 4, "model": "M-7024"}]
        async with link_on(wire, tmp_path, modules, echo=echo) as (link, sim):
            assert (await link.read_bits(2, 2, 32, 8)) == [False] * 8  # auto decides here
            assert link.echo.detected is True
            await link.write(4, 6, 0, [1234])
            assert await link.read_registers(4, 3, 0, 1) == [1234]
            await link.write(4, 6, 0, [77])
            assert await link.read_registers(4, 3, 0, 1) == [77]
            # a module that does not answer: its write's echo alone is no reply
            with pytest.raises(CommError) as info:
                await link.write(9, 6, 0, [1])
            assert info.value.kind is ErrorKind.TIMEOUT


async def test_echo_false_on_an_echoing_line_fails_reads_it_never_reads_the_echo_as_data(
    tmp_path,
):
    with PacedWire(9600, echo=True) as wire:
        async with link_on(wire, tmp_path, [SMALL], echo=False) as (link, _):
            with pytest.raises(CommError) as info:
                await link.read_bits(2, 2, 32, 8)
            assert info.value.kind in (ErrorKind.CRC, ErrorKind.GARBAGE)


async def test_echo_true_without_an_echo_says_so(tmp_path):
    with PacedWire(9600) as wire:
        async with link_on(wire, tmp_path, [SMALL], echo=True, timeout=0.05) as (link, _):
            with pytest.raises(CommError) as info:
                await link.read_bits(2, 2, 32, 8)
            assert info.value.kind is ErrorKind.GARBAGE and "echo" in str(info.value)


def test_validate_warns_when_a_line_cannot_poll_its_modules_within_poll_ms(tmp_path, capsys):
    import json

    from fieldgate.cli import main

    path = tmp_path / "slow.yaml"
    path.write_text(json.dumps(topology("/dev/ttyUSB0", poll_ms=100)))
    assert main(["validate", str(path)]) == 0
    out = capsys.readouterr().out
    # 125 registers: 8 + 255 bytes; 8 DI: 8 + 6 bytes; 10 bits a character; t3.5 before each
    assert (
        "warning: backs.rs485: one poll of every module takes 305 ms on the wire at 9600 baud"
        in out
    )
    assert "305 % booked" in out
    path.write_text(json.dumps(topology("/dev/ttyUSB0", poll_ms=400)))
    assert main(["validate", str(path)]) == 0
    assert "warning" not in capsys.readouterr().out
