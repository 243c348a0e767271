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
import socket
import time
from collections import Counter
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.server.internal_session import SessionState

from fieldgate.events import MASTER_BACK, MASTER_LOST, NMT_STATE, Event
from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.image import Change, Channel, Quality, Value
from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.metric_samples import counter, gauge
from fieldgate.plugin import Front, GatewayContext, PluginStartError

from . import deadband, logs, model
from .admission import AdmissionLimits
from .config import OpcUaFrontConfig
from .framing import FramingLimits
from .quality import status_code
from .security import TrustDirectory, Users, certificate_der, ensure_certificate
from .subscriptions import GuardedSubscriptions, SubscriptionLimits
from .transport import Guard, GuardedServer
from .writes import WriteGate, WriteTarget, data_value

POLICY = {
    "None": ua.SecurityPolicyType.NoSecurity,
    "Sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
}
VARIANT = {
    name: getattr(ua.VariantType, name)
    for name in (
        "Boolean",
        "Byte",
        "Int16",
        "UInt16",
        "Int32",
        "UInt32",
        "Int64",
        "UInt64",
        "Float",
        "Double",
        "String",
    )
}
UNIT_NS = "http://www.opcfoundation.org/UA/units/un/cefact"
# UNECE Rec. 20 common codes of the units module manuals use (UnitId = the code as base-256 ASCII)
UNECE = {
    "°C": "CEL",
    "degC": "CEL",
    "V": "VLT",
    "mV": "2Z",
    "mA": "4K",
    "A": "AMP",
    "%": "P1",
    "bar": "BAR",
    "Pa": "PAL",
    "kPa": "KPA",
    "Hz": "HTZ",
    "ohm": "OHM",
    "Ω": "OHM",
    "m/s": "MTS",
    "rpm": "RPM",
    "K": "KEL",
    "W": "WTT",
    "kW": "KWT",
    "kWh": "KWH",
    "Wh": "WHR",
    "kvar": "KVR",
    "VA": "D46",
    "kVA": "KVA",
    "m3/h": "MQH",
    "l/min": "L2",
    "s": "SEC",
    "min": "MIN",
    "h": "HUR",
}


