"""README's "Exit codes" table is fieldgate.exitcodes.ExitCode, the commands return those
codes (never bare numbers), and each code happens where the table says."""

from __future__ import annotations

import argparse
import asyncio
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from fieldgate import hookimpl, load_registry
from fieldgate.cli import build_parser
from fieldgate.exitcodes import ExitCode
from fieldgate.plugin import Scanner, ScanProgress

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "i7232d-style.yaml"
# every module whose functions are commands (their return value is an exit code)
COMMAND_MODULES = [
    *sorted((REPO / "core").glob("*cmd.py")),
    REPO / "core" / "cli.py",
    REPO / "conformance" / "cli.py",
    *sorted((REPO / "plugins").glob("*/eds.py")),
    *sorted((REPO / "plugins").glob("*/scan.py")),
]


def readme_table() -> dict[int, str]:
    text = (REPO / "README.md").read_text()
    section = text.split("### Exit codes", 1)[1].split("\n#", 1)[0]
    rows = re.findall(r"^\| (\d+) \| (\w+) \| (.+) \|$", section, re.M)
    return {int(code): name for code, name, _meaning in rows}


def test_the_readme_table_is_the_enum():
    assert readme_table() == {code.value: code.name for code in ExitCode}


@pytest.mark.parametrize("path", COMMAND_MODULES, ids=lambda p: str(p.relative_to(REPO)))
def test_commands_return_exit_codes_by_name(path):
    bare = re.findall(r"^\s+return (?:\d+|\d+ if .*)$|(?<!\w)code=\d+", path.read_text(), re.M)
    assert bare == [], f"{path}: use fieldgate.exitcodes.ExitCode"


def fieldgate(*args: str, **kwargs: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fieldgate", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
        **kwargs,
    )


def test_0_valid_and_1_invalid(tmp_path):
    assert fieldgate("validate", str(EXAMPLE)).returncode == ExitCode.OK
    bad = tmp_path / "bad.yaml"
    bad.write_text("gateway: {name: 3x}\n")
    assert fieldgate("validate", str(bad)).returncode == ExitCode.FAILED


def test_2_a_front_that_cannot_start_and_a_wrong_command_line():
    bus = ["--set=fronts.can.interface=socketcan", "--set=fronts.can.channel=fgcan9"]
    run = fieldgate("run", str(EXAMPLE), *bus, "--duration", "5")
    assert run.returncode == ExitCode.CANNOT_RUN, run.stderr
    assert "cannot start: front can (canopen)" in run.stderr
    assert fieldgate("run").returncode == ExitCode.CANNOT_RUN  # argparse: FILE missing
    malformed = fieldgate("validate", str(EXAMPLE), "--set", "no-equals-sign")
    assert malformed.returncode == ExitCode.CANNOT_RUN
    assert malformed.stderr == "fieldgate: --set expects PATH=VALUE, got 'no-equals-sign'\n"


def test_130_a_scan_interrupted_prints_what_it_found(capsys):
    class Interrupted(Scanner):
        address_range = (1, 9)

        async def scan(
            self,
            port: str,
            baudrate: int,
            addresses: list[int],
            args: argparse.Namespace,
            progress: ScanProgress,
            found: list[Any],
        ) -> None:
            found.append(1)
            progress(1, len(addresses), 1)
            raise asyncio.CancelledError  # what Ctrl-C does to asyncio.run's task

        def topology(self, found: list[Any], args: argparse.Namespace) -> str:
            return f"found {found}\n"

    class Plugin:
        PLUGIN_NAME = "cut"

        @hookimpl
        def fieldgate_register(self, registry):
            registry.add_scanner("cut", Interrupted())

    registry = load_registry(extra_plugins=[Plugin()])
    args = build_parser(registry).parse_args(["scan", "cut", "--port", "x", "--addresses", "1-3"])
    assert args.handler(args, registry) == ExitCode.INTERRUPTED
    out, err = capsys.readouterr()
    assert out == "found [1]\n"
    assert "interrupted at address 2 at 9600 bit/s" in err
