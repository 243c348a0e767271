"""Prometheus exposition of a running gateway, built at scrape time.

A private :class:`prometheus_client.CollectorRegistry` holds one custom collector that
reads what the components already keep (``status()``, module health, line statistics,
the process image) when ``/metrics`` is scraped: nothing is counted per frame for it.

Components add their own series through a method a front or back MAY have::

    def metrics(self) -> list[tuple[str, str, str, float, dict[str, str]]]:
        return [("canopen_emcy_sent_total", "counter", "EMCY frames sent", 3, {})]

(name without the ``fieldgate_`` prefix, ``"counter"`` or ``"gauge"``, help text, value,
labels). The collector adds the prefix and a ``component`` label with the component's
name; a counter's name must end in ``_total`` and a gauge's must not. A sample that
breaks a rule (bad name or label, wrong type, a type or help that differs between two
samples of one name) is dropped and logged once; a scrape never fails because of it.
"""

from __future__ import annotations

import asyncio
import logging
import math
import platform
import re
import time
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
    Metric,
)

from ..health import RTT_BUCKETS, ErrorKind, LineStats
from ..image import Quality
from ..version import __version__
from .explain import readiness

if TYPE_CHECKING:
    from .view import GatewayView

log = logging.getLogger("fieldgate.http.metrics")

PREFIX = "fieldgate_"
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
_NAME = re.compile(r"^[a-zA-Z_][a-zA-Z0-9_]*$")
_LABEL = re.compile(r"^[a-zA-Z_][a-zA-Z0-9_]*$")
RESERVED_LABELS = frozenset({"component"})

ComponentSample = tuple[str, str, str, float, dict[str, str]]


class ComponentMetricsError(ValueError):
    pass


def check_sample(sample: Any) -> ComponentSample:
    """A component's metric sample as the contract says, or ComponentMetricsError saying why not."""
    if not isinstance(sample, tuple) or len(sample) != 5:
        raise ComponentMetricsError(
            "expected (name, type, help, value, labels), got " + type(sample).__name__
        )
    name, mtype, help_text, value, labels = sample
    if not isinstance(name, str) or not _NAME.match(name) or name.startswith(PREFIX):
        raise ComponentMetricsError(
            f"bad metric name {name!r} (letters, digits, _; without the {PREFIX} prefix)"
        )
    if mtype not in ("counter", "gauge"):
        raise ComponentMetricsError(f"{name}: type must be 'counter' or 'gauge', got {mtype!r}")
    if mtype == "counter" and not name.endswith("_total"):
        raise ComponentMetricsError(f"{name}: a counter's name must end in _total")
    if mtype == "gauge" and name.endswith("_total"):
        raise ComponentMetricsError(f"{name}: only counters end in _total")
    if not isinstance(help_text, str):
        raise ComponentMetricsError(f"{name}: help must be a string")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ComponentMetricsError(f"{name}: value must be a number, got {value!r}")
    if mtype == "counter" and (value < 0 or math.isnan(value)):
        raise ComponentMetricsError(f"{name}: a counter cannot be {value}")
    if not isinstance(labels, dict):
        raise ComponentMetricsError(f"{name}: labels must be a dict")
    for key, label_value in labels.items():
        if not isinstance(key, str) or not _LABEL.match(key) or key.startswith("__"):
            raise ComponentMetricsError(f"{name}: bad label name {key!r}")
        if key in RESERVED_LABELS:
            raise ComponentMetricsError(f"{name}: label {key!r} is set by fieldgate")
        if not isinstance(label_value, str):
            raise ComponentMetricsError(f"{name}: label {key} must be a string")
    return name, mtype, help_text, float(value), labels


