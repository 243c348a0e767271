"""fieldgate.plugins.modbus: Modbus RTU master back end and Modbus module simulator.

* back type ``modbus`` (:class:`~.back.ModbusBack`, config :class:`~.config.ModbusBackConfig`)
* simulator for ``fieldgate run --simulate`` and tests (:class:`~.simulator.ModbusSimulator`)
* ``fieldgate simulate modbus`` (:mod:`.cli`)

See docs/modbus.md.
"""

from __future__ import annotations

from fieldgate.plugin import hookimpl

from . import cli
from .back import ModbusBack
from .config import ChannelGroup, ModbusBackConfig, ModbusModuleConfig
from .simulator import Fault, ModbusSimulator

__all__ = [
    "ChannelGroup",
    "Fault",
    "ModbusBack",
    "ModbusBackConfig",
    "ModbusModuleConfig",
    "ModbusSimulator",
]


def _simulator(config: ModbusBackConfig, port: str, animate: bool = False) -> ModbusSimulator:
    return ModbusSimulator(config, port, animate)


@hookimpl
def fieldgate_register(registry) -> None:
    registry.add_back(
        "modbus",
        ModbusBackConfig,
        ModbusBack,
        "Modbus RTU master (RS-485 I/O modules such as ICP DAS M-7000)",
    )
    registry.add_simulator("modbus", _simulator)
    registry.add_command(
        ("simulate", "modbus"),
        "simulated Modbus RTU modules on a serial port or pty",
        cli.configure,
        cli.run,
    )
