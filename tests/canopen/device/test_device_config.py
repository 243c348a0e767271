"""The ``canopen-device`` front's configuration: the example validates as shipped and its
EDS comes back from ``fieldgate eds``; a missing file, an entry the file lacks, a channel the
topology lacks and a hook module that cannot load are each one clear error."""

from __future__ import annotations

from pathlib import Path

import pytest

from fieldgate import load_registry
from fieldgate.cli import main as cli_main
from fieldgate.plugins.canopen.device.hooks import HookError, load_setup
from fieldgate.plugins.canopen.device.odfile import file_entries, read_device_file
from fieldgate.topology import TopologyError, load_topology

REPO = Path(__file__).resolve().parents[3]
EXAMPLE = REPO / "examples" / "canopen-device" / "battery.yaml"
REGISTRY = load_registry()


def topology(**front) -> dict:
    return {
        "gateway": {"name": "t"},
        "fronts": [
            {
                "name": "dev",
                "type": "canopen-device",
                "interface": "virtual",
                "channel": "x",
                "node_id": 5,
                "eds": str(EXAMPLE.parent / "battery.eds"),
                **front,
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }


def errors(topo: dict) -> str:
    with pytest.raises(TopologyError) as info:
        load_topology(topo, REGISTRY)
    return "\n".join(issue.message for issue in info.value.issues)


def test_the_example_validates_and_its_eds_round_trips(tmp_path):
    loaded = load_topology(EXAMPLE, REGISTRY)
    assert loaded.fronts[0].type == "canopen-device"
    out = tmp_path / "pack.eds"
    assert cli_main(["eds", str(EXAMPLE), "-o", str(out)]) == 0

    def described(path):
        return {
            (v.index, v.subindex): (v.data_type, v.access_type, v.default, v.min, v.max)
            for v in file_entries(read_device_file(path))
        }

    assert described(out) == described(EXAMPLE.parent / "battery.eds")


def test_a_missing_file_names_it():
    assert "nowhere.eds: cannot read it" in errors(topology(eds="/nowhere.eds"))


def test_a_binding_needs_an_entry_of_the_file_and_a_channel_of_the_topology():
    assert "bind: 0x6000:1 is no entry of battery.eds" in errors(
        topology(bind={"0x6000:1": "io/m1/di0"})
    )
    assert "'io/m9/di0' is no channel" in errors(topology(bind={"0x2103": "io/m9/di0"}))
    assert "write an entry as 'index:sub'" in errors(topology(bind={"six": "io/m1/di0"}))


def test_validate_loads_the_hook_module():
    assert "hooks: cannot import 'no_such_module_xyz'" in errors(
        topology(hooks="no_such_module_xyz")
    )


def test_a_hook_module_that_cannot_load_is_one_line(tmp_path):
    with pytest.raises(HookError, match="cannot import 'no_such_module_xyz'"):
        load_setup("no_such_module_xyz")
    broken = tmp_path / "broken.py"
    broken.write_text("raise ImportError('missing dependency')\n")
    with pytest.raises(HookError, match="broken.py failed to load: missing dependency"):
        load_setup(str(broken))
    empty = tmp_path / "empty.py"
    empty.write_text("X = 1\n")
    with pytest.raises(HookError, match="no setup"):
        load_setup(str(empty))


def test_hooks_come_from_a_module_on_the_path_or_an_entry_point(tmp_path, monkeypatch):
    (tmp_path / "acme_pack_hooks.py").write_text("def setup(device):\n    device.tag = 'module'\n")
    monkeypatch.syspath_prepend(str(tmp_path))

    class Api:
        tag = ""

    api = Api()
    load_setup("acme_pack_hooks")(api)
    assert api.tag == "module"

    class Point:
        name = "acme-pack"

        def load(self):
            return lambda device: setattr(device, "tag", "entry point")

    def entry_points(group: str):
        return [Point()] if group == "fieldgate.canopen_hooks" else []

    monkeypatch.setattr("importlib.metadata.entry_points", entry_points)
    load_setup("acme-pack")(api)
    assert api.tag == "entry point"


def test_serial_is_the_one_value_the_topology_adds_and_the_eds_says_it(tmp_path):
    source = tmp_path / "t.yaml"
    import json

    source.write_text(json.dumps(topology(serial=1001)))
    out = tmp_path / "unit.eds"
    assert cli_main(["eds", str(source), "-o", str(out)]) == 0
    written = {(v.index, v.subindex): v.default for v in file_entries(read_device_file(out))}
    shipped = {
        (v.index, v.subindex): v.default
        for v in file_entries(read_device_file(EXAMPLE.parent / "battery.eds"))
    }
    assert {k for k in written if written[k] != shipped[k]} == {(0x1018, 4)}
    assert written[(0x1018, 4)] == 1001
