"""``fieldgate scan BACK``: core runs every back's scanner the same way (baud rates, exit
codes, what is kept when the port fails at a later baud rate)."""

from __future__ import annotations

import argparse
from typing import Any

import pytest

from fieldgate import hookimpl, load_registry
from fieldgate.cli import build_parser
from fieldgate.exitcodes import ExitCode
from fieldgate.plugin import PluginStartError, Scanner, ScanProgress
from fieldgate.scancmd import parse_addresses


class FakeScanner(Scanner):
    """Finds a module at address 2 at every baud rate in ``answers``; ``fails`` at others."""

    addresses = "1-4"
    address_range = (1, 9)

    def __init__(self, answers: set[int], fails: set[int] = frozenset()) -> None:
        self.answers, self.fails, self.opened = answers, fails, []

    def configure(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--colour", default="red")

    async def scan(
        self,
        port: str,
        baudrate: int,
        addresses: list[int],
        args: argparse.Namespace,
        progress: ScanProgress,
        found: list[Any],
    ) -> None:
        self.opened.append(baudrate)
        if baudrate in self.fails:
            raise PluginStartError(f"cannot open {port} at {baudrate} bit/s: device disconnected")
        for done, address in enumerate(addresses, 1):
            if address == 2 and baudrate in self.answers:
                found.append((address, baudrate, args.colour))
            progress(done, len(addresses), len(found))

    def topology(self, found: list[Any], args: argparse.Namespace) -> str:
        return f"{found}\n"


def scan(scanner: FakeScanner, *argv: str) -> int:
    class Plugin:
        PLUGIN_NAME = "fake"

        @hookimpl
        def fieldgate_register(self, registry):
            registry.add_scanner("fake", scanner)

    registry = load_registry(extra_plugins=[Plugin()])
    args = build_parser(registry).parse_args(["scan", "fake", "--port", "/dev/x", *argv])
    return int(args.handler(args, registry))


def test_modules_found_none_found_and_the_back_s_own_option(capsys):
    scanner = FakeScanner({19200})
    assert scan(scanner, "--baudrate", "9600,19200", "--colour", "blue") == ExitCode.OK
    assert capsys.readouterr().out == "[(2, 19200, 'blue')]\n"
    assert scanner.opened == [9600, 19200]
    assert scan(FakeScanner(set())) == ExitCode.FAILED
    assert capsys.readouterr().out == "[]\n"


def test_a_port_that_fails_at_a_later_baud_rate_keeps_the_earlier_finds(capsys):
    scanner = FakeScanner({9600}, fails={115200})
    assert scan(scanner, "--baudrate", "9600,115200") == ExitCode.CANNOT_RUN
    out, err = capsys.readouterr()
    assert scanner.opened == [9600, 115200]
    assert out == "[(2, 9600, 'red')]\n"
    assert "cannot open /dev/x at 115200 bit/s" in err and "the modules found before that" in err


def test_addresses_outside_the_protocol_s_range_are_a_usage_error(capsys):
    assert scan(FakeScanner({9600}), "--addresses", "0-3") == ExitCode.CANNOT_RUN
    assert "fieldgate scan fake: address range '0-3' outside 1..9" in capsys.readouterr().err


@pytest.mark.parametrize(
    "text, addresses", [("0-3", [0, 1, 2, 3]), ("1,8,0x10", [1, 8, 16]), ("5-6,1", [1, 5, 6])]
)
def test_parse_addresses(text, addresses):
    assert parse_addresses(text) == addresses


def test_parse_addresses_rejects_out_of_range():
    with pytest.raises(ValueError, match="outside 0..255"):
        parse_addresses("250-300")