def unit_id(code: str) -> int:
    value = 0
    for ch in code:
        value = (value << 8) | ord(ch)
    return value


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
            ua.Variant(value, VARIANT[var.data_type]),
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
        host, port = cfg.host_port
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
        self.guard = Guard(
            FramingLimits(cfg.max_chunk_size, cfg.max_message_size, cfg.max_chunk_count),
            AdmissionLimits(
                cfg.max_connections,
                cfg.max_connections_per_peer,
                cfg.max_sessions,
                cfg.max_sessions_per_peer,
                cfg.hello_timeout_s,
                cfg.activation_timeout_s,
            ),
            self.log,
            cfg.anonymous_allowed,
            self.rejected,
        )
        server = GuardedServer(
            self.guard, user_manager=Users(passwords, cfg.anonymous_allowed, self._reject)
        )
        self._limit(server)
        await server.init()
        host_text = f"[{host}]" if ":" in host else host
        self.url = f"opc.tcp://{host_text}:{port}/"
        if host in ("0.0.0.0", "::"):  # every interface: advertise the host's name, bind to all
            self.url = f"opc.tcp://{socket.gethostname()}:{port}/"
            server.socket_address = (host, port)
        server.set_endpoint(self.url)
        server.set_server_name(f"fieldgate {gateway} ({self.name})")
        await server.set_application_uri(app_uri)
        server.set_security_policy([POLICY[m] for m in cfg.security])
        tokens: list[type] = []
        if cfg.anonymous_allowed:
            tokens.append(ua.AnonymousIdentityToken)
        if cfg.users:
            tokens.append(ua.UserNameIdentityToken)
        server.set_identity_tokens(tokens)
        if any(m != "None" for m in cfg.security):
            await self._load_security(server, app_uri, base_dir)
        self._ns = await server.register_namespace(self.namespace_uri)
        self.server = server
        await self._build(server)
        quiet = logging.getLogger(
            "asyncua.server.server"
        )  # it logs a bind failure with a traceback
        level = quiet.level
        quiet.setLevel(logging.CRITICAL)
        try:
            await server.start()
        except OSError as exc:
            raise PluginStartError(
                f"cannot listen on {cfg.listen}: {exc.strerror or exc}"
            ) from None
        finally:
            quiet.setLevel(level)
        self._listening = True
        if self._trust is not None:
            self._trust.guard(server._policies)  # asyncua keeps its channel policies there
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

    def _limit(self, server: GuardedServer) -> None:
        """The configuration's limits on asyncua's internal server (before it is started)."""
        cfg = self.config
        iserver = server.iserver
        iserver.max_session_timeout_ms = cfg.max_session_timeout_ms
        iserver.max_monitored_item_queue_size = cfg.max_queue_size
        iserver.max_unacked_messages_per_subscription = cfg.max_retransmission_queue
        iserver.max_subscriptions = cfg.max_sessions * cfg.max_subscriptions_per_session
        subscriptions = GuardedSubscriptions(
            iserver.aspace,
            iserver,
            SubscriptionLimits(
                cfg.min_publishing_interval_ms,
                cfg.min_sampling_interval_ms,
                cfg.max_subscriptions_per_session,
                cfg.max_monitored_items_per_subscription,
                cfg.max_monitored_items_per_session,
                cfg.max_queue_size,
            ),
            self._subscription_event,
        )
        iserver.subscription_service = subscriptions
        iserver.isession.subscription_service = subscriptions
        self._subscriptions = subscriptions

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

    async def _load_security(self, server: Server, app_uri: str, base_dir: Path) -> None:
        cfg = self.config
        state = self.context.state_dir
        try:
            if cfg.certificate_file is not None and cfg.private_key_file is not None:
                cert_path = _resolve(base_dir, cfg.certificate_file)
                key_path = _resolve(base_dir, cfg.private_key_file)
                cert, key = certificate_der(cert_path), key_path.read_bytes()
            else:
                cert, key = ensure_certificate(
                    state / f"{self.name}.opcua-cert.der",
                    state / f"{self.name}.opcua-key.pem",
                    app_uri,
                    f"fieldgate {self.context.topology.gateway.name}",
                )
            await server.load_certificate(cert, format="DER")
            await server.load_private_key(key, format="PEM")
        except (OSError, ValueError) as exc:
            raise PluginStartError(f"server certificate: {exc}") from None
        trusted = (
            _resolve(base_dir, cfg.trusted_clients_dir)
            if cfg.trusted_clients_dir is not None
            else state / f"{self.name}.opcua-pki" / "trusted"
        )
        trusted.mkdir(parents=True, exist_ok=True)
        self._trust = TrustDirectory(trusted, self._reject)
        server.set_certificate_validator(self._trust)

    async def _build(self, server: Server) -> None:
        ctx = self.context
        cfg = self.config
        channels = ctx.front_channels(cfg)
        modules = {m.key: m.model for m in ctx.health.modules()}
        lines: dict[str, str] = {}
        for back_cfg in ctx.topology.backs:
            port = getattr(back_cfg, "port", None)
            baud = getattr(back_cfg, "baudrate", None)
            lines[back_cfg.name] = (
                f"{back_cfg.type}"
                + (f" on {port}" if port else "")
                + (f" at {baud} baud" if baud else "")
            )
        try:
            locations = ctx.point_locations()
        except Exception:  # noqa: BLE001  (only descriptions depend on it)
            self.log.debug("point_locations failed", exc_info=True)
            locations = {}
        others = [f.name for f in ctx.topology.fronts if f.name != self.name]
        space = model.build(
            ctx.topology.gateway.name, channels, cfg.writable, modules, lines, locations, others
        )
        self.space = space
        nodes: dict[str | None, Any] = {None: server.nodes.objects}
        for folder in space.folders:
            parent = nodes[folder.parent]
            node = await parent.add_folder(
                self._nid(folder.node_id), ua.QualifiedName(folder.browse_name, self._ns)
            )
            if folder.description:
                await node.write_attribute(
                    ua.AttributeIds.Description,
                    ua.DataValue(ua.Variant(ua.LocalizedText(folder.description))),
                )
            nodes[folder.node_id] = node
        ranges: dict[ua.NodeId, tuple[float, float]] = {}
        targets: dict[ua.NodeId, WriteTarget] = {}
        by_id = {c.id: c for c in channels}
        for var in space.variables:
            nid = self._nid(var.node_id)
            parent = nodes[var.parent]
            vtype = VARIANT[var.data_type]
            if var.channel_id is not None:
                channel = by_id[var.channel_id]
                initial = self._datavalue(var, channel)
            else:
                initial = ua.DataValue(ua.Variant(_zero(var.data_type), vtype))
            node = await parent.add_variable(
                nid,
                ua.QualifiedName(var.browse_name, self._ns),
                initial.Value,
                varianttype=vtype,
                datatype=ua.NodeId(vtype.value),
            )
            await node.write_attribute(
                ua.AttributeIds.Description,
                ua.DataValue(ua.Variant(ua.LocalizedText(var.description))),
            )
            access = ua.AccessLevel.CurrentRead.mask | (
                ua.AccessLevel.CurrentWrite.mask if var.writable else 0
            )
            await node.write_attribute(
                ua.AttributeIds.AccessLevel, ua.DataValue(ua.Variant(access, ua.VariantType.Byte))
            )
            await node.write_attribute(
                ua.AttributeIds.UserAccessLevel,
                ua.DataValue(ua.Variant(access, ua.VariantType.Byte)),
            )
            if var.eu_range is not None:
                ranges[nid] = var.eu_range
                await node.add_property(
                    self._nid(f"{var.node_id}/EURange"),
                    "EURange",
                    ua.Range(Low=var.eu_range[0], High=var.eu_range[1]),
                )
            if var.unit is not None:
                code = UNECE.get(var.unit)
                eu = ua.EUInformation(
                    NamespaceUri=UNIT_NS,
                    UnitId=unit_id(code) if code else -1,
                    DisplayName=ua.LocalizedText(var.unit),
                    Description=ua.LocalizedText(var.unit),
                )
                await node.add_property(
                    self._nid(f"{var.node_id}/EngineeringUnits"), "EngineeringUnits", eu
                )
            if var.channel_id is not None:
                await server.write_attribute_value(nid, initial)
                self._vars.setdefault(var.channel_id, []).append((nid, var))
                if var.writable:
                    targets[nid] = WriteTarget(
                        var.channel_id, vtype, channel.spec.data_type, channel.check
                    )
            else:
                self._other[var.node_id] = nid
        deadband.set_ranges(server.iserver.aspace, ranges)
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
                        ua.Variant(value, VARIANT[dtype]),
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
        server = self.server
        if server is None or server.bserver is None:
            return []
        out = []
        for proto in list(server.bserver.clients):
            session = getattr(proto.processor, "session", None)
            user = getattr(session, "user", None)
            peer = proto.peer_name
            out.append(
                {
                    "peer": f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else repr(peer),
                    "session": str(getattr(session, "name", "")),
                    "user": getattr(user, "name", None)
                    or ("anonymous" if user is not None else ""),
                }
            )
        return out

    def held(self) -> dict[str, int]:
        """What clients hold now: connections, sessions, subscriptions, monitored items."""
        server = self.server
        if server is None:
            return {}
        iserver = server.iserver
        subs = self._subscriptions
        return {
            "connections": len(server.bserver.clients) if server.bserver is not None else 0,
            "sessions": sum(
                1 for s in iserver._external_sessions.values() if s.state != SessionState.Closed
            ),
            "subscriptions": len(subs.subscriptions) if subs is not None else 0,
            "monitored_items": subs.monitored_items if subs is not None else 0,
        }

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
        front = self.name
        held = self.held()
        rows = [
            gauge("opcua_clients", "client connections open", len(self.clients()), front=front),
            gauge("opcua_sessions", "sessions open", held["sessions"], front=front),
            gauge("opcua_subscriptions", "subscriptions", held["subscriptions"], front=front),
            gauge("opcua_monitored_items", "monitored items", held["monitored_items"], front=front),
            counter(
                "opcua_value_updates_total",
                "node values written from process image changes",
                self.counters["value_updates"],
                front=front,
            ),
            counter(
                "opcua_writes_total",
                "client writes applied to outputs",
                self.counters["writes"],
                front=front,
            ),
            counter(
                "opcua_write_errors_total",
                "client writes refused",
                self.counters["write_errors"],
                front=front,
            ),
            counter(
                "opcua_subscriptions_expired_total",
                "subscriptions deleted after their lifetime without a Publish request",
                self.counters["subscriptions_expired"],
                front=front,
            ),
        ]
        rows += [
            counter(
                "opcua_rejected_total",
                "connections, sessions and requests refused or closed, by reason",
                n,
                front=front,
                reason=reason,
            )
            for reason, n in sorted(self.rejected.items())
        ]
        faults = self.guard.faults if self.guard is not None else Counter()
        rows += [
            counter(
                "opcua_service_faults_total",
                "requests answered with a ServiceFault, by status",
                n,
                front=front,
                status=status,
            )
            for status, n in sorted(faults.items())
        ]
        return rows

    def point_locations(self) -> dict[str, list[str]]:
        return {
            cid: [f"ns={self.namespace_uri};s={var.node_id}" for _, var in nodes]
            for cid, nodes in self._vars.items()
        }


def _resolve(base: Path, name: str) -> Path:
    path = Path(name)
    return path if path.is_absolute() else base / path


def _now() -> Any:  # asyncua types timestamps ua.DateTime (a datetime)
    return datetime.datetime.now(datetime.UTC)


def _zero(dtype: str) -> Any:
    return {"Boolean": False, "String": "", "Float": 0.0, "Double": 0.0}.get(dtype, 0)


logging.getLogger("asyncua").setLevel(logging.WARNING)
