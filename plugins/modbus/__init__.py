"""The ``modbus`` back: a Modbus RTU master of RS-485 I/O modules, their simulator and scan.

* back type ``modbus`` (:class:`~.back.ModbusBack`, config :class:`~.config.ModbusBackConfig`)
* simulator for ``fieldgate run --simulate``, ``fieldgate simulate modbus`` and tests
  (:class:`~.simulator.ModbusSimulator`)
* ``fieldgate scan modbus``: unit ids that answer, at one baud rate or several (:mod:`.scan`)

See docs/modbus.md.
"""

from __future__ import annotations

from fieldgate.plugin import Registry, hookimpl

from .back import ModbusBack
from .config import ChannelGroup, ModbusBackConfig, ModbusModuleConfig
from .scan import ModbusScanner
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
def fieldgate_register(registry: Registry) -> None:
    registry.add_back(
        "modbus",
        ModbusBackConfig,
        ModbusBack,
        "Modbus RTU master (RS-485 I/O modules such as ICP DAS M-7000)",
    )
    registry.add_simulator("modbus", _simulator)
    registry.add_scanner("modbus", ModbusScanner())
