"""/metrics parsed back with prometheus-client's own parser; names checked against its rules."""

from __future__ import annotations

import asyncio
import logging
import re

import pytest
from httpkit import load_gateway, start
from prometheus_client.parser import text_string_to_metric_families

from fieldgate.http.metrics import ComponentMetricsError, check_sample

DURATION_WORDS = ("duration", "latency", "time", "rtt", "lag", "cycle")


async def scrape(running) -> dict:
    reply = await running.get("/metrics")
    assert reply.status == 200
    return {f.name: f for f in text_string_to_metric_families(reply.text)}


def check_names(families: dict) -> None:
    for name, family in families.items():
        assert name.startswith("fieldgate_"), name
        assert re.fullmatch(r"[a-z_][a-z0-9_]*", name), name
        for sample in family.samples:
            if family.type == "counter":
                assert sample.name in (name + "_total", name + "_created"), sample.name
            if family.type == "gauge":
                assert not sample.name.endswith("_total"), sample.name
            assert "point" not in sample.labels or name.startswith("fieldgate_point_"), sample
        if family.type in ("gauge", "histogram") and any(w in name for w in DURATION_WORDS):
            assert name.endswith("_seconds"), f"{name}: durations are in seconds"


async def test_metrics_follow_the_naming_rules_and_cover_the_issue(running):
    families = await scrape(running)
    check_names(families)
    types = {name: f.type for name, f in families.items()}
    expected = {
        "fieldgate_build_info": "gauge",
        "fieldgate_ready": "gauge",
        "fieldgate_module_up": "gauge",
        "fieldgate_poll_duration_seconds": "histogram",
        "fieldgate_transactions": "counter",
        "fieldgate_points": "gauge",
        "fieldgate_line_last_cycle_seconds": "gauge",
        "fieldgate_master_present": "gauge",
        "fieldgate_can_frames": "counter",
        "fieldgate_can_frames_ignored": "counter",
        "fieldgate_can_bus_off": "gauge",
        "fieldgate_canopen_nmt_state": "gauge",
        "fieldgate_canopen_emcy_sent": "counter",
        "fieldgate_master_output_writes": "counter",
        "fieldgate_events": "counter",
        "fieldgate_http_responses": "counter",
        "fieldgate_sse_dropped": "counter",
    }
    assert {k: types.get(k) for k in expected} == expected
    up = {s.labels["module"]: s.value for s in families["fieldgate_module_up"].samples}
    assert up == {"1": 1.0, "3": 1.0, "4": 1.0, "5": 1.0}
    nmt = {s.labels["state"]: s.value for s in families["fieldgate_canopen_nmt_state"].samples}
    assert nmt["PRE-OPERATIONAL"] == 1.0 and sum(nmt.values()) == 1.0
    assert all(s.labels["component"] == "can" for s in families["fieldgate_can_frames"].samples)
    tx = next(s for s in families["fieldgate_can_frames"].samples if s.labels["direction"] == "tx")
    assert tx.value >= 1  # the boot-up message at least
    buckets = [
        s
        for s in families["fieldgate_poll_duration_seconds"].samples
        if s.name.endswith("_bucket") and s.labels["module"] == "1"
    ]
    assert buckets[-1].labels["le"] == "+Inf"
    assert buckets[-1].value == running.gateway.health.get("rs485", 1).requests
    ok = next(
        s
        for s in families["fieldgate_transactions"].samples
        if s.labels == {"back": "rs485", "module": "1", "result": "ok"}
    )
    assert ok.value == running.gateway.health.get("rs485", 1).requests
    points = {s.labels["quality"]: s.value for s in families["fieldgate_points"].samples}
    assert points["good"] == len(running.gateway.image) and points["comm-fault"] == 0
    assert "fieldgate_point_value" not in families  # no per-point series by default


