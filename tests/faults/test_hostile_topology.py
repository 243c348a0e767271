"""Hostile topology files (scripts/faults/hostile_topology.py): one error line with the
place where there is one, exit 1, no traceback, for validate and run. Timings and memory
are the probe's (docs/reliability.md)."""

from __future__ import annotations

import hostile_topology
import pytest

from fieldgate.cli import main
from fieldgate.topology import TopologyError, load_topology

CASES = hostile_topology.CASES


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("command", ["validate", "run"])
def test_each_hostile_file_is_one_line_and_exit_1(name, command, tmp_path, capsys):
    make, expected = CASES[name]
    path = make(tmp_path)
    assert main([command, path]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err and expected in lines[0]
    assert lines[0].startswith(f"{path}:") and (len(lines) == 1 or lines[1].endswith("error(s)"))
    assert len(lines) <= 2


def test_the_places_are_file_line_column(tmp_path):
    from fieldgate import load_registry

    registry = load_registry()
    expected = {
        "alias bomb + duplicate key": (6, 17),  # the alias that crosses the limit
        "400-deep nesting": (1, 73),
        "recursive alias": (1, 29),
        "duplicate key": (2, 1),
    }
    for name, place in expected.items():
        folder = tmp_path / name.replace(" ", "_")
        folder.mkdir()
        with pytest.raises(TopologyError) as info:
            load_topology(CASES[name][0](folder), registry)
        (issue,) = info.value.issues
        assert (issue.line, issue.column) == place, name


def test_a_legitimate_anchor_alias_and_merge_key_still_load(tmp_path):
    from fieldgate import load_registry

    registry = load_registry()
    path = tmp_path / "ok.yaml"
    path.write_text(
        "gateway: {name: bench}\n"
        "fronts:\n"
        "  - &front {name: plc, type: memory, restart_backoff_s: 2.0}\n"
        "  - {<<: *front, name: plc2, expose: [io/m1/di0]}\n"
        "backs:\n"
        "  - name: io\n"
        "    type: loopback\n"
        "    modules:\n"
        "      - {address: 3, digital: 2, error_mode: &hold hold}\n"
        "      - {address: 1, digital: 2, error_mode: *hold}\n"
    )
    topology = load_topology(str(path), registry)
    assert [f.restart_backoff_s for f in topology.fronts] == [2.0, 2.0]
