"""Plugin discovery through the entry-point group: built-in and third-party alike."""

import importlib.metadata
import subprocess
import sys

from fieldgate import hookimpl, load_registry
from fieldgate.plugin import ENTRY_POINT_GROUP


def test_external_package_is_found_through_its_entry_point_alone():
    eps = {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}
    assert (
        eps["loopback"].dist.name == "fieldgate-loopback"
    )  # installed from tests/plugin_pkg, not part of fieldgate
    registry = load_registry()
    info = registry.plugins["loopback"]
    assert (info.version, info.distribution, info.error) == ("1.0.0", "fieldgate-loopback", "")
    assert info.provides == ["back:loopback", "front:memory", "front:probe"]
    assert registry.lookup("back", "loopback").model.__name__ == "LoopbackConfig"


def test_builtin_plugins_register_through_the_same_group():
    eps = {ep.name: ep.value for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}
    builtin = {name: value for name, value in eps.items() if value.startswith("fieldgate.plugins.")}
    registry = load_registry()
    for name in builtin:
        assert registry.plugins[name].distribution == "fieldgate"
        assert registry.plugins[name].error == "", registry.plugins[name].error


class Broken:
    PLUGIN_NAME = "broken"

    @hookimpl
    def fieldgate_register(self, registry):
        raise RuntimeError("cannot register")


class Clash:
    PLUGIN_NAME = "clash"

    @hookimpl
    def fieldgate_register(self, registry):
        registry.add_back("loopback", object, object)


def test_a_broken_plugin_is_reported_and_does_not_hide_the_others():
    registry = load_registry(extra_plugins=[Broken(), Clash()])
    assert "RuntimeError: cannot register" in registry.plugins["broken"].error
    assert "registered by both loopback and clash" in registry.plugins["clash"].error
    assert registry.lookup("back", "loopback").plugin == "loopback"


def test_commands_count_as_what_a_plugin_provides():
    class Tool:
        PLUGIN_NAME = "tool"

        @hookimpl
        def fieldgate_register(self, registry):
            registry.add_command(
                ("scan", "thing"), "finds things", lambda parser: None, lambda args: 0
            )

    registry = load_registry(extra_plugins=[Tool()])
    assert registry.plugins["tool"].provides == ["command:scan thing"]


def test_fieldgate_plugins_lists_name_version_and_what_each_provides():
    out = subprocess.run(
        [sys.executable, "-m", "fieldgate", "plugins"], capture_output=True, text=True, check=True
    ).stdout
    header, *rows = out.splitlines()
    assert header.split() == ["PLUGIN", "VERSION", "DISTRIBUTION", "PROVIDES", "SUMMARY"]
    line = next(text for text in rows if text.startswith("loopback"))
    assert line.split()[1:3] == ["1.0.0", "fieldgate-loopback"]
    assert "back:loopback, front:memory" in line
    assert line.endswith("a loopback back and a memory front, used by fieldgate's tests.")


def test_a_run_loads_only_the_plugins_of_its_topology_s_types():
    from fieldgate.cli import topology_types

    types = topology_types(["run", "examples/i7232d-style.yaml", "--simulate"])
    assert types == {"canopen", "modbus"}
    registry = load_registry(only=types)
    assert sorted(registry.plugins) == ["canopen", "modbus"]  # no conformance, dcon, opcua, ...
    assert registry.lookup("front", "canopen") and registry.lookup("back", "modbus")
    # a type no plugin of that name provides (the test package's "memory" front): every plugin
    everything = load_registry(only={"memory", "loopback"})
    assert "canopen" in everything.plugins and everything.lookup("front", "memory")
    assert topology_types(["validate", "examples/i7232d-style.yaml"]) is None
    assert topology_types(["run", "x.yaml", "--set", "fronts.can.type=devicenet"]) is None
    assert topology_types(["--log-level", "debug", "run", "/no/such/file.yaml"]) is None