async def test_per_point_series_are_opt_in(tmp_path):
    gw = load_gateway(tmp_path, point_metrics=True)
    running = await start(gw)
    try:
        families = await scrape(running)
        check_names(families)
        values = {s.labels["point"]: s.value for s in families["fieldgate_point_value"].samples}
        assert set(values) == {c.id for c in gw.image}
        assert values["rs485/m5/ai0"] == float(gw.image.value("rs485/m5/ai0"))
    finally:
        await gw.stop()


async def test_a_component_breaking_the_contract_loses_only_its_bad_series(tmp_path, caplog):
    gw = load_gateway(tmp_path)  # every scrape renders (the tests' default)
    running = await start(gw)
    try:
        await _breaking_the_contract(running, caplog)
    finally:
        await gw.stop()


async def test_scrapes_within_metrics_max_age_share_one_render(tmp_path):
    gw = load_gateway(tmp_path, metrics_max_age_ms=1000)  # the default
    running = await start(gw)
    try:
        await _one_render(running)
    finally:
        await gw.stop()


async def _one_render(running):
    service = running.gateway.http
    renders = []
    render = service.metrics.render_async

    async def counting(slice_s=0.0005):
        renders.append(1)
        return await render(slice_s)

    service.metrics.render_async = counting
    service._metrics_cache = None
    replies = await asyncio.gather(*(running.get("/metrics") for _ in range(5)))
    again = await running.get("/metrics")
    assert len(renders) == 1  # five at once and one after: one render (max age 1 s)
    assert {r.body for r in replies} == {again.body}


async def _breaking_the_contract(running, caplog):
    front = running.gateway.component("can")
    good = front.metrics

    def metrics():
        return good() + [
            ("my_gauge_total", "gauge", "a gauge named like a counter", 1.0, {}),
            ("my_count", "counter", "a counter without _total", 1.0, {}),
            ("fieldgate_x", "gauge", "prefix given", 1.0, {}),
            ("my_value", "gauge", "bad label", 1.0, {"bad-label": "x"}),
            ("my_value", "gauge", "reserved label", 1.0, {"component": "x"}),
            ("my_value", "summary", "bad type", 1.0, {}),
            ("my_value", "gauge", "a string value", "3", {}),
            "not a tuple",
            ("extra_ok", "gauge", "fine", 2.5, {"kind": "a"}),
        ]

    front.metrics = metrics
    caplog.set_level(logging.WARNING, logger="fieldgate.http.metrics")
    for _ in range(2):
        families = await scrape(running)
    check_names(families)
    assert [s.value for s in families["fieldgate_extra_ok"].samples] == [2.5]
    assert "fieldgate_canopen_nmt_state" in families
    assert not any(n.startswith(("fieldgate_my_", "fieldgate_fieldgate")) for n in families)
    warnings = [r.getMessage() for r in caplog.records if r.name == "fieldgate.http.metrics"]
    assert len(warnings) == 8  # each problem once, not once per scrape
    assert any("a counter's name must end in _total" in w for w in warnings)

    def broken():
        raise RuntimeError("no")

    front.metrics = broken
    families = await scrape(running)
    assert "fieldgate_module_up" in families and "fieldgate_canopen_nmt_state" not in families


@pytest.mark.parametrize(
    "sample",
    [
        ("x_total", "gauge", "", 1, {}),
        ("x", "counter", "", 1, {}),
        ("x_total", "counter", "", -1, {}),
        ("1x", "gauge", "", 1, {}),
        ("x", "gauge", "", True, {}),
        ("x", "gauge", "", 1, {"__name": "a"}),
        ("x", "gauge", "", 1, {"a": 1}),
    ],
)
def test_check_sample_rejects(sample):
    with pytest.raises(ComponentMetricsError):
        check_sample(sample)


def test_check_sample_accepts_the_contract():
    assert check_sample(("x_total", "counter", "h", 3, {"a": "b"})) == (
        "x_total",
        "counter",
        "h",
        3.0,
        {"a": "b"},
    )
