"""The profile cases of issue 32's rows, against fieldgate's front (in-process, virtual bus): each
passes where the front does what the manual says, and fails (or says INFO) where it does not
(a topology that differs, the front broken on purpose)."""

from __future__ import annotations

import uuid

import can
import pytest
from conformance_gateway import GatewayThread, front_unavailable, topology, write_eds

from fieldgate.conformance import Options, SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.report import text_report


def grade(work, patterns: list[str], profiles: list[str], **front) -> dict[str, tuple]:
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    channel = f"rows-{uuid.uuid4().hex[:8]}"
    work.mkdir(parents=True, exist_ok=True)
    topo = topology(work / "state", channel)
    cfg = topo["fronts"][0]
    for key in ("master", "heartbeat_ms"):  # the I-7232D as shipped: no master profile
        cfg.pop(key, None)
    modules = front.pop("modules", None)
    if modules is not None:
        topo["backs"][0]["modules"] = modules
    cfg.update(front)
    eds = write_eds(topo, work)
    timing = Timing(response=0.3, silence=0.1, heartbeat_ms=50, bootup=1.0, sdo_server_timeout=1.0)
    with GatewayThread(topo):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            results = run_suite(
                SuiteConfig(
                    5,
                    str(eds),
                    timing=timing,
                    options=Options(loopback=True),
                    profiles=profiles,
                    patterns=patterns,
                ),
                bus=bus,
            )
        finally:
            bus.shutdown()
    report = text_report(results)
    return {r.case.id: (r.verdict, report) for r in results}


def test_no_tpdo_at_start_passes_as_shipped_and_fails_with_tpdo_on_start(tmp_path):
    seen = grade(tmp_path / "a", ["icpdas.no_tpdo_at_start"], ["icpdas"])
    assert seen["icpdas.no_tpdo_at_start"][0] is Verdict.PASS, seen["icpdas.no_tpdo_at_start"][1]
    seen = grade(tmp_path / "b", ["icpdas.no_tpdo_at_start"], ["icpdas"], tpdo_on_start="async")
    verdict, report = seen["icpdas.no_tpdo_at_start"]
    assert verdict is Verdict.FAIL and "TV-07" in report, report


def test_store_write_emcy_passes_on_a_store_that_cannot_be_written(tmp_path):
    # /proc takes no new file, not even from root: nothing saved at start (no error), every
    # save refused
    seen = grade(
        tmp_path / "a",
        ["icpdas.store_write_emcy"],
        ["icpdas"],
        store_file=f"/proc/fieldgate-{uuid.uuid4().hex[:8]}.canopen.json",
    )
    verdict, report = seen["icpdas.store_write_emcy"]
    assert verdict is Verdict.PASS, report


def test_module_limits_says_info_past_the_i7232d(tmp_path):
    modules = [{"address": a, "digital": 8} for a in range(1, 12)]  # 11 > 10
    seen = grade(tmp_path, ["icpdas.module_limits"], ["icpdas"], modules=modules)
    verdict, report = seen["icpdas.module_limits"]
    assert verdict is Verdict.INFO and "more than the I-7232D holds (10)" in report, report


NA9161 = [{"address": 1, "digital": 8, "analog": 1}, {"address": 2, "digital": 4}]


def test_na9161_rows_pass_and_fail_when_the_front_is_broken(tmp_path, monkeypatch):
    cases = ["na9161.slot_memory_not_io", "na9161.stored_cob_ids_kept", "na9161.field_power_bit"]
    seen = grade(tmp_path / "a", cases, ["na9161"], style="na9161", modules=NA9161)
    for cid in cases:
        assert seen[cid][0] is Verdict.PASS, seen[cid][1]
    from fieldgate.plugins.canopen.cia301 import store
    from fieldgate.plugins.canopen.na9161 import slots

    # the old slot memory (the I/O block) and the old store (defaults only)
    monkeypatch.setattr(
        slots.SlotObjects,
        "read_memory",
        lambda self, slot: b"".join(
            int(c.value or 0).to_bytes(2, "little") for c in slot.of[slots.Kind.AI]
        ),
    )
    real_init = store.StoreService.__init__

    def forgetful(self, *args, **kwargs):
        real_init(self, *args, **{**kwargs, "keep_node_id_entries": False})

    monkeypatch.setattr(store.StoreService, "__init__", forgetful)
    seen = grade(tmp_path / "b", cases[:2], ["na9161"], style="na9161", modules=NA9161)
    for cid in cases[:2]:
        assert seen[cid][0] is Verdict.FAIL, seen[cid][1]
