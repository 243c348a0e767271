"""``fieldgate service-unit``: the systemd unit shipped with the package (docs/deploy.md),
with ``ExecStart`` pointing at the ``fieldgate`` of the installation it runs from."""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

from .exitcodes import ExitCode

UNIT_NAME = "fieldgate@.service"
SHIPPED_EXECUTABLE = "/opt/fieldgate/bin/fieldgate"  # the path docs/deploy.md installs to


def unit_text(executable: str | None = None) -> str:
    """The unit; ``executable`` replaces the shipped ``/opt/fieldgate/bin/fieldgate``."""
    text = (resources.files("fieldgate.deploy") / UNIT_NAME).read_text(encoding="utf-8")
    return text.replace(SHIPPED_EXECUTABLE, executable) if executable else text


def this_executable() -> str | None:
    """The ``fieldgate`` script beside this interpreter (a venv's bin/), if there is one."""
    script = Path(sys.executable).with_name("fieldgate")
    return str(script.absolute()) if script.is_file() else None


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--executable",
        metavar="PATH",
        help="the fieldgate to run (default: the one beside this Python, else "
        f"{SHIPPED_EXECUTABLE})",
    )


def run(args: argparse.Namespace) -> int:
    sys.stdout.write(unit_text(args.executable or this_executable()))
    return ExitCode.OK