class GatewayCollector:
    """Reads a :class:`~fieldgate.runtime.Gateway` at scrape time."""

    def __init__(self, gateway: GatewayView, *, point_metrics: bool = False, extra: Any = None):
        self.gateway = gateway
        self.point_metrics = point_metrics
        self.extra = extra  # the HTTP service: its own counters
        self.started_wall = time.time()
        self._logged: set[tuple[str, str]] = set()
        self.rejected = 0

    def _log_once(self, component: str, text: str) -> None:
        self.rejected += 1
        key = (component, text)
        if key not in self._logged:
            self._logged.add(key)
            log.warning("metrics of %s: %s (dropped)", component, text)

    def collect(self) -> Iterator[Metric]:
        gw = self.gateway
        yield from self._gateway(gw)
        yield from self._modules(gw)
        yield from self._lines(gw)
        yield from self._points(gw)
        yield from self._events(gw)
        if self.extra is not None:
            yield from self.extra.metrics_families()
        yield from self._components(gw)

    # -- core -------------------------------------------------------------------------
    def _gateway(self, gw: GatewayView) -> Iterator[Metric]:
        info = InfoMetricFamily("fieldgate_build", "fieldgate version and gateway identity")
        info.add_metric(
            [],
            {
                "version": __version__,
                "python": platform.python_version(),
                "gateway": gw.topology.gateway.name,
            },
        )
        yield info
        yield GaugeMetricFamily(
            "fieldgate_start_time_seconds",
            "when the gateway process started serving metrics (Unix time)",
            value=self.started_wall,
        )
        ready, _ = readiness(gw)
        yield GaugeMetricFamily(
            "fieldgate_ready", "1 when every front and back is started", value=float(ready)
        )
        up = GaugeMetricFamily(
            "fieldgate_component_up",
            "1 while a front or back runs, 0 while it waits for a restart",
            labels=["component", "role"],
        )
        restarts = CounterMetricFamily(
            "fieldgate_component_restarts",
            "restarts of a front or back after a run-time failure",
            labels=["component", "role"],
        )
        master = GaugeMetricFamily(
            "fieldgate_master_present",
            "1 while a front's fieldbus master is present (guarding, heartbeat, connection)",
            labels=["component"],
        )
        for role, comps in (("back", gw.backs), ("front", gw.fronts)):
            for comp in comps:
                running = getattr(comp, "started", False) and comp.name not in gw.down
                up.add_metric([comp.name, role], float(running))
                restarts.add_metric([comp.name, role], float(gw.restarts(comp.name)))
        for comp in gw.fronts:
            master.add_metric([comp.name], float(gw.masters.is_ok(comp.name)))
        yield from (up, restarts, master)

    def _modules(self, gw: GatewayView) -> Iterator[Metric]:
        labels = ["back", "module"]
        module_up = GaugeMetricFamily(
            "fieldgate_module_up",
            "1 while a module answers (0: offline)",
            labels=[*labels, "model"],
        )
        failures = GaugeMetricFamily(
            "fieldgate_module_consecutive_failures",
            "failed transactions in a row (offline when above fail_threshold)",
            labels=labels,
        )
        transactions = CounterMetricFamily(
            "fieldgate_transactions",
            "transactions with a module by result (ok, or the error kind)",
            labels=[*labels, "result"],
        )
        latency = HistogramMetricFamily(
            "fieldgate_poll_duration_seconds",
            "round trip of successful transactions with a module",
            labels=labels,
        )
        for m in gw.health.modules():
            key = [m.back, str(m.address)]
            module_up.add_metric([*key, m.model], float(m.online))
            failures.add_metric(key, float(m.consecutive_failures))
            errors = sum(m.errors.values())
            transactions.add_metric([*key, "ok"], float(m.requests - errors))
            for kind in ErrorKind:
                transactions.add_metric([*key, kind.value], float(m.errors.get(kind, 0)))
            cumulative, buckets = 0, []
            for bound, count in zip((*RTT_BUCKETS, math.inf), m.rtt_counts, strict=True):
                cumulative += count
                buckets.append(("+Inf" if bound == math.inf else repr(bound), float(cumulative)))
            latency.add_metric(key, buckets, m.rtt_sum)
        yield from (module_up, failures, transactions, latency)

    def _lines(self, gw: GatewayView) -> Iterator[Metric]:
        cycles = CounterMetricFamily(
            "fieldgate_line_cycles",
            "poll cycles completed (every online module polled once)",
            labels=["back"],
        )
        cycle_time = GaugeMetricFamily(
            "fieldgate_line_last_cycle_seconds",
            "duration of the last complete poll cycle",
            labels=["back"],
        )
        writes = CounterMetricFamily(
            "fieldgate_line_writes", "output write transactions to modules", labels=["back"]
        )
        pending = GaugeMetricFamily(
            "fieldgate_line_pending_writes", "outputs waiting to be written", labels=["back"]
        )
        for comp in gw.backs:
            scheduler = getattr(comp, "scheduler", None)  # a LineScheduler, or its mirror
            stats = getattr(scheduler, "stats", None)
            if not isinstance(stats, LineStats):
                continue
            cycles.add_metric([comp.name], float(stats.cycles))
            if stats.last_cycle_time is not None:
                cycle_time.add_metric([comp.name], stats.last_cycle_time)
            writes.add_metric([comp.name], float(stats.writes))
            pending.add_metric([comp.name], float(getattr(scheduler, "pending_writes", 0)))
        yield from (cycles, cycle_time, writes, pending)

    def _points(self, gw: GatewayView) -> Iterator[Metric]:
        counts: dict[tuple[str, str], int] = {}
        backs = [b.name for b in gw.topology.backs]
        for back in backs:
            for q in Quality:
                counts[(back, q.value)] = 0
        for ch in gw.image:
            key = (ch.source.back, ch.quality.value)
            counts[key] = counts.get(key, 0) + 1
        family = GaugeMetricFamily(
            "fieldgate_points", "points of a back by quality", labels=["back", "quality"]
        )
        for (back, quality), n in sorted(counts.items()):
            family.add_metric([back, quality], float(n))
        yield family
        if not self.point_metrics:
            return
        value = GaugeMetricFamily(
            "fieldgate_point_value",
            "raw value of a point (opt-in: http.point_metrics)",
            labels=["point", "kind"],
        )
        good = GaugeMetricFamily(
            "fieldgate_point_good", "1 while a point's quality is good (opt-in)", labels=["point"]
        )
        for ch in gw.image:
            if not isinstance(ch.value, str):  # text has no number to export
                value.add_metric([ch.id, ch.kind.value], float(ch.value))
            good.add_metric([ch.id], float(ch.quality is Quality.GOOD))
        yield from (value, good)

    def _events(self, gw: GatewayView) -> Iterator[Metric]:
        family = CounterMetricFamily(
            "fieldgate_events", "gateway events published, by kind", labels=["kind"]
        )
        for kind, n in sorted(gw.context.events.counts.items()):
            family.add_metric([kind], float(n))
        yield family

    # -- components' own --------------------------------------------------------------
    def _components(self, gw: GatewayView) -> Iterator[Metric]:
        families: dict[str, tuple[str, str, list[tuple[dict[str, str], float]]]] = {}
        for comp in gw.backs + gw.fronts:
            method = getattr(comp, "metrics", None)
            if method is None or not getattr(comp, "started", False):
                continue
            try:
                samples: Iterable[Any] = method()
                samples = list(samples)
            except Exception as exc:
                self._log_once(comp.name, f"metrics() raised {type(exc).__name__}: {exc}")
                continue
            for sample in samples:
                try:
                    name, mtype, help_text, value, labels = check_sample(sample)
                except ComponentMetricsError as exc:
                    self._log_once(comp.name, str(exc))
                    continue
                full = PREFIX + name
                known = families.get(full)
                if known is None:
                    known = families[full] = (mtype, help_text, [])
                elif known[0] != mtype:
                    self._log_once(comp.name, f"{name}: type {mtype} differs from {known[0]}")
                    continue
                known[2].append(({**labels, "component": comp.name}, value))
        for full, (mtype, help_text, samples) in sorted(families.items()):
            label_names = sorted({k for labels, _ in samples for k in labels})
            seen: set[tuple[str, ...]] = set()
            family: CounterMetricFamily | GaugeMetricFamily
            if mtype == "counter":
                family = CounterMetricFamily(full, help_text, labels=label_names)
            else:
                family = GaugeMetricFamily(full, help_text, labels=label_names)
            for labels, value in samples:
                key = tuple(labels.get(k, "") for k in label_names)
                if key in seen:
                    self._log_once(labels["component"], f"{full}: duplicate labels {labels}")
                    continue
                seen.add(key)
                family.add_metric(list(key), value)
            yield family


