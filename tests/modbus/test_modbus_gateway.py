"""End to end: a gateway with the modbus back on simulated modules, and ``fieldgate simulate
modbus`` (the command core serves for every back with a simulator)."""

import argparse
import asyncio
import os
import re
import signal
import subprocess
import sys

import pytest
from modbus_line import I7232D_MODULES

from fieldgate import Quality, load_registry
from fieldgate.plugins.modbus.client import ModbusLink
from fieldgate.plugins.modbus.config import ModbusBackConfig
from fieldgate.plugins.modbus.simulator import ModbusSimulator
from fieldgate.simcmd import UsageError, build_config
from fieldgate.simcmd import execute as run_command
from fieldgate.testing import assert_channel, wait_for_channel, wait_until


def demo_topology():
    modules = [dict(m) for m in I7232D_MODULES]
    modules[1] |= {"error_modes": {"do0": {"value": 1}}, "shutdown_mode": {"value": 0}}
    return {
        "gateway": {"name": "demo"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 10,
                "timeout_ms": 50,
                "modules": modules,
            }
        ],
    }


async def test_the_demo_loop_runs_through_gateway_and_simulator(fieldgate_gateway):
    async with fieldgate_gateway(demo_topology(), animate=True) as gateway:
        sim = gateway.bench.simulator("rs485")
        image = gateway.image
        await wait_for_channel(image, "rs485/m1/di0")  # read, good
        gateway.write("rs485/m3/do2", True)  # DO of the M-7055D, wired to the M-7052D's DI
        await wait_for_channel(image, "rs485/m1/di2", True)
        assert sim.get_output("rs485/m3/do2") is True
        gateway.write("rs485/m4/ao0", 0x3FFF)  # 5 V out of the M-7024 into the M-7017R
        await wait_for_channel(image, "rs485/m5/ai0", 0x3FFF)
        gateway.component("plc").lose_master()  # do0 goes to its error value 1
        await wait_until(lambda: sim.get_output("rs485/m3/do0") is True)
        status = gateway.status()["backs"]["rs485"]
        assert status["modbus"]["requests"]["fc2"] > 0 and status["cycles"] > 0
        assert {m["address"]: m["online"] for m in status["modules"]} == {
            1: True,
            3: True,
            4: True,
            5: True,
        }
    assert sim.get_output("rs485/m3/do0") is False  # shutdown value written before the line closed


async def test_a_dead_module_in_the_gateway_goes_comm_fault_and_comes_back(fieldgate_gateway):
    topology = demo_topology()
    topology["backs"][0] |= {"offline_probe_ms": 100, "timeout_ms": 50}
    async with fieldgate_gateway(topology) as gateway:
        sim = gateway.bench.simulator("rs485")
        image = gateway.image
        sim.set_input("rs485/m5/ai0", 77)
        await wait_for_channel(image, "rs485/m5/ai0", 77)
        from fieldgate.plugins.modbus.simulator import Fault

        sim.inject(5, Fault("no_answer"))
        await wait_for_channel(image, "rs485/m5/ai0", 77, Quality.COMM_FAULT)  # the last value
        assert not gateway.health.get("rs485", 5).online and gateway.health.get("rs485", 1).online
        sim.clear_faults()
        await wait_for_channel(image, "rs485/m5/ai0", 77, Quality.GOOD)
        sim.inject(1, Fault("exception", code=2, address=34))  # the M-7052D refuses DI2
        await wait_for_channel(image, "rs485/m1/di2", quality=Quality.CONFIG_ERROR)
        assert gateway.status()["backs"]["rs485"]["modbus"]["refused_points"] == ["rs485/m1/di2"]
        assert_channel(image, "rs485/m1/di3")  # good


def execute(sim: ModbusSimulator, line: str) -> str:
    return run_command(sim, list(sim.channels), line)


def test_cli_commands():
    config = ModbusBackConfig(name="rs485", port="unused", modules=I7232D_MODULES)
    sim = ModbusSimulator(config, "unused")
    assert execute(sim, "set rs485/m1/di3 on") == "rs485/m1/di3 = True"
    assert execute(sim, "get rs485/m5/ai0") == "rs485/m5/ai0 = 0"
    assert execute(sim, "fault 5 delay 2 delay=0.3") == "module 5: delay for 2 replies"
    assert sim.modules[5].faults[0].delay == 0.3
    assert execute(sim, "clear") == "faults cleared" and not sim.modules[5].faults
    assert execute(sim, "set rs485/m3/do0 1").startswith("error: rs485/m3/do0 is an output")
    assert execute(sim, "fault 9 crc").startswith("error: no simulated module at address 9")
    assert "rs485/m4/ao0 = 0" in execute(sim, "show")
    assert execute(sim, "help").startswith("commands:")
    assert execute(sim, "quit") == "quit"


