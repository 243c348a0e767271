"""The DCON module simulator on a serial port (a pty end in tests and demos).

Python API::

    sim = DconSimulator.from_modules("/dev/pts/5", [(1, "I-7043"), (2, "I-7053"), (4, "I-7012")])
    await sim.start()
    sim.set_input("rs485/m2/di0", True)      # or sim.bus.modules[2].di_bits = 0x0001
    sim.get_output("rs485/m1/do3")
    sim.inject("silence", address=2)         # faults: silence, bad-checksum, garbage, delay, truncate, wrong-address
    sim.wire((1, "do", 0), (2, "di", 0), invert=True)
    await sim.stop()

``fieldgate simulate dcon`` serves the same from the command line.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import re
from typing import Any

from fieldgate.plugin import PluginStartError, SimulateCli, Simulator
from fieldgate.serial_link import PortServer, cancel_task

from .codec import BAUD_TO_CODE
from .config import DconBackConfig
from .formats import FORMAT_NAMES, DataFormat
from .profiles import find_profile
from .simulated import Fault, SimBus, SimModule, Wire

log = logging.getLogger("fieldgate.dcon.sim")

_CHANNEL = re.compile(r"(?:^|/)m(\d+)/(di|do|ai|ao)(\d+)$")
TICK = 0.02
FAULT_KINDS = ("silence", "bad-checksum", "garbage", "delay", "truncate", "wrong-address")


class DconSimulator(Simulator):
    def __init__(self, port: str, bus: SimBus, *, baudrate: int = 9600, animate: bool = False):
        self.port_name = port
        self.bus = bus
        self.baudrate = baudrate
        self.animate = animate
        self.server = PortServer(port, self._received, baudrate=baudrate)
        self._ticker: asyncio.Task[None] | None = None

    @property
    def replies(self) -> int:
        return self.server.sent

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_config(cls, config: DconBackConfig, port: str, animate: bool = False) -> DconSimulator:
        """The modules a topology's ``dcon`` back declares, with its type codes and formats (hex
        by default); for ``modules: auto``, the modules of its scan file, with their checksum
        setting (a back without one cannot be simulated: nothing says what is on the line)."""
        checksum, modules = config.checksum, config.module_list()
        if config.auto:
            if config.scan_file is None:
                raise PluginStartError(
                    f"back {config.name}: modules: auto can be simulated only from a scan file "
                    f"(scan.file in the topology, or --scan-file {config.name}=FILE)"
                )
            found = config.scan_file.supported()
            checksum = found[0].checksum if found else checksum
        bus = SimBus(checksum=checksum)
        for m in modules:
            fmt = DataFormat.HEX if m.data_format == "auto" else FORMAT_NAMES[m.data_format]
            module = SimModule(
                m.profile,
                m.address,
                type_code=m.type_code,
                data_format=fmt,
                baud_code=BAUD_TO_CODE.get(config.baudrate, 0x06),
            )
            bus.add(module)
        return cls(port, bus, baudrate=config.baudrate, animate=animate)

    @classmethod
    def from_modules(
        cls,
        port: str,
        modules: list[tuple[Any, ...]],
        *,
        checksum: bool = False,
        baudrate: int = 9600,
        animate: bool = False,
    ) -> DconSimulator:
        """``modules``: (address, model[, type_code[, format name]]) tuples."""
        bus = SimBus(checksum=checksum)
        for address, model, *rest in modules:
            profile = find_profile(model)
            if profile is None:
                raise ValueError(f"unknown DCON module {model!r}")
            type_code = rest[0] if rest else None
            fmt = FORMAT_NAMES[rest[1]] if len(rest) > 1 else DataFormat.HEX
            bus.add(
                SimModule(
                    profile,
                    address,
                    type_code=type_code,
                    data_format=fmt,
                    baud_code=BAUD_TO_CODE.get(baudrate, 0x06),
                )
            )
        return cls(port, bus, baudrate=baudrate, animate=animate)

    # -- life cycle ---------------------------------------------------------------------
    async def start(self) -> None:
        self.server.open()
        now = self.server.now
        for module in self.bus.modules.values():
            module.power_cycle(now)
        self._ticker = asyncio.create_task(self._tick())

    async def stop(self) -> None:
        await cancel_task(self._ticker)
        self._ticker = None
        self.server.close()

    async def _tick(self) -> None:
        while True:
            now = self.server.now
            for address in self.bus.tick(now):
                log.info(
                    "simulated module %d: host-watchdog timeout, outputs at safe values", address
                )
            if self.animate:
                self.bus.animate(now)
                self.bus.propagate()
            await asyncio.sleep(TICK)

    def _received(self, data: bytes, now: float) -> None:
        for reply, delay in self.bus.feed(data, now):
            if delay > 0:
                self.server.send_later(delay, reply)
            else:
                self.server.send(reply)

    # -- the Simulator interface -------------------------------------------------------------
    def _locate(self, channel_id: str) -> tuple[SimModule, str, int]:
        match = _CHANNEL.search(channel_id)
        if match is None:
            raise KeyError(f"not a channel id: {channel_id!r}")
        address, kind, index = int(match[1]), match[2], int(match[3])
        module = self.bus.modules.get(address)
        if module is None:
            raise KeyError(f"no simulated module at address {address}")
        limit = {
            "di": module.profile.di,
            "do": module.profile.do,
            "ai": module.profile.ai,
            "ao": module.profile.ao,
        }[kind]
        if index >= limit:
            raise KeyError(f"{module.profile.model} at {address} has no {kind}{index}")
        return module, kind, index

    def set_input(self, channel_id: str, value: bool | int | float) -> None:
        """DI: bool; AI: the raw 16-bit value in the module's hex scale (as the process image holds it)."""
        module, kind, index = self._locate(channel_id)
        if kind == "di":
            module.di_bits = (
                module.di_bits | 1 << index if value else module.di_bits & ~(1 << index)
            )
        elif kind == "ai":
            module.ai_raw[index] = int(value)
        else:
            raise KeyError(f"{channel_id} is an output")

    def get_output(self, channel_id: str) -> bool | int:
        module, kind, index = self._locate(channel_id)
        if kind == "do":
            return bool(module.do_bits >> index & 1)
        if kind == "ao":
            return module.ao_raw[index]
        raise KeyError(f"{channel_id} is an input")

    def get(self, channel_id: str) -> bool | int:
        """Any channel's value in the simulated module (inputs too)."""
        module, kind, index = self._locate(channel_id)
        if kind in ("di", "do"):
            return bool((module.di_bits if kind == "di" else module.do_bits) >> index & 1)
        return (module.ai_raw if kind == "ai" else module.ao_raw)[index]

    def describe(self) -> list[str]:
        return [
            f"module {m.address:3d}: {m.profile.model} ({m.profile.description}), "
            f"type 0x{m.type_code:02X}, {m.data_format.name.lower()}"
            for m in self.bus.modules.values()
        ]

    def command(self, words: list[str]) -> str | None:
        """``fault ADDRESS KIND [COUNT] [delay=S]`` and ``clear`` (``fieldgate simulate dcon``)."""
        cmd, rest = words[0].lower(), words[1:]
        if cmd == "fault" and len(rest) >= 2:
            if rest[1] not in FAULT_KINDS:
                raise ValueError(f"unknown fault {rest[1]!r}; one of: {', '.join(FAULT_KINDS)}")
            address = int(rest[0], 0)
            if address not in self.bus.modules:
                raise KeyError(f"no simulated module at address {address}")
            options = {k: v for k, _, v in (w.partition("=") for w in rest[2:] if "=" in w)}
            counts = [int(w) for w in rest[2:] if w.isdigit()]
            fault = self.inject(
                rest[1],
                address,
                delay=float(options.get("delay", 0.5 if rest[1] == "delay" else 0.0)),
                count=counts[0] if counts else None,
            )
            return f"module {address}: {fault.kind}" + (
                f" for {fault.count} replies" if fault.count else " until cleared"
            )
        if cmd == "clear":
            self.clear_faults()
            return "faults cleared"
        return None

    def commands_help(self) -> str:
        return f"fault ADDRESS {{{'|'.join(FAULT_KINDS)}}} [COUNT] [delay=S] | clear"

    def inject(
        self, kind: str, address: int | None = None, *, delay: float = 0.0, count: int | None = None
    ) -> Fault:
        fault = Fault(kind, address, delay, count)
        self.bus.faults.append(fault)
        return fault

    def clear_faults(self) -> None:
        self.bus.faults.clear()

    def wire(
        self, source: tuple[int, str, int], target: tuple[int, str, int], invert: bool = False
    ) -> None:
        self.bus.wires.append(Wire(source, target, invert))
        self.bus.propagate()

    def module(self, address: int) -> SimModule:
        return self.bus.modules[address]


