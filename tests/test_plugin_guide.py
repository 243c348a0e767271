"""docs/plugins.md and its example back, examples/plugins/fieldgate-jsonfile: every listing in
the guide is the example's file, every file of the example is in the guide, and the example
builds as a wheel, installs beside fieldgate in a fresh venv and runs there (.ci/wheel/run:
CI runs it; locally FIELDGATE_WHEEL=1, it takes a minute). The example's own tests run with
the suite (the test venv has it installed editable, scripts/ensure-venv)."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "plugins.md"
EXAMPLE = REPO / "examples" / "plugins" / "fieldgate-jsonfile"
LISTING = re.compile(r"<!-- file: (\S+) -->\n```\w+\n(.*?)```", re.S)


def listings() -> dict[str, str]:
    found = LISTING.findall(GUIDE.read_text())
    names = [name for name, _ in found]
    assert len(names) == len(set(names)), f"a file is listed twice: {names}"
    return dict(found)


def example_files() -> set[str]:
    tracked = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "."],
        cwd=EXAMPLE,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    return {name for name in tracked if name.endswith((".py", ".toml", ".yaml"))}


@pytest.mark.parametrize("name", sorted(listings()))
def test_each_listing_in_the_guide_is_the_example_s_file(name):
    path = EXAMPLE / name
    assert path.is_file(), f"docs/plugins.md lists {name}, which the example does not have"
    assert listings()[name] == path.read_text(), (
        f"docs/plugins.md shows another {name} than examples/plugins/fieldgate-jsonfile/{name}"
    )


def test_every_file_of_the_example_is_in_the_guide():
    assert example_files() == set(listings())


def test_the_guide_s_fixture_table_names_fixtures_that_exist(request):
    section = GUIDE.read_text().split("## 7. Tests", 1)[1].split("\n## ", 1)[0]
    named = re.findall(r"^\| `(\w+)[(`]", section, re.M)
    assert {"fieldgate_gateway", "fieldgate_thread", "canopen_master", "devicenet_scanner"} <= set(
        named
    )
    for name in named:
        assert request.getfixturevalue(name) is not None, name


@pytest.mark.skipif(
    os.environ.get("CI") != "true" and os.environ.get("FIELDGATE_WHEEL") != "1",
    reason="builds two wheels and a fresh venv (about a minute): CI runs it, or FIELDGATE_WHEEL=1",
)
def test_the_example_builds_installs_and_runs_from_wheels_in_a_fresh_venv():
    result = subprocess.run(
        ["bash", str(REPO / ".ci" / "wheel" / "run")],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    done = [line for line in result.stdout.splitlines() if line.startswith("ok: ")]
    assert done == [
        "ok: wheels built without warnings",
        "ok: installed in a fresh venv without warnings",
        "ok: the base wheel pulls neither asyncua nor paho-mqtt nor protobuf"
        " (extras opcua, sparkplug, modbus-tcp, all)",
        "ok: fieldgate plugins (no test plugin, no failure)",
        "ok: validate, eds and run --simulate of examples/i7232d-style.yaml",
        "ok: validate of a topology whose fronts' extras are missing names"
        " 'pip install fieldgate[opcua]' and [sparkplug]",
        "ok: eds of examples/i7241d-style.yaml (DeviceNet)",
        "ok: validate and run --simulate of the example plugin's lab.yaml",
        "ok: the example plugin's tests",
    ]