class _Families:
    """A registry-like holder of already collected families, for ``generate_latest``."""

    def __init__(self, families: list[Metric]):
        self.families = families

    def collect(self) -> list[Metric]:
        return self.families


class GatewayMetrics:
    """The private registry and its text output."""

    def __init__(self, gateway: GatewayView, *, point_metrics: bool = False, extra: Any = None):
        self.registry = CollectorRegistry(auto_describe=False)
        self.collector = GatewayCollector(gateway, point_metrics=point_metrics, extra=extra)
        self.registry.register(self.collector)

    def render(self) -> bytes:
        return generate_latest(self.registry)

    @staticmethod
    def render_family(family: Metric) -> bytes:
        """One family in the text format."""
        return generate_latest(_Families([family]))

    async def render_async(self, slice_s: float = 0.0005) -> bytes:
        """The same text, collected and formatted in slices with a loop turn in between.

        prometheus-client's ``generate_latest`` costs about 20 us a sample, so a big
        gateway's scrape would hold the event loop for milliseconds in one go. Here the
        families are collected and formatted one by one, and after every ``slice_s`` of
        work the loop serves whatever waits (a CAN frame, a poll reply). Each family is
        read in one go, so its samples are consistent with each other.
        """
        parts: list[bytes] = []
        started = time.perf_counter()
        for family in self.collector.collect():
            parts.append(self.render_family(family))
            if time.perf_counter() - started >= slice_s:
                await asyncio.sleep(0)
                started = time.perf_counter()
        return b"".join(parts)
