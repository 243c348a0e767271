"""``fieldgate scan modbus-tcp-client --port HOST[:PORT]``: which unit ids answer on a host.

One connection; every unit id is asked for holding register 0 (FC3, one register), as the
RTU scan does. Data or an exception means a device is there, but exceptions 0A and 0B (a
gateway saying its target is absent or silent) and no answer mean nobody is. ``--baudrate``
means nothing on TCP and is ignored. The printed ``backs:`` section has ``model: FILL-IN``
for every unit: give a model (yours, or a preset) or declare the channels.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from fieldgate.health import ErrorKind
from fieldgate.plugin import PluginStartError, Scanner, ScanProgress
from fieldgate.polling import CommError, LineLost

from .client import ModbusExceptionError
from .scan import PROBE, UNKNOWN_MODEL, Found
from .tcp_config import host_key, parse_host

if TYPE_CHECKING:
    from .tcp_link import ModbusTcpLink

ABSENT = (0x0A, 0x0B)  # gateway path unavailable, gateway target failed to respond


class ModbusTcpScanner(Scanner):
    addresses = "1-247"
    address_range = (0, 255)

    async def scan(
        self,
        port: str,
        baudrate: int,
        addresses: list[int],
        args: argparse.Namespace,
        progress: ScanProgress,
        found: list[Any],
    ) -> None:
        try:
            host, tcp_port = parse_host(port)
        except ValueError as exc:
            raise PluginStartError(f"--port {port!r}: {exc} (give HOST or HOST:PORT)") from None
        from .tcp_link import ModbusTcpLink  # loaded by a scan, not by every gateway

        link = ModbusTcpLink(host, tcp_port, timeout=args.timeout_ms / 1000)
        try:
            await link.connect()
        except (OSError, TimeoutError) as exc:
            raise PluginStartError(
                f"cannot connect to {link.name}: {getattr(exc, 'strerror', None) or exc or 'timed out'}"
            ) from None
        count = len(found)
        try:
            for done, unit in enumerate(addresses, 1):
                answer = await probe(link, unit)
                if answer is not None:
                    found.append(Found(unit, 0, answer))
                progress(done, len(addresses), len(found) - count)
        finally:
            link.close()

    def topology(self, found: list[Any], args: argparse.Namespace) -> str:
        host, port = parse_host(args.port)
        lines = [
            "backs:",
            f"  - name: {args.name}",
            "    type: modbus-tcp-client",
            f"    host: {host_key(host, port)}",
            "    modules:",
        ]
        for f in found:
            lines.append(f"      - address: {f.address}  # answered {f.answer}")
            lines.append(
                f"        model: {UNKNOWN_MODEL}  # Modbus does not say: a model, or channels"
            )
        if not found:
            lines[-1] = "    modules: []  # no unit answered"
        return "\n".join(lines) + "\n"


async def probe(link: ModbusTcpLink, unit: int) -> str | None:
    """What ``unit`` answers to the probe; None when nobody does."""
    function, register, count = PROBE
    try:
        values = await link.read_registers(unit, function, register, count)
    except ModbusExceptionError as exc:
        if exc.code in ABSENT:
            return None
        return f"FC{function} register {register}: exception {exc.code}"
    except LineLost as exc:
        raise PluginStartError(f"{exc}") from None
    except CommError as exc:
        if exc.kind is not ErrorKind.TIMEOUT:
            print(f"\nunit {unit}: answered but {exc.kind}: {exc}", file=sys.stderr)
        return None
    return f"FC{function} register {register} = {values[0]}"