def simulator_factory(
    back_config: DconBackConfig, port: str, animate: bool = False
) -> DconSimulator:
    return DconSimulator.from_config(back_config, port, animate)


# -- fieldgate simulate dcon -----------------------------------------------------------------
def module_spec(text: str) -> dict[str, Any]:
    """``ADDRESS:MODEL[:TYPE[:FORMAT]]`` (TYPE in hex: ``4:I-7012:08:hex``) as a module mapping."""
    parts = text.split(":")
    if len(parts) < 2 or len(parts) > 4 or not parts[0].strip():
        raise ValueError(f"--module expects ADDRESS:MODEL[:TYPE[:FORMAT]], got {text!r}")
    module: dict[str, Any] = {"address": int(parts[0], 0), "model": parts[1]}
    if len(parts) > 2:
        module["type_code"] = int(parts[2], 0 if parts[2].lower().startswith("0x") else 16)
    if len(parts) > 3:
        module["data_format"] = parts[3]
    return module


def _options(group: argparse._ArgumentGroup) -> None:
    group.add_argument("--checksum", action="store_true", help="modules expect and send checksums")


SIMULATE_CLI = SimulateCli(
    module_metavar="ADDRESS:MODEL[:TYPE[:FORMAT]]",
    module_example="1:I-7043 or 4:I-7012:08:hex",
    module=module_spec,
    configure=_options,
    fields=lambda args: {"checksum": True} if args.checksum else {},
)
