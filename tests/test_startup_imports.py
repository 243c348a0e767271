"""Loading the plugins imports no front's server library: a gateway, `validate` or
`plugins` pays for asyncua (OPC UA) or pymodbus's server with aiohttp (Modbus TCP) only when
its topology has such a front (the fronts' own tests, tests/opcua and tests/modbus_tcp, make
them through the registry). In the SocketCAN guest, where every module is read over
hostfs, these were several seconds of each `fieldgate run` start."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("asyncua", "cryptography", "pymodbus.server", "aiohttp")

PROBE = """
import sys
from fieldgate import load_registry
registry = load_registry()
assert {"opcua", "modbus-tcp"} <= set(registry.type_names("front"))
print(" ".join(name for name in %r if name in sys.modules))
"""


def loaded_after(code: str) -> set[str]:
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    return set(done.stdout.split())


def test_loading_the_plugins_imports_no_server_library():
    assert loaded_after(PROBE % (HEAVY,)) == set()
