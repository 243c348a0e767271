"""Command-line conveniences: --log-level after the command, seconds that cannot be negative,
the status lines' legend, and the demo script's check of its topology argument."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate.cli import STATUS_LEGEND, build_parser
from fieldgate.plugin import load_registry

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "i7232d-style.yaml"


@pytest.fixture(scope="module")
def parser():
    return build_parser(load_registry())


@pytest.mark.parametrize(
    "argv, level",
    [
        (["validate", "x.yaml"], "info"),
        (["--log-level", "debug", "validate", "x.yaml"], "debug"),
        (["validate", "x.yaml", "--log-level", "error"], "error"),
        (
            ["--log-level", "debug", "run", "x.yaml", "--log-level", "warning"],
            "warning",
        ),  # the later one wins
        (["simulate", "dcon", "--pty", "--log-level", "debug"], "debug"),  # a plugin's command
    ],
)
def test_log_level_before_or_after_the_command(parser, argv, level):
    assert parser.parse_args(argv).log_level == level


@pytest.mark.parametrize("option", ["--duration", "--status-every"])
@pytest.mark.parametrize("value", ["-1", "nan", "soon"])
def test_seconds_must_be_zero_or_more(parser, capsys, option, value):
    with pytest.raises(SystemExit) as stop:
        parser.parse_args(["run", "x.yaml", option, value])
    assert stop.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err
    assert parser.parse_args(["run", "x.yaml", option, "0"]) is not None


def test_status_lines_start_with_their_legend():
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "fieldgate",
            "--log-level",
            "warning",
            "run",
            str(EXAMPLE),
            "--simulate",
            "--status-every",
            "0.3",
            "--duration",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    lines = result.stdout.splitlines()
    assert result.returncode == 0, result.stderr
    assert lines[0] == STATUS_LEGEND and "channel 0 first" in lines[0]
    assert lines[1].startswith("rs485/m1 di=")


def test_the_demo_names_a_missing_topology_instead_of_running_another(tmp_path):
    result = subprocess.run(
        ["bash", str(REPO / "scripts" / "demo"), "examples/i7231d.yaml"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert result.returncode == 1
    assert "no such topology file: examples/i7231d.yaml" in result.stderr
    assert "examples/i7231d-style.yaml" in result.stderr  # what there is
    assert "on simulated modules" not in result.stderr  # nothing was started
