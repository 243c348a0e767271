"""``fieldgate scan modbus-tcp-client --port HOST[:PORT]``: which unit ids answer on a host.

One connection; every unit id is asked for holding register 0 (FC3, one register), as the
RTU scan does. Data or an exception means a device is there, but exceptions 0A and 0B (a
gateway saying its target is absent or silent) and no answer mean nobody is. ``--baudrate``
means nothing on TCP and is ignored. The printed ``backs:`` section has ``model: FILL-IN``
for every unit: give a model (yours, or a preset) or declare the channels.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from fieldgate.plugin import PluginStartError, Scanner

from .scan import UNKNOWN_MODEL, Found, probe
from .tcp_config import host_key, parse_host

if TYPE_CHECKING:
    from .tcp_link import ModbusTcpLink

ABSENT = (0x0A, 0x0B)  # gateway path unavailable, gateway target failed to respond


class ModbusTcpScanner(Scanner):
    addresses = "1-247"
    address_range = (0, 255)

    async def open(self, port: str, baudrate: int, args: argparse.Namespace) -> ModbusTcpLink:
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
        return link

    async def probe(self, link: ModbusTcpLink, address: int, baudrate: int) -> Found | None:
        answer = await probe(link, address, ABSENT, lost_ends_scan=True)
        return None if answer is None else Found(address, 0, answer)  # no baud rate on TCP

    async def close(self, link: ModbusTcpLink) -> None:
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
