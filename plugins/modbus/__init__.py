"""The modbus backs: Modbus RTU on RS-485 lines and Modbus TCP to devices on Ethernet.

Each with its simulator and scan:

* back type ``modbus`` (:class:`~.back.ModbusBack`, config :class:`~.config.ModbusBackConfig`)
* back type ``modbus-tcp-client`` (:class:`~.tcp_back.ModbusTcpClientBack`, config
  :class:`~.tcp_config.ModbusTcpClientBackConfig`): devices by host and unit id
* simulators for ``fieldgate run --simulate``, ``fieldgate simulate`` and tests
  (:class:`~.simulator.ModbusSimulator`, :class:`~.tcp_simulator.ModbusTcpSimulator`)
* ``fieldgate scan modbus`` / ``scan modbus-tcp-client``: unit ids that answer (:mod:`.scan`,
  :mod:`.tcp_scan`)
* device models (the topology's ``models:``, a CSV register map): :mod:`.models`

See docs/modbus.md and docs/modbus-tcp-client.md.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from fieldgate.plugin import GatewayContext, Registry, SimulateCli, hookimpl

from .back import ModbusBack
from .config import ModbusBackConfig, ModbusModuleConfig
from .groups import ChannelGroup
from .models import ModbusDeviceModel
from .scan import ModbusScanner
from .tcp_config import ModbusTcpClientBackConfig, ModbusTcpDeviceConfig
from .tcp_scan import ModbusTcpScanner

if TYPE_CHECKING:
    from .simulator import Fault, ModbusSimulator
    from .tcp_back import ModbusTcpClientBack
    from .tcp_simulator import ModbusTcpSimulator

__all__ = [
    "ChannelGroup",
    "Fault",
    "ModbusBack",
    "ModbusBackConfig",
    "ModbusModuleConfig",
    "ModbusSimulator",
    "ModbusTcpClientBack",
    "ModbusTcpClientBackConfig",
    "ModbusTcpDeviceConfig",
    "ModbusTcpSimulator",
]

# Loaded when first used (issue 33): a gateway on an RS-485 line does not carry the Modbus
# TCP client's modules, nor a deployed one the simulators'.
_LAZY = {
    "Fault": ".simulator",
    "ModbusSimulator": ".simulator",
    "ModbusTcpClientBack": ".tcp_back",
    "ModbusTcpSimulator": ".tcp_simulator",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _simulator(config: ModbusBackConfig, port: str, animate: bool = False) -> ModbusSimulator:
    from .simulator import ModbusSimulator

    return ModbusSimulator(config, port, animate)


def _tcp_back(config: ModbusTcpClientBackConfig, context: GatewayContext) -> ModbusTcpClientBack:
    from .tcp_back import ModbusTcpClientBack

    return ModbusTcpClientBack(config, context)


def _tcp_simulator(
    config: ModbusTcpClientBackConfig, port: None = None, animate: bool = False
) -> ModbusTcpSimulator:
    from .tcp_simulator import ModbusTcpSimulator

    return ModbusTcpSimulator(config, animate)


def _tcp_simulate_options(group: Any) -> None:
    group.add_argument(
        "--listen",
        default="127.0.0.1:5020",
        metavar="HOST:PORT",
        help="where the simulated devices of --module answer (a loopback address; default "
        "127.0.0.1:5020)",
    )


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
    registry.add_back(
        "modbus-tcp-client",
        ModbusTcpClientBackConfig,
        _tcp_back,
        "Modbus TCP client (meters, drives, PLCs, TCP/RTU gateways on Ethernet)",
    )
    registry.add_simulator(
        "modbus-tcp-client",
        _tcp_simulator,
        SimulateCli(
            module_example="1:M-7017R",
            configure=_tcp_simulate_options,
            fields=lambda args: {"host": args.listen},
        ),
    )
    registry.add_scanner("modbus-tcp-client", ModbusTcpScanner())
    registry.add_model(
        "modbus", ModbusDeviceModel, "a Modbus device's channel groups, or its CSV register map"
    )
