"""The Sparkplug front's metric rows for the gateway's Prometheus endpoint: a table of
what each row shows, read from the session and the link's counters."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.metric_samples import counter, gauge

from .actions import State
from .session import Session


@dataclass(frozen=True)
class Figures:
    """What the rows read: the session, and the front's own counters."""

    session: Session
    age_s: float  # of the oldest journaled sample
    outbox: int
    writes: int
    write_errors: int
    published: Counter[str]
    dropped: Counter[str]


class Row(Protocol):
    def __call__(self, name: str, help_text: str, value: float, **labels: str) -> MetricSample: ...


SINGLE: tuple[tuple[Row, str, str, Callable[[Figures], float]], ...] = (
    (
        gauge,
        "sparkplug_connected",
        "1 while the edge node session is publishing (NBIRTH sent)",
        lambda f: f.session.state is State.ONLINE,
    ),
    (
        gauge,
        "sparkplug_bdseq",
        "bdSeq of the current or next MQTT connection",
        lambda f: f.session.bdseq,
    ),
    (
        gauge,
        "sparkplug_backlog_messages",
        "samples waiting in the store-and-forward journal",
        lambda f: f.session.journal.count(),
    ),
    (
        gauge,
        "sparkplug_backlog_oldest_age_seconds",
        "age of the oldest sample in the journal",
        lambda f: f.age_s,
    ),
    (
        counter,
        "sparkplug_dropped_messages_total",
        "samples dropped from the journal (full, or channel gone)",
        lambda f: f.session.dropped,
    ),
    (
        counter,
        "sparkplug_replayed_messages_total",
        "journaled samples sent as historical DDATA",
        lambda f: f.session.replayed,
    ),
    (
        counter,
        "sparkplug_connects_total",
        "accepted MQTT connections",
        lambda f: f.session.connects,
    ),
    (
        gauge,
        "sparkplug_outbox_messages",
        "messages waiting to be handed to the MQTT client",
        lambda f: f.outbox,
    ),
    (counter, "sparkplug_writes_total", "outputs written by DCMD", lambda f: f.writes),
    (
        counter,
        "sparkplug_write_errors_total",
        "DCMD output writes refused by the process image",
        lambda f: f.write_errors,
    ),
)
"""One row each: factory, name, help, value."""

BY_LABEL: tuple[tuple[str, str, str, Callable[[Figures], Mapping[str, int]]], ...] = (
    (
        "sparkplug_messages_total",
        "Sparkplug messages published, by type",
        "type",
        lambda f: f.session.sent,
    ),
    (
        "sparkplug_published_messages_total",
        "messages handed to the MQTT client, by type",
        "type",
        lambda f: f.published,
    ),
    (
        "sparkplug_publish_dropped_total",
        "messages never handed to the MQTT client, by reason (rebirth: DATA of the old births, its samples journaled)",
        "reason",
        lambda f: f.dropped,
    ),
    (
        "sparkplug_rebirths_total",
        "NBIRTH sequences, by reason",
        "reason",
        lambda f: f.session.rebirths,
    ),
    (
        "sparkplug_ignored_commands_total",
        "incoming messages ignored, by reason",
        "reason",
        lambda f: f.session.ignored,
    ),
)
"""A counter row per label value: name, help, label, counts."""


def metric_rows(front: str, figures: Figures) -> list[MetricSample]:
    """Every row of :data:`SINGLE`, then :data:`BY_LABEL`'s, labelled ``front``."""
    rows = [
        make(name, text, float(value(figures)), front=front) for make, name, text, value in SINGLE
    ]
    for name, text, label, counts in BY_LABEL:
        rows += [
            counter(name, text, count, front=front, **{label: key})
            for key, count in sorted(counts(figures).items())
        ]
    return rows
