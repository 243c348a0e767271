"""``fieldgate scan modbus``: which unit ids answer on a line, at one baud rate or several.

Every unit id is asked for holding register 0 (FC3, one register). Any well-formed answer
from that unit, data or a Modbus exception (a module without holding registers answers
exception 2), means a module is there; silence means nobody is. Modbus RTU has no standard
way to ask a module what it is (Read Device Identification, FC 43/14, is optional and the
ICP DAS M-7000 manuals of docs/modbus.md do not list it), so the printed topology gives each
unit id with ``model: FILL-IN``: ``fieldgate validate`` then lists the presets to choose
from, or declare the module's ``channels``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

from fieldgate.health import ErrorKind
from fieldgate.plugin import PluginStartError, Scanner
from fieldgate.polling import CommError, LineLost

from .client import ModbusExceptionError, ModbusLink, Transactions
from .codec import Function

PROBE = (Function.READ_HOLDING_REGISTERS, 0, 1)  # function, address, count
UNKNOWN_MODEL = "FILL-IN"


@dataclass(frozen=True)
class Found:
    address: int
    baudrate: int
    answer: str  # what it answered to the probe


class ModbusScanner(Scanner):
    addresses = "1-247"
    address_range = (1, 247)  # 0 is the broadcast address: nobody answers it

    def configure(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument(
            "--parity", choices=("N", "E", "O"), default="N", help="parity of the line (default N)"
        )

    async def open(self, port: str, baudrate: int, args: argparse.Namespace) -> ModbusLink:
        link = ModbusLink(
            port, baudrate=baudrate, parity=args.parity, timeout=args.timeout_ms / 1000
        )
        await link.open()  # PluginStartError: one line
        return link

    async def probe(self, link: ModbusLink, address: int, baudrate: int) -> Found | None:
        answer = await probe(link, address)
        return None if answer is None else Found(address, baudrate, answer)

    async def close(self, link: ModbusLink) -> None:
        link.close()

    def topology(self, found: list[Any], args: argparse.Namespace) -> str:
        return topology_yaml(found, args.port, args.parity, args.name)


async def probe(
    link: Transactions, address: int, absent: Collection[int] = (), lost_ends_scan: bool = False
) -> str | None:
    """What unit ``address`` answers to the probe; None when nothing answers, or when it
    answers an exception code in ``absent`` (a TCP gateway saying its target is not there).
    ``lost_ends_scan``: a lost link (LineLost) ends the scan as a PluginStartError."""
    function, register, count = PROBE
    try:
        values = await link.read_registers(address, function, register, count)
    except ModbusExceptionError as exc:
        if exc.code in absent:
            return None
        return f"FC{function} register {register}: exception {exc.code}"
    except LineLost as exc:
        if lost_ends_scan:
            raise PluginStartError(f"{exc}") from None
        _answered_but(address, exc)
        return None
    except CommError as exc:
        _answered_but(address, exc)
        return None
    return f"FC{function} register {register} = {values[0]}"


def _answered_but(address: int, exc: CommError) -> None:
    if exc.kind is not ErrorKind.TIMEOUT:
        print(f"\nunit {address}: answered but {exc.kind}: {exc}", file=sys.stderr)


def topology_yaml(found: list[Found], port: str, parity: str, name: str = "rs485") -> str:
    """Ready-to-paste ``backs:`` entries, one per baud rate that had modules."""
    lines = ["backs:"]
    rates = sorted({f.baudrate for f in found})
    for baud in rates:
        lines += [
            f"  - name: {name if len(rates) == 1 else f'{name}-{baud}'}",
            "    type: modbus",
            f"    port: {port}",
            f"    baudrate: {baud}",
            f"    parity: {parity}",
            "    modules:",
        ]
        for f in (f for f in found if f.baudrate == baud):
            lines.append(f"      - address: {f.address}  # answered {f.answer}")
            lines.append(
                f"        model: {UNKNOWN_MODEL}  # Modbus RTU does not say: a preset, or channels"
            )
    if len(lines) == 1:
        lines.append("  []  # no module answered")
    return "\n".join(lines) + "\n"
