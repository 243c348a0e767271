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


# what `fieldgate run` of a fieldbus-only topology leaves unloaded (issue 33, its memory):
# the other commands, the north-facing children's modules, the Modbus TCP client, the
# front's libraries and difflib (suggestions for a wrong name)
NOT_ON_THE_FIELDBUS_PATH = (
    "fieldgate.doctorcmd",
    "fieldgate.statuscmd",
    "fieldgate.simcmd",
    "fieldgate.scancmd",
    "fieldgate.edscmd",
    "fieldgate.isolation.front",
    "fieldgate.isolation.feed",
    "fieldgate.plugins.modbus.tcp_back",
    "fieldgate.plugins.modbus.tcp_link",
    "fieldgate.plugins.modbus.tcp_simulator",
    "fieldgate.plugins.sparkplug",
    "fieldgate.plugins.opcua",
    "pickle",
    "difflib",
    "aiohttp",
    "asyncua",
    "paho",
    "google.protobuf",
)

RUN = """
import sys
from pathlib import Path
from fieldgate.cli import main
example = Path(%r)
code = main(["run", str(example), "--simulate", "--duration", "0.3"])
assert code == 0, code
assert "fieldgate.plugins.modbus.simulator" in sys.modules  # the probe sees what it loaded
print(" ".join(name for name in %r if name in sys.modules))
"""


def test_a_fieldbus_only_gateway_loads_no_module_it_does_not_run(tmp_path):
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "i7232d-style.yaml"
    assert loaded_after(RUN % (str(example), NOT_ON_THE_FIELDBUS_PATH)) == set()
