"""``--simulate`` for every kind of back: a serial back gets a pty end, any other back gets
``port=None`` and is pointed at what its simulator serves; a back without a simulator stops
``--simulate`` with one line naming it, before anything starts."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from fieldgate import Back, ChannelSpec, Gateway, Kind, Source, channel_id, hookimpl, load_registry
from fieldgate.plugin import Simulator
from fieldgate.runtime import GatewayStartError
from fieldgate.topology import BackConfig

REPO = Path(__file__).resolve().parents[2]
MAILBOXES: dict[str, dict[str, Any]] = {}  # what a "mailbox" device holds, by name


class MailboxConfig(BackConfig):
    """A back that is not serial: it reads one input from a named mailbox."""

    mailbox: str = "plant"

    def channel_specs(self) -> list[ChannelSpec]:
        return [ChannelSpec(channel_id(self.name, 1, Kind.AI, 0), Kind.AI, Source(self.name, 1, 0))]


class MailboxBack(Back):
    async def start(self) -> None:
        if self.config.mailbox not in MAILBOXES:
            from fieldgate import PluginStartError

            raise PluginStartError(f"no mailbox {self.config.mailbox}")

    async def run(self) -> None:
        while True:
            value = MAILBOXES[self.config.mailbox].get("level", 0)
            self.context.image.update_input(channel_id(self.name, 1, Kind.AI, 0), value)
            await asyncio.sleep(0.01)

    async def stop(self) -> None:
        pass


class MailboxSimulator(Simulator):
    def __init__(self, config: MailboxConfig):
        self.box = f"simulated-{config.name}"
        config.mailbox = self.box  # the back reads what the simulator serves
        self.started = False

    async def start(self) -> None:
        MAILBOXES[self.box] = {}
        self.started = True

    async def stop(self) -> None:
        MAILBOXES.pop(self.box, None)

    def set_input(self, channel_id: str, value: bool | int | float) -> None:
        MAILBOXES[self.box]["level"] = value

    def get_output(self, channel_id: str) -> bool | int | float:
        raise KeyError(channel_id)


class MailboxPlugin:
    PLUGIN_NAME = "mailbox"

    def __init__(self) -> None:
        self.ports: list[Any] = []

    @hookimpl
    def fieldgate_register(self, registry):
        registry.add_back("mailbox", MailboxConfig, MailboxBack)

        def simulator(config: MailboxConfig, port: str | None, animate: bool) -> Simulator:
            self.ports.append(port)
            return MailboxSimulator(config)

        registry.add_simulator("mailbox", simulator)


def topology(*backs: dict[str, Any]) -> dict[str, Any]:
    return {
        "gateway": {"name": "sim"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": list(backs),
    }


MODBUS = {"name": "rs485", "type": "modbus", "port": "/dev/ttyUSB7", "parity": "E",
          "modules": [{"address": 1, "model": "M-7052D"}]}  # fmt: skip


async def test_a_back_that_is_not_serial_is_served_by_its_simulator_and_a_serial_one_by_a_pty():
    plugin = MailboxPlugin()
    registry = load_registry(extra_plugins=[plugin])
    gw = Gateway.load(
        topology({"name": "tank", "type": "mailbox"}, MODBUS), registry=registry, simulate=True
    )
    async with gw:
        assert plugin.ports == [None]  # not serial: no pty, the simulator chose its resource
        assert gw.topology.backs[0].mailbox == "simulated-tank"
        modbus = gw.topology.backs[1]
        assert modbus.port.startswith("/dev/pts/") and modbus.parity == "N"  # a pty end
        gw.bench.simulator("tank").set_input("tank/m1/ai0", 421)
        async with asyncio.timeout(5):
            while gw.read("tank/m1/ai0") != 421:
                await asyncio.sleep(0.01)
    assert "simulated-tank" not in MAILBOXES  # the simulator was stopped with the gateway


async def test_backs_without_a_simulator_are_named_in_one_line_and_nothing_starts():
    registry = load_registry()
    loop = {"type": "loopback", "modules": [{"address": 1, "digital": 1}]}
    gw = Gateway.load(
        topology({"name": "a", **loop}, MODBUS, {"name": "b", **loop}),
        registry=registry,
        simulate=True,
    )
    with pytest.raises(GatewayStartError) as failed:
        await gw.start()
    assert str(failed.value) == (
        "--simulate: no simulator for back a (loopback), back b (loopback): "
        "their plugins offer none"
    )
    assert gw.topology.backs[1].port == "/dev/ttyUSB7"  # no pty was opened for the others
    assert gw.backs == [] and gw.bench.simulators == {}


def test_run_simulate_with_a_back_without_simulator_is_one_line_and_exit_2(tmp_path):
    file = tmp_path / "loop.yaml"
    file.write_text(
        "gateway: {name: loop}\nfronts: [{name: plc, type: memory}]\n"
        "backs: [{name: io, type: loopback, modules: [{address: 1, digital: 2}]}]\n"
    )
    result = subprocess.run(
        [sys.executable, "-m", "fieldgate", "run", str(file), "--simulate", "--duration", "5"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and errors[0].endswith(
        "cannot start: --simulate: no simulator for back io (loopback): its plugin offers none"
    ), result.stderr