async def test_fieldgate_simulate_modbus_serves_a_pty(tmp_path):
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "fieldgate",
        "simulate",
        "modbus",
        "--pty",
        "--module",
        "1:M-7052D",
        "--module",
        "3:M-7055D",
        "--baudrate",
        "115200",
        "--input",
        "rs485/m1/di0=1",
        "--duration",
        "20",
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        banner = (await asyncio.wait_for(proc.stdout.readline(), 10)).decode()
        match = re.search(r"point the gateway at (\S+)", banner)
        assert match, banner
        link = ModbusLink(match.group(1), baudrate=115200, timeout=0.5, inter_frame=0)
        await link.open()
        try:
            assert (await link.read_bits(1, 2, 32, 8))[0] is True
            await link.write(3, 5, 4, [True])
            assert (
                await asyncio.wait_for(proc.stdout.readline(), 5)
            ).decode().strip() == "output rs485/m3/do4 = True"
            proc.stdin.write(b"set rs485/m1/di7 1\n")
            await proc.stdin.drain()
            assert (
                await asyncio.wait_for(proc.stdout.readline(), 5)
            ).decode().strip() == "rs485/m1/di7 = True"
            assert (await link.read_bits(1, 2, 32, 8))[7] is True
        finally:
            link.close()
        proc.stdin.write(b"quit\n")
        await proc.stdin.drain()
        assert await asyncio.wait_for(proc.wait(), 10) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_fieldgate_simulate_modbus_stops_with_exit_0_on_ctrl_c_and_sigterm(stopped_by_signal, sig):
    """Ctrl-C is how a simulator is stopped: exit 0, no traceback, even while stdin is a
    terminal with a read pending (it used to hang there, or exit 130)."""
    code, stderr = stopped_by_signal(
        ["simulate", "modbus", "--pty", "--module", "1:M-7055D"],
        "simulating back rs485 (modbus): modules 1 (M-7055D)",
        sig,
    )
    assert code == 0 and "Traceback" not in stderr


def test_simulate_modbus_takes_baud_as_an_alias_of_baudrate(capsys):
    from fieldgate import load_registry
    from fieldgate.cli import build_parser

    parser = build_parser(load_registry())
    command = ["simulate", "modbus", "--pty", "--module", "1:M-7055D"]
    assert (
        parser.parse_args([*command, "--baud", "19200"]).baudrate
        == parser.parse_args([*command, "--baudrate", "19200"]).baudrate
        == 19200
    )
    assert parser.parse_args(command).baudrate is None  # the topology's, or 9600
    with pytest.raises(SystemExit):
        parser.parse_args([*command, "--help"])
    usage = capsys.readouterr().out
    assert "--baudrate" in usage and "--baud " not in usage


def test_cli_fault_limited_to_an_address():
    sim = ModbusSimulator(
        ModbusBackConfig(name="rs485", port="unused", modules=I7232D_MODULES), "unused"
    )
    assert (
        execute(sim, "fault 5 exception code=2 address=0")
        == "module 5: exception on requests touching address 0 until cleared"
    )
    (fault,) = sim.modules[5].faults
    assert (fault.code, fault.address, fault.count) == (2, 0, None)


def test_cli_takes_the_modules_from_a_topology(tmp_path):
    path = tmp_path / "plant.yaml"
    path.write_text(
        "gateway: {name: plant}\nfronts: [{name: plc, type: memory}]\nbacks:\n"
        "  - {name: line2, type: modbus, port: /dev/ttyUSB0, baudrate: 19200, modules: [{address: 7, model: M-7060D}]}\n"
    )
    registry = load_registry()
    args = argparse.Namespace(
        port="/dev/pts/99",
        pty=False,
        topology=str(path),
        back=None,
        module=[],
        name="rs485",
        baudrate=None,
        set=[],
    )
    config = build_config(args, registry, "modbus")
    assert (config.name, config.port, config.baudrate) == ("line2", "/dev/pts/99", 19200)
    assert "line2/m7/do3" in {s.id for s in config.channel_specs()}
    args.back = "nope"
    with pytest.raises(UsageError, match="has no modbus back named nope"):
        build_config(args, registry, "modbus")
    with pytest.raises(UsageError, match="expects ADDRESS:MODEL"):
        build_config(
            argparse.Namespace(
                port="x",
                pty=False,
                topology=None,
                back=None,
                module=["M-7060D"],
                name="rs485",
                baudrate=None,
                set=[],
            ),
            registry,
            "modbus",
        )


def test_the_old_set_channel_value_still_sets_an_input_with_a_deprecation_note():
    result = subprocess.run(
        [sys.executable, "-m", "fieldgate", "simulate", "modbus", "--pty"]
        + ["--module", "1:M-7052D", "--set", "rs485/m1/di0=1", "--duration", "20"],
        input="get rs485/m1/di0\nquit\n",
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 0, result.stderr
    assert "rs485/m1/di0 = True" in result.stdout.splitlines()
    assert result.stderr.strip() == (
        "fieldgate: '--set CHANNEL=VALUE' is deprecated and goes away in the next release; "
        "use '--input CHANNEL=VALUE'"
    )
