"""What the ``opcua`` front shows of its clients: who is connected, what they hold, and its
metric rows for the gateway's Prometheus endpoint."""

from __future__ import annotations

from collections import Counter
from typing import Any

from asyncua import Server
from asyncua.server.internal_session import SessionState

from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.metric_samples import counter, gauge

from .subscriptions import GuardedSubscriptions

COUNTERS = (
    (
        "opcua_value_updates_total",
        "node values written from process image changes",
        "value_updates",
    ),
    ("opcua_writes_total", "client writes applied to outputs", "writes"),
    ("opcua_write_errors_total", "client writes refused", "write_errors"),
    (
        "opcua_subscriptions_expired_total",
        "subscriptions deleted after their lifetime without a Publish request",
        "subscriptions_expired",
    ),
)
"""The front's counters as metric rows: name, help, key in its ``counters``."""


def clients(server: Server) -> list[dict[str, Any]]:
    """Each client connection: peer address, session name, user."""
    if server.bserver is None:
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
                "user": getattr(user, "name", None) or ("anonymous" if user is not None else ""),
            }
        )
    return out


def held(server: Server, subs: GuardedSubscriptions | None) -> dict[str, int]:
    """What clients hold now: connections, sessions, subscriptions, monitored items."""
    iserver = server.iserver
    return {
        "connections": len(server.bserver.clients) if server.bserver is not None else 0,
        "sessions": sum(
            1 for s in iserver._external_sessions.values() if s.state != SessionState.Closed
        ),
        "subscriptions": len(subs.subscriptions) if subs is not None else 0,
        "monitored_items": subs.monitored_items if subs is not None else 0,
    }


def metric_rows(
    front: str,
    n_clients: int,
    holding: dict[str, int],
    counters: Counter[str],
    rejected: Counter[str],
    faults: Counter[str],
) -> list[MetricSample]:
    rows = [
        gauge("opcua_clients", "client connections open", n_clients, front=front),
        gauge("opcua_sessions", "sessions open", holding["sessions"], front=front),
        gauge("opcua_subscriptions", "subscriptions", holding["subscriptions"], front=front),
        gauge("opcua_monitored_items", "monitored items", holding["monitored_items"], front=front),
    ]
    rows += [counter(name, text, counters[key], front=front) for name, text, key in COUNTERS]
    by_label = (
        (
            "opcua_rejected_total",
            "connections, sessions and requests refused or closed, by reason",
            "reason",
            rejected,
        ),
        (
            "opcua_service_faults_total",
            "requests answered with a ServiceFault, by status",
            "status",
            faults,
        ),
    )
    for name, text, label, counts in by_label:
        rows += [
            counter(name, text, n, front=front, **{label: key}) for key, n in sorted(counts.items())
        ]
    return rows
