"""One fuzz target per wire, each turning a fuzz buffer into protocol input for a real
engine and checking after it that the engine still does its job (docs/reliability.md,
scripts/faults/fuzz.py). The targets live in fuzz_can.py, fuzz_serial.py, fuzz_yaml.py,
fuzz_opcua.py (the OPC UA front's binary headers and Hello, against its server) and
fuzz_mbtcp.py (the Modbus TCP server's); their common parts in fuzz_base.py."""

from __future__ import annotations

from fuzz_base import Bytes, InvariantBroken, Target, run_sync
from fuzz_can import DeviceNetTarget, NmtLssTarget, PdoTarget, SdoTarget, SyncTimeEmcyTarget
from fuzz_mbtcp import ModbusTcpSocketTarget, ModbusTcpTarget
from fuzz_opcua import OpcUaTarget
from fuzz_serial import DconTarget, ModbusTarget
from fuzz_yaml import YamlTarget

TARGETS: dict[str, type[Target]] = {
    t.name: t
    for t in (
        SdoTarget,
        NmtLssTarget,
        PdoTarget,
        SyncTimeEmcyTarget,
        DeviceNetTarget,
        ModbusTarget,
        DconTarget,
        ModbusTcpTarget,
        ModbusTcpSocketTarget,
        YamlTarget,
        OpcUaTarget,
    )
}
FULL_INPUTS = {name: 1_000_000 for name in TARGETS} | {
    "yaml": 20_000,
    "opcua": 200_000,
    "modbus_tcp_socket": 100_000,
}

__all__ = ["FULL_INPUTS", "TARGETS", "Bytes", "InvariantBroken", "Target", "run_sync"]
