"""The ``opcua`` front: the process image served by an OPC UA server (asyncua).

The address space comes from :mod:`.model` (stable string node ids from channel ids); each
change of the process image (its subscription callback, in the writer's loop turn) becomes a
value write on the node with the quality's StatusCode (:mod:`.quality`) and the acquisition
time as source timestamp, so monitored items are fed by the image's change events, never by
polling it. Data-change filters (absolute and percent deadband) are :mod:`.deadband`'s.
Client writes reach only outputs listed in ``writable`` (the other variables are read-only),
under the one-writer rule the topology checks, through ``context.set_outputs``: the Write
is answered once the fieldbus side applied it (:mod:`.writes`).

What a client can make the server hold is bounded by the front's configuration, checked
before anything is buffered (:mod:`.transport`, :mod:`.framing`, :mod:`.admission`,
:mod:`.subscriptions`); asyncua's log lines about clients' faults are one line each and
rate-limited (:mod:`.logs`). The front uses only what a north-facing child process has of
the gateway: ``context.image`` (its channels and change stream), ``health``, ``masters``,
``events``, ``topology``, ``state_dir``, ``front_channels``, ``set_outputs`` and
``point_locations``.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import logging
import time
from collections import Counter
from typing import Any

from asyncua import Server, ua

from fieldgate.events import MASTER_BACK, MASTER_LOST, NMT_STATE, Event
from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.image import Change, Channel, Quality, Value
from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.plugin import Front, GatewayContext, PluginStartError

from . import deadband, logs, model, nodes, observe, server_setup
from .config import OpcUaFrontConfig
from .quality import status_code
from .security import TrustDirectory, Users
from .subscriptions import GuardedSubscriptions
from .transport import Guard, GuardedServer
from .writes import WriteGate, WriteTarget, data_value


class OpcUaFront(Front):
    def __init__(self, config: OpcUaFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.config: OpcUaFrontConfig = config
        self.server: Server | None = None
        self.space: model.AddressSpace | None = None
        self.url = ""
        self.namespace_uri = ""
        self._ns = 0
        self._vars: dict[str, list[tuple[ua.NodeId, model.Variable]]] = {}  # channel id -> nodes
        self._other: dict[str, ua.NodeId] = {}  # health/front node id text -> NodeId
        self._pending: list[tuple[ua.NodeId, ua.DataValue]] = []
        self._flush_task: asyncio.Task[None] | None = None
        self._subscription: Any = None
        self._listening = False
        self._wall_offset = 0.0
        self._cancel_events: Any = None
        self._trust: TrustDirectory | None = None
        self._listeners_added = False
        self.counters: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()  # refusals and evictions, by reason
        self.guard: Guard | None = None
        self._subscriptions: GuardedSubscriptions | None = None

    # -- helpers ----------------------------------------------------------------------------
    def _nid(self, text: str) -> ua.NodeId:
        return ua.NodeId(ua.String(text), ua.Int16(self._ns))

    def _stamp(self, channel: Channel) -> Any:  # asyncua types it ua.DateTime (a datetime)
        """Acquisition time of a good value; the time of the change otherwise."""
        mono = (
            channel.timestamp
            if channel.quality is Quality.GOOD and channel.timestamp is not None
            else self.context.image.clock()
        )
        return datetime.datetime.fromtimestamp(mono + self._wall_offset, datetime.UTC)

    def _datavalue(self, var: model.Variable, channel: Channel) -> ua.DataValue:
        raw = channel.value
        value: Any = (
            channel.spec.scaling.to_engineering(float(raw))
            if var.engineering and channel.spec.scaling
            else raw
        )
        if var.data_type in ("Float", "Double"):
            value = float(value)
        return ua.DataValue(
            ua.Variant(value, nodes.VARIANT[var.data_type]),
            ua.StatusCode(ua.UInt32(status_code(channel.quality))),
            SourceTimestamp=self._stamp(channel),
            ServerTimestamp=_now(),
        )

    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1

    # -- life cycle -------------------------------------------------------------------------
    async def start(self) -> None:
        cfg = self.config
        ctx = self.context
        gateway = ctx.topology.gateway.name
        base_dir = ctx.topology.base_dir
        self._wall_offset = time.time() - ctx.image.clock()
        passwords: dict[str, str] = {}
        for user in cfg.users:
            try:
                passwords[user.name] = user.password(base_dir)
            except ValueError as exc:
                raise PluginStartError(f"user {user.name}: {exc}") from None
        logs.install()
        self.namespace_uri = cfg.namespace_uri or f"urn:fieldgate:{gateway}"
        app_uri = f"urn:fieldgate:{gateway}:{self.name}"
        self.guard = server_setup.new_guard(cfg, self.log, self.rejected)
        server = GuardedServer(
            self.guard, user_manager=Users(passwords, cfg.anonymous_allowed, self._reject)
        )
        self._subscriptions = server_setup.limit(server, cfg, self._subscription_event)
        await server.init()
        name = f"fieldgate {gateway} ({self.name})"
        self.url = await server_setup.set_endpoint(server, cfg, name, app_uri)
        if any(m != "None" for m in cfg.security):
            self._trust = await server_setup.load_security(
                server,
                cfg,
                front=self.name,
                gateway=gateway,
                app_uri=app_uri,
                state=ctx.state_dir,
                base_dir=base_dir,
                reject=self._reject,
            )
        self._ns = await server.register_namespace(self.namespace_uri)
        self.server = server
        await self._build(server)
        await self._listen(server)
        channels = [c for c in ctx.front_channels(cfg)]
        self._subscription = ctx.image.subscribe_batch(
            self._on_changes, ids=[c.id for c in channels]
        )
        if not self._listeners_added:  # health and masters keep listeners for good: add them once
            self._listeners_added = True
            ctx.health.subscribe(self._on_health)
            ctx.masters.subscribe(self._on_master)
        self._cancel_events = ctx.events.subscribe(self._on_event)
        self.log.info(
            "OPC UA server on %s (security %s%s): %d variables, namespace %s",
            self.url,
            ", ".join(cfg.security),
            ", anonymous allowed" if cfg.anonymous_allowed else f", {len(cfg.users)} user(s)",
            len(self.space.variables) if self.space else 0,
            self.namespace_uri,
        )

    async def _listen(self, server: GuardedServer) -> None:
        quiet = logging.getLogger(
            "asyncua.server.server"
        )  # it logs a bind failure with a traceback
        level = quiet.level
        quiet.setLevel(logging.CRITICAL)
        try:
            await server.start()
        except OSError as exc:
            raise PluginStartError(
                f"cannot listen on {self.config.listen}: {exc.strerror or exc}"
            ) from None
        finally:
            quiet.setLevel(level)
        self._listening = True
        if self._trust is not None:
            self._trust.guard(server._policies)  # asyncua keeps its channel policies there

    def _subscription_event(self, what: str, n: int) -> None:
        if what == "subscription_expired":
            self.counters["subscriptions_expired"] += n
        elif self.guard is not None:
            cfg = self.config
            limit = (
                f"at most {cfg.max_subscriptions_per_session} per session"
                if what == "too_many_subscriptions"
                else f"at most {cfg.max_monitored_items_per_subscription} per subscription and "
                f"{cfg.max_monitored_items_per_session} per session"
            )
            text = f"{n} {what.removeprefix('too_many_').replace('_', ' ')} refused ({limit})"
            self.guard.note(what, "of a session", text, n=n)

    async def _build(self, server: Server) -> None:
        """The address space (:mod:`.model`) on the server (:mod:`.nodes`), client writes
        to its writable variables gated (:mod:`.writes`), and the values known now."""
        ctx = self.context
        channels = ctx.front_channels(self.config)
        try:
            locations = ctx.point_locations()
        except Exception:  # noqa: BLE001  (only descriptions depend on it)
            self.log.debug("point_locations failed", exc_info=True)
            locations = {}
        others = [f.name for f in ctx.topology.fronts if f.name != self.name]
        modules = {m.key: m.model for m in ctx.health.modules()}
        self.space = model.build(
            ctx.topology.gateway.name,
            channels,
            self.config.writable,
            modules,
            nodes.back_lines(ctx.topology),
            locations,
            others,
        )
        targets = await self._add_nodes(server, self.space, {c.id: c for c in channels})
        iserver = server.iserver
        iserver.attribute_service = WriteGate(
            iserver.attribute_service,
            iserver.aspace,
            targets,
            self._set_outputs,
            self._applied,
            self.counters,
            self.log,
        )
        for health in ctx.health.modules():
            self._health_values(health)
        for name in others:
            self._set_other(f"fronts/{name}/master_present", ctx.masters.is_ok(name), "Boolean")
        for event in ctx.events.recent():  # what the fronts started before this one reported
            self._on_event(event)
        self._schedule()

    async def _add_nodes(
        self, server: Server, space: model.AddressSpace, by_id: dict[str, Channel]
    ) -> dict[ua.NodeId, WriteTarget]:
        """Every folder and variable; the channels' variables get their current values.
        Returns the write targets of the writable ones."""
        folders = await nodes.add_folders(server, space, self._nid, self._ns)
        ranges: dict[ua.NodeId, tuple[float, float]] = {}
        targets: dict[ua.NodeId, WriteTarget] = {}
        for var in space.variables:
            nid = self._nid(var.node_id)
            vtype = nodes.VARIANT[var.data_type]
            channel = by_id[var.channel_id] if var.channel_id is not None else None
            if channel is not None:
                initial = self._datavalue(var, channel)
            else:
                initial = ua.DataValue(ua.Variant(nodes.zero(var.data_type), vtype))
            await nodes.add_variable(folders[var.parent], var, self._nid, self._ns, initial)
            if var.eu_range is not None:
                ranges[nid] = var.eu_range
            if var.channel_id is None or channel is None:
                self._other[var.node_id] = nid
                continue
            await server.write_attribute_value(nid, initial)
            self._vars.setdefault(var.channel_id, []).append((nid, var))
            if var.writable:
                targets[nid] = WriteTarget(
                    var.channel_id, vtype, channel.spec.data_type, channel.check
                )
        deadband.set_ranges(server.iserver.aspace, ranges)
        return targets

    async def run(self) -> None:
        await asyncio.Event().wait()  # the server runs on the loop; nothing else to do

    async def stop(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        if self._cancel_events is not None:
            self._cancel_events()
            self._cancel_events = None
        if self._flush_task is not None:
            self._flush_task.cancel()
            self._flush_task = None
        server, self.server = self.server, None
        self._vars.clear()
        self._other.clear()
        self._pending.clear()
        if server is not None and self._listening:
            self._listening = False
            # asyncua stops its server-time task by a flag it reads after a 1 s sleep: cancel
            # it instead, so a gateway's stop does not wait that second
            clock = server.iserver.time_task
            if clock is not None:
                clock.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await clock
                server.iserver.time_task = None
            await server.stop()

    # -- image -> nodes ----------------------------------------------------------------------
    def _on_changes(self, changes: list[Change]) -> None:
        """One process-image batch (a poll reply): every changed channel, one wake-up."""
        for change in changes:
            for nid, var in self._vars.get(change.id, ()):
                self._pending.append((nid, self._datavalue(var, change.channel)))
        self._schedule()

    def _on_health(self, health: ModuleHealth, event: HealthEvent) -> None:
        self._health_values(health)
        self._schedule()

    def _health_values(self, health: ModuleHealth) -> None:
        folder = f"{model.module_folder(health.back, health.address)}/health"
        if f"{folder}/online" not in self._other:
            return
        self._set_other(f"{folder}/online", health.online, "Boolean")
        self._set_other(f"{folder}/error_counter", health.error_counter & 0xFFFF, "UInt16")
        self._set_other(f"{folder}/consecutive_failures", health.consecutive_failures, "UInt32")
        self._set_other(f"{folder}/last_error", health.last_error, "String")

    def _on_master(self, front: str, ok: bool, reason: str) -> None:
        self._set_other(f"fronts/{front}/master_present", ok, "Boolean")
        self._schedule()

    def _on_event(self, event: Event) -> None:
        """A front's protocol state: its NMT state, or the last thing it reported (fault,
        bus-off); master lost/back have their own variable."""
        node = f"fronts/{event.source}/state"
        if node not in self._other or event.kind in (MASTER_LOST, MASTER_BACK):
            return
        state = event.data.get("new") if event.kind == NMT_STATE else event.text
        self._set_other(node, str(state or event.text), "String")
        self._schedule()

    def _set_other(self, node: str, value: Any, dtype: str) -> None:
        nid = self._other.get(node)
        if nid is not None:
            self._pending.append(
                (
                    nid,
                    ua.DataValue(
                        ua.Variant(value, nodes.VARIANT[dtype]),
                        SourceTimestamp=_now(),
                    ),
                )
            )

    def _schedule(self) -> None:
        if (
            self._pending
            and self.server is not None
            and (self._flush_task is None or self._flush_task.done())
        ):
            self._flush_task = asyncio.get_running_loop().create_task(self._flush())

    async def _flush(self) -> None:
        server = self.server
        while self._pending and server is not None:
            batch, self._pending = self._pending, []
            for nid, dv in batch:
                try:
                    await server.write_attribute_value(nid, dv)
                    self.counters["value_updates"] += 1
                except Exception:  # one bad node must not stop the others' updates
                    self.counters["update_errors"] += 1
                    if self.counters["update_errors"] == 1:
                        self.log.exception("writing %s into the address space failed", nid)

    # -- client writes ------------------------------------------------------------------------
    async def _set_outputs(self, values: Any) -> None:
        await self.context.set_outputs(values, origin=self.name)

    async def _applied(self, nid: ua.NodeId, target: WriteTarget, value: Value) -> None:
        """A client's write was applied: the node shows it at once (a Read right after the
        Write response sees it), with the channel's status."""
        server = self.server
        if server is None:
            return
        quality = self.context.image[target.channel_id].quality
        await server.write_attribute_value(nid, data_value(target, value, status_code(quality)))

    # -- observability -------------------------------------------------------------------------
    def clients(self) -> list[dict[str, Any]]:
        return [] if self.server is None else observe.clients(self.server)

    def held(self) -> dict[str, int]:
        """What clients hold now: connections, sessions, subscriptions, monitored items."""
        return {} if self.server is None else observe.held(self.server, self._subscriptions)

    def status(self) -> dict[str, Any]:
        if self.server is None:
            return {}
        clients = self.clients()
        faults = self.guard.faults if self.guard is not None else Counter()
        return {
            "state": "listening" if self._listening else "stopped",
            "endpoint": self.url,
            "security": list(self.config.security),
            "namespace": self.namespace_uri,
            "variables": len(self.space.variables) if self.space else 0,
            "clients": clients,
            "held": self.held(),
            "counters": {
                "value_updates": self.counters["value_updates"],
                "writes": self.counters["writes"],
                "write_errors": self.counters["write_errors"],
                "subscriptions_expired": self.counters["subscriptions_expired"],
                **{f"rejected_{k}": v for k, v in sorted(self.rejected.items())},
            },
            "service_faults": dict(sorted(faults.items())),
        }

    def metrics(self) -> list[MetricSample]:
        if self.server is None:
            return []
        faults = self.guard.faults if self.guard is not None else Counter()
        return observe.metric_rows(
            self.name, len(self.clients()), self.held(), self.counters, self.rejected, faults
        )

    def point_locations(self) -> dict[str, list[str]]:
        return {
            cid: [f"ns={self.namespace_uri};s={var.node_id}" for _, var in nodes]
            for cid, nodes in self._vars.items()
        }


def _now() -> Any:  # asyncua types timestamps ua.DateTime (a datetime)
    return datetime.datetime.now(datetime.UTC)


logging.getLogger("asyncua").setLevel(logging.WARNING)
