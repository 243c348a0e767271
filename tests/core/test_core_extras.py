"""A north-facing front's library is an optional extra (issue 33): the base install pulls
neither asyncua nor paho-mqtt nor protobuf, and a topology with a front whose extra is not
installed fails ``validate`` and ``run`` with one line naming the ``pip install`` command.

A missing library is simulated the way Python records an import known to fail: a ``None``
entry in ``sys.modules`` (``import asyncua`` then raises ModuleNotFoundError), set in a
process of its own before fieldgate's command line runs.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from fieldgate.plugin import load_registry
from fieldgate.registry import module_installed

REPO = Path(__file__).resolve().parents[2]
PLANT = REPO / "examples" / "plant-northbound.yaml"  # canopen, opcua, modbus-tcp, sparkplug
NORTH_LIBRARIES = ("asyncua", "paho", "google.protobuf")


def fieldgate_without(blocked: tuple[str, ...], *argv: str) -> subprocess.CompletedProcess[str]:
    code = (
        "import sys\n"
        f"for name in {blocked!r}: sys.modules[name] = None\n"
        "from fieldgate.cli import main\n"
        f"sys.exit(main({list(argv)!r}))\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO
    )


def lines_of(stderr: str, needle: str) -> list[str]:
    return [line for line in stderr.splitlines() if needle in line]


@pytest.mark.parametrize("command", ["validate", "run"])
def test_an_opcua_front_without_its_extra_is_one_line_naming_the_install(command):
    result = fieldgate_without(("asyncua",), command, str(PLANT))
    assert result.returncode == 1, result.stderr  # as every other configuration error
    (line,) = lines_of(result.stderr, "asyncua")
    assert line.startswith(f"{PLANT}:25:")  # the front's `type:` line
    assert line.endswith(
        "front type 'opcua' needs asyncua, which is not installed: pip install 'fieldgate[opcua]'"
    )
    assert "Traceback" not in result.stderr
    assert not lines_of(result.stderr, "sparkplug")  # its libraries are there


def test_a_sparkplug_front_without_its_extra_names_its_own_extra():
    result = fieldgate_without(("paho",), "validate", str(PLANT))
    assert result.returncode == 1, result.stderr
    (line,) = lines_of(result.stderr, "fieldgate[")
    assert line.startswith(f"{PLANT}:37:")
    assert "front type 'sparkplug' needs paho.mqtt, which is not installed" in line
    assert line.endswith("pip install 'fieldgate[sparkplug]'")


def test_a_fieldbus_only_topology_needs_no_extra():
    example = REPO / "examples" / "i7232d-style.yaml"
    valid = fieldgate_without(NORTH_LIBRARIES, "validate", str(example))
    assert valid.returncode == 0, valid.stderr
    run = fieldgate_without(NORTH_LIBRARIES, "run", str(example), "--simulate", "--duration", "0.5")
    assert run.returncode == 0, run.stderr
    plugins = fieldgate_without(NORTH_LIBRARIES, "plugins")
    assert plugins.returncode == 0, plugins.stderr  # the plugins load without their libraries
    assert "FAILED" not in plugins.stdout


def test_every_needed_module_is_known_to_the_check(monkeypatch):
    registry = load_registry()
    opcua = registry.lookup("front", "opcua")
    sparkplug = registry.lookup("front", "sparkplug")
    assert opcua is not None and sparkplug is not None
    assert opcua.missing() == "" and sparkplug.missing() == ""  # the test venv has `all`
    monkeypatch.setitem(sys.modules, "google.protobuf", None)
    assert not module_installed("google.protobuf")
    assert sparkplug.missing() == (
        "front type 'sparkplug' needs google.protobuf, which is not installed: "
        "pip install 'fieldgate[sparkplug]'"
    )
    assert module_installed("json") and not module_installed("fieldgate_no_such_module.sub")


def test_the_base_install_pulls_no_north_facing_library():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    base = " ".join(project["dependencies"]).lower()
    for dist in ("asyncua", "paho-mqtt", "protobuf", "cryptography"):
        assert dist not in base
    extras = project["optional-dependencies"]
    assert any(d.startswith("asyncua") for d in extras["opcua"])
    assert {d.split(">")[0] for d in extras["sparkplug"]} == {"paho-mqtt", "protobuf"}
    assert extras["modbus-tcp"] == []  # the server is ours
    assert extras["all"] == ["fieldgate[opcua,sparkplug,modbus-tcp]"]
