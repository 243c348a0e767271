"""The ``modbus-tcp-client`` back: Modbus TCP devices polled by host, their health and quality
as the RTU back's.

Each host (``HOST:PORT``) gets at most ``max_connections`` connections
(:class:`~.tcp_link.ModbusTcpLink`), shared by the unit ids on it, and its devices are spread
over ``max_connections x pipeline`` *lanes* (never more than it has devices). A lane is one
core :class:`~fieldgate.polling.LineScheduler`: one request at a time, writes ahead of reads,
poll periods, offline after ``fail_threshold`` failures and the slow re-probe, quality (stale,
comm-fault), exactly as on an RS-485 line; lanes run side by side. So:

* a dead host costs only its own devices (its lanes wait on its connection, nothing else
  does); a host that refuses or drops the connection takes its devices offline at once
  (COMM_FAULT) and is connected again with back-off (0.1 s doubling up to
  ``offline_probe_ms``), every device probed as soon as it is back;
* a dead device on a shared host (behind a TCP/RTU gateway) costs its lane ``timeout_ms``
  per attempt until it is offline, then one probe every ``offline_probe_ms``; with
  ``pipeline`` > 1 (where the device allows) it has a lane of its own and the others never
  wait for it;
* a device's requests stay in order (one lane each), so a write is on the wire before the
  read that follows it.

The modules are the RTU back's :class:`~.back.ModbusModule` (coalesced reads, per-point
fallback, writes, scaling), on a TCP link instead of a serial one.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import Any

from fieldgate.health import ModuleHealth
from fieldgate.image import ChannelSpec
from fieldgate.plugin import Back, GatewayContext
from fieldgate.polling import REOPEN_FIRST_S, LineLost, LineScheduler, PolledModule
from fieldgate.topology import ModuleConfig

from .back import ModbusModule, describe_point
from .client import ModbusStats
from .config import module_points
from .tcp_config import ModbusTcpClientBackConfig, ModbusTcpDeviceConfig
from .tcp_link import ModbusTcpLink

log = logging.getLogger("fieldgate.modbus.tcp")


STABLE_S = 5.0  # a connection lost sooner than this after it opened counts as dropped at once


@dataclass
class Lane:
    host: str
    link: ModbusTcpLink
    scheduler: LineScheduler
    addresses: list[int]


class ModbusTcpClientBack(Back):
    config: ModbusTcpClientBackConfig

    def __init__(self, config: ModbusTcpClientBackConfig, context: GatewayContext) -> None:
        super().__init__(config, context)
        self.health: dict[int, ModuleHealth] = {}
        for device in config.modules:
            self.health[device.address] = context.health.add(
                ModuleHealth(self.name, device.address, device.model or "", config.fail_threshold)
            )
        self.links: dict[str, list[ModbusTcpLink]] = {}
        self.lanes: list[Lane] = []
        self.modules: dict[int, ModbusModule] = {}
        self._outage: dict[int, bool] = {}  # id(link) -> its devices were marked lost
        # id(link) -> (when it last connected, connections in a row lost within STABLE_S): a
        # host that accepts and drops at once is re-tried with the same back-off as a refusal
        self._flaps: dict[int, tuple[float, int]] = {}

    # -- life cycle -----------------------------------------------------------------------------
    async def start(self) -> None:
        cfg = self.config
        specs = [s for s in self.context.topology.channel_specs if s.source.back == self.name]
        self.links.clear()
        self.lanes.clear()
        self.modules.clear()
        self._outage.clear()
        self._flaps.clear()
        for key, devices in cfg.by_host().items():
            connections, _pipeline, timeout, _rtt = cfg.host_settings(key)
            host, port = cfg.endpoint(devices[0])
            links = [
                ModbusTcpLink(
                    host,
                    port,
                    timeout=timeout,
                    connect_timeout=cfg.connect_timeout_ms / 1000,
                    clock=self.context.clock,
                )
                for _ in range(min(connections, len(devices)))
            ]
            self.links[key] = links
            count = cfg.lanes(key)
            groups: list[list[ModbusTcpDeviceConfig]] = [[] for _ in range(count)]
            for i, device in enumerate(devices):
                groups[i % count].append(device)
            for i, group in enumerate(groups):
                link = links[i % len(links)]
                modules: list[PolledModule] = [self._module(d, link, specs) for d in group]
                scheduler = LineScheduler(
                    f"{self.name} {key}" + (f" lane {i}" if count > 1 else ""),
                    modules,
                    self.context.image,
                    self.health,
                    poll_period=cfg.poll_ms / 1000,
                    offline_probe_period=cfg.offline_probe_ms / 1000,
                    write_period=None
                    if cfg.write_period_ms is None
                    else cfg.write_period_ms / 1000,
                    retries=cfg.retries,
                    clock=self.context.clock,
                )
                scheduler.attach()  # outputs written by fronts from now on are queued
                self.lanes.append(Lane(key, link, scheduler, [d.address for d in group]))

    def _module(
        self, device: ModbusTcpDeviceConfig, link: ModbusTcpLink, specs: list[ChannelSpec]
    ) -> ModbusModule:
        module = ModbusModule(
            device,
            [s for s in specs if s.source.module == device.address],
            link,
            module_points(self.name, device),
            retry_period=self.config.offline_probe_ms / 1000,
            clock=self.context.clock,
            unit=self.config.unit_of(device),
            image=self.context.image,
        )
        self.modules[device.address] = module
        return module

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tasks:
            for lane in self.lanes:
                tasks.create_task(self._run_lane(lane), name=f"{lane.scheduler.name}")

    async def _run_lane(self, lane: Lane) -> None:
        await self._connect(lane.link)
        while True:
            try:
                await lane.scheduler.run()
            except LineLost as exc:
                await self._connect(lane.link, str(exc))

    def _lanes_of(self, link: ModbusTcpLink) -> list[Lane]:
        return [lane for lane in self.lanes if lane.link is link]

    async def _connect(self, link: ModbusTcpLink, cause: str | None = None) -> None:
        """Connect ``link`` (again), with back-off; one lane does it, the others of the link
        wait for it. While it is down its devices are offline (COMM_FAULT, at once)."""
        async with link.lock:
            if link.connected:
                return
            delay, cap = 0.0, max(REOPEN_FIRST_S, self.config.offline_probe_ms / 1000)
            lost_at = self.context.clock()
            connected_at, flaps = self._flaps.get(id(link), (lost_at, 0))
            if cause is not None and lost_at - connected_at < STABLE_S:
                flaps += 1  # lost right after it connected: not a network blip, a host that drops
                delay = min(REOPEN_FIRST_S * 2 ** (flaps - 1), cap)
                if flaps == 1:
                    log.warning(
                        "back %s: %s dropped the connection %.1f s after it opened (%s); "
                        "re-tried every %.1f s at most while it does",
                        self.name,
                        link.name,
                        lost_at - connected_at,
                        cause,
                        cap,
                    )
            else:
                flaps = 0
            while True:
                if delay:
                    await asyncio.sleep(delay)
                try:
                    await link.connect()
                    break
                except (OSError, TimeoutError) as exc:
                    text = f"{link.name}: {_why(exc)}"
                    link.lost_reason = _why(exc)
                    if not self._outage.get(id(link)):
                        self._outage[id(link)] = True
                        log.warning(
                            "back %s: cannot connect to %s (%s); its devices are offline, "
                            "re-tried every %.1f s at most",
                            self.name,
                            link.name,
                            _why(exc),
                            cap,
                        )
                        for lane in self._lanes_of(link):
                            lane.scheduler.line_lost(text)
                    delay = min(max(delay * 2, REOPEN_FIRST_S), cap)
            self._flaps[id(link)] = (self.context.clock(), flaps)
            if self._outage.pop(id(link), False) or (cause is not None and not flaps):
                log.warning(
                    "back %s: connected to %s again after %.1f s",
                    self.name,
                    link.name,
                    self.context.clock() - lost_at,
                )
            for lane in self._lanes_of(link):
                lane.scheduler.line_reopened()

    async def flush_outputs(self, timeout: float = 2.0) -> None:
        """Write pending outputs (shutdown values) on the connections that are up."""
        deadline = self.context.clock() + timeout
        for lane in self.lanes:
            while (
                lane.link.connected
                and lane.scheduler.pending_writes
                and self.context.clock() < deadline
            ):
                try:
                    await lane.scheduler.step()
                except LineLost:
                    break

    async def stop(self) -> None:
        for lane in self.lanes:
            lane.scheduler.detach()
        for links in self.links.values():
            for link in links:
                link.close()

    # -- observability -------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        if not self.lanes:
            return {"running": False}
        hosts: dict[str, Any] = {}
        for key, links in self.links.items():
            lanes = [lane for lane in self.lanes if lane.host == key]
            hosts[key] = {
                "connections": [link.status() for link in links],
                "lanes": [{"devices": lane.addresses, **lane.scheduler.status()} for lane in lanes],
            }
        stats = ModbusStats()
        for links in self.links.values():
            for link in links:
                stats.requests.update(link.stats.requests)
                stats.errors.update(link.stats.errors)
                stats.exception_codes.update(link.stats.exception_codes)
                if link.stats.last_rtt is not None:
                    stats.last_rtt = link.stats.last_rtt
        modules = [h.as_dict() for h in self.health.values()]
        return {
            "hosts": hosts,
            "modules": modules,
            "requests": sum(lane.scheduler.stats.requests for lane in self.lanes),
            "modbus": {
                **stats.as_dict(),
                "refused_points": sorted(cid for m in self.modules.values() for cid in m.bad),
            },
        }

    def point_locations(self) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for device in self.config.modules:
            where = self.config.describe_module(device)
            for p in module_points(self.name, device):
                out[p.channel] = [f"{where}: {describe_point(p)}"]
        return out

    def module_config(self, address: int) -> ModuleConfig:
        return next(m for m in self.config.modules if m.address == address)


def _why(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "connect timed out"
    if isinstance(exc, OSError):
        return exc.strerror or str(exc) or type(exc).__name__
    return str(exc)
