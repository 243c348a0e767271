"""Simulated Modbus TCP devices: one MBAP server per host of a ``modbus-tcp-client`` back.

The devices are the RTU simulator's :class:`~.simulator.SimModule` (the same cells, the same
exception rules), served over MBAP: each host of the back gets a listener, its devices by
unit id; a unit id nobody serves is answered with exception 0B (gateway target failed to
respond), as TCP/RTU gateways do. A host on a loopback address is served exactly there (port
0: any free one); any other host is served on a free loopback port and the back's config is
pointed at it (``fieldgate run --simulate``; ``fieldgate simulate`` prints where).

Faults per device (``inject``): no answer, a delay, an exception, garbage (bytes that break
the MBAP stream: the client must drop the connection), a truncated answer, an answer from
another unit id. Per host: ``kill_host`` closes its listener and connections (refused from
then on), ``revive_host`` listens again; ``pipelining=False`` makes a host drop a request that
arrives while it has not answered the one before (a device that does not allow pipelining).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import struct
import time
from collections import deque
from dataclasses import dataclass, field

from fieldgate.plugin import PluginStartError

from .codec import ExceptionCode, frame, parse_request
from .config import module_points
from .points import Point
from .simulator import FAULT_KINDS, ChannelSimulator, Fault, SimModule
from .tcp_config import ModbusTcpClientBackConfig, host_key, parse_host

log = logging.getLogger("fieldgate.modbus.simulator")

MBAP = struct.Struct(">HHHB")
GATEWAY_NO_RESPONSE = 0x0B


@dataclass
class Seen:
    """A request as a simulated host received it."""

    unit: int
    function: int
    address: int
    count: int
    at: float
    outstanding: int  # requests of this connection not yet answered when it arrived


@dataclass
class Answer:
    unit: int
    pdu: bytes | None  # None: no answer
    delay: float = 0.0
    raw: bool = False  # bytes sent as they are (garbage), not framed


@dataclass
class HostSim:
    key: str  # as the back's config named it (HOST:PORT)
    bind: tuple[str, int]
    units: dict[int, SimModule]
    pipelining: bool = True
    server: asyncio.Server | None = None
    writers: set[asyncio.StreamWriter] = field(default_factory=set)
    log: deque[Seen] = field(default_factory=lambda: deque(maxlen=10_000))
    connections: int = 0

    @property
    def endpoint(self) -> str:
        return host_key(*self.bind)


class ModbusTcpSimulator(ChannelSimulator):
    def __init__(self, config: ModbusTcpClientBackConfig, animate: bool = False):
        self.config = config
        self.animate = animate
        self.hosts: dict[str, HostSim] = {}
        self.devices: dict[int, tuple[HostSim, SimModule]] = {}
        self.channels: dict[str, tuple[SimModule, Point]] = {}
        for key, devices in config.by_host().items():
            host, port = parse_host(key)
            bind = (host, port) if _is_loopback(host) else ("127.0.0.1", 0)
            sim = HostSim(key, bind, {})
            self.hosts[key] = sim
            for device in devices:
                points = module_points(config.name, device)
                unit = config.unit_of(device)
                module = SimModule(unit, points)
                sim.units[unit] = module
                self.devices[device.address] = (sim, module)
                for p in points:
                    self.channels[p.channel] = (module, p)
        self._task: asyncio.Task[None] | None = None

    # -- life cycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        for sim in self.hosts.values():
            await self._listen(sim)
        self._point_config_at_servers()
        if self.animate:
            self._task = asyncio.get_running_loop().create_task(self._animate())

    async def _listen(self, sim: HostSim) -> None:
        try:
            sim.server = await asyncio.start_server(
                lambda r, w: self._serve(sim, r, w), sim.bind[0], sim.bind[1]
            )
        except OSError as exc:
            raise PluginStartError(
                f"cannot listen on {sim.endpoint} for {sim.key}: {exc.strerror or exc}"
            ) from None
        sock = sim.server.sockets[0]
        sim.bind = (sim.bind[0], sock.getsockname()[1])

    def _point_config_at_servers(self) -> None:
        """The back's devices (and its hosts' settings) name the simulated hosts."""
        cfg = self.config
        moved = {key: sim.endpoint for key, sim in self.hosts.items()}
        for device in cfg.modules:
            device.host = moved[host_key(*cfg.endpoint(device))]
        cfg.hosts = {
            moved[host_key(*parse_host(name))]: settings for name, settings in cfg.hosts.items()
        }

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        for sim in self.hosts.values():
            await self._close(sim)

    async def _close(self, sim: HostSim) -> None:
        server, sim.server = sim.server, None
        if server is not None:
            server.close()
        for writer in list(sim.writers):
            writer.close()
        sim.writers.clear()
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)

    def describe(self) -> list[str]:
        return [
            f"host {key} served on {sim.endpoint}: units {', '.join(str(u) for u in sorted(sim.units))}"
            for key, sim in self.hosts.items()
        ]

    # -- hosts -------------------------------------------------------------------------------------
    def host_of(self, address: int) -> HostSim:
        try:
            return self.devices[address][0]
        except KeyError:
            raise KeyError(f"no simulated device with address {address}") from None

    async def kill_host(self, address: int) -> None:
        """The host of device ``address`` goes away: connections reset, new ones refused."""
        await self._close(self.host_of(address))

    async def revive_host(self, address: int) -> None:
        sim = self.host_of(address)
        if sim.server is None:
            await self._listen(sim)

    # -- the MBAP server ------------------------------------------------------------------------
    async def _serve(
        self, sim: HostSim, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        sim.writers.add(writer)
        sim.connections += 1
        outstanding = 0
        loop = asyncio.get_running_loop()

        def send(data: bytes) -> None:
            nonlocal outstanding
            outstanding = max(0, outstanding - 1)
            if not writer.is_closing():
                writer.write(data)

        try:
            while True:
                header = await reader.readexactly(MBAP.size)
                tid, protocol, length, unit = MBAP.unpack(header)
                if protocol != 0 or not 2 <= length <= 254:
                    break  # a broken stream: close it, as a device would
                pdu = await reader.readexactly(length - 1)
                if outstanding and not sim.pipelining:
                    continue  # a device that does not take pipelined requests drops it
                outstanding += 1
                answer = self._answer(sim, unit, pdu, outstanding)
                if answer.pdu is None:
                    outstanding -= 1
                    continue
                data = answer.pdu if answer.raw else _mbap(tid, answer.unit, answer.pdu)
                delay = answer.delay
                if delay:
                    loop.call_later(delay, send, data)
                else:
                    send(data)
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            sim.writers.discard(writer)
            writer.close()

    def _answer(self, sim: HostSim, unit: int, pdu: bytes, outstanding: int) -> Answer:
        """What the host sends back for one request (nothing, with no_answer)."""
        function = pdu[0] if pdu else 0
        module = sim.units.get(unit)
        if module is None:
            return Answer(unit, bytes([function | 0x80, GATEWAY_NO_RESPONSE]))
        try:
            request = parse_request(frame(unit, pdu))
        except (ValueError, IndexError):
            code = (
                ExceptionCode.ILLEGAL_FUNCTION
                if function not in (1, 2, 3, 4, 5, 6, 15, 16)
                else ExceptionCode.ILLEGAL_DATA_VALUE
            )
            return Answer(unit, bytes([function | 0x80, code]))
        sim.log.append(
            Seen(unit, function, request.address, request.count, time.monotonic(), outstanding)
        )
        fault = module.take_fault(request)
        if fault is not None and fault.kind == "exception":
            return Answer(unit, bytes([function | 0x80, fault.code]))
        answer = module.handle(request)[1:-2]
        if fault is None:
            return Answer(unit, answer)
        if fault.kind == "no_answer":
            return Answer(unit, None)
        if fault.kind == "delay":
            return Answer(unit, answer, fault.delay)
        if fault.kind in ("garbage", "crc"):  # (TCP has no CRC: bytes that break the stream)
            return Answer(unit, b"\x55\xaa\x00\xff\x13\x00\x00", raw=True)
        if fault.kind == "truncate":
            whole = _mbap(0, unit, answer)
            return Answer(unit, whole[: max(8, len(whole) - 2)], raw=True)
        if fault.kind == "wrong_address":
            return Answer((unit % 247) + 1, answer)
        return Answer(unit, answer)

    # -- the Simulator API: set_input, get_output, get (ChannelSimulator) -------------------------
    def inject(self, address: int, fault: Fault) -> None:
        """A fault of device ``address`` (the back's device number)."""
        if address not in self.devices:
            raise KeyError(f"no simulated device with address {address}")
        self.devices[address][1].faults.append(fault)

    def clear_faults(self, address: int | None = None) -> None:
        for a, (_sim, module) in self.devices.items():
            if address is None or a == address:
                module.faults.clear()

    def requests(self, address: int) -> list[Seen]:
        """What the host of device ``address`` received, oldest first (its other units too)."""
        return list(self.host_of(address).log)

    def command(self, words: list[str]) -> str | None:
        """``fault ADDRESS KIND [COUNT] [delay=S] [code=N]``, ``clear [ADDRESS]``,
        ``host ADDRESS down|up``."""
        cmd, rest = words[0].lower(), words[1:]
        if cmd == "fault" and len(rest) >= 2:
            options = {k: v for k, _, v in (w.partition("=") for w in rest[2:] if "=" in w)}
            counts = [int(w) for w in rest[2:] if w.isdigit()]
            fault = Fault(
                rest[1],
                count=counts[0] if counts else None,
                code=int(options.get("code", 4)),
                delay=float(options.get("delay", 0.5)),
            )
            self.inject(int(rest[0]), fault)
            return f"device {rest[0]}: {fault.kind}" + (
                f" for {fault.count} replies" if fault.count else " until cleared"
            )
        if cmd == "clear":
            self.clear_faults(int(rest[0]) if rest else None)
            return "faults cleared"
        if cmd == "host" and len(rest) == 2 and rest[1] in ("down", "up"):
            action = self.kill_host if rest[1] == "down" else self.revive_host
            asyncio.get_running_loop().create_task(action(int(rest[0])))
            return f"host of device {rest[0]} {rest[1]}"
        return None

    def commands_help(self) -> str:
        return (
            f"fault ADDRESS {{{'|'.join(FAULT_KINDS)}}} [COUNT] [code=N] [delay=S]"
            " | clear [ADDRESS] | host ADDRESS down|up"
        )

    async def _animate(self) -> None:
        from .simulator import _animated_value

        tick = 0
        while True:
            await asyncio.sleep(0.25)
            tick += 1
            for module, p in self.channels.values():
                if not p.kind.is_output:
                    module.set_point(p, _animated_value(p, tick))


def _mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return MBAP.pack(tid, 0, len(pdu) + 1, unit) + pdu


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
