"""The cases for monitoring errors that end (life guarding, heartbeat consumer, SYNC loss) against
fieldgate's canopen front in-process with one injected fault at a time: each fault (the front
patched in the test, as the DeviceNet front's broken variants) fails exactly its cases, while the
same error ended another way still passes. The healthy front passes them in
test_conformance_gateway.py (whole suite)."""

from __future__ import annotations

import uuid

import can
import pytest
from conformance_gateway import NODE_ID, GatewayThread, front_unavailable, topology, write_eds

from fieldgate.conformance import SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.report import text_report

TIMING = Timing(response=0.3, silence=0.1, heartbeat_ms=50, bootup=1.0, sdo_server_timeout=1.0)

# fault: (class, method that must end the error, the call inside it that is dropped), the cases it
# fails, and the cases run with it: the same error ended another way must still pass
FAULTS = {
    "guard_off_keeps_error": (
        ("cia301.errctl", "ErrorControl"),
        "_guarding_written",
        "_end",
        {"errctl.guard_off_ends_error"},
        "errctl.guard_*",
    ),
    "consumer_off_keeps_error": (
        ("cia301.errctl", "ErrorControl"),
        "_consumers_written",
        "_end",
        {"errctl.consumer_off_ends_error"},
        "errctl.consumer_*",
    ),
    "reset_keeps_errors": (
        ("cia301.errctl", "ErrorControl"),
        "on_nmt_state",
        "_end",
        {"errctl.guard_reset_ends_error", "errctl.consumer_reset_ends_error"},
        "errctl.*_ends_error",
    ),
    "sync_keeps_loss": (
        ("cia301.sync", "SyncService"),
        "_consume",
        "_end_loss",
        {"sync-pdo.sync_loss_ends_on_sync"},
        "sync-pdo.sync_loss_*",
    ),
    "period_0_keeps_loss": (
        ("cia301.sync", "SyncService"),
        "_configure",
        "_end_loss",
        {"sync-pdo.sync_loss_ends_period_0"},
        "sync-pdo.sync_loss_*",
    ),
}


@pytest.fixture(scope="module")
def gateway(tmp_path_factory):
    """One front for every test here (the faults patch its classes while it runs): (channel, EDS)."""
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    work = tmp_path_factory.mktemp("monitoring")
    channel = f"gw-mon-{uuid.uuid4().hex[:8]}"
    topo = topology(work / "state", channel)
    eds = write_eds(topo, work)
    with GatewayThread(topo):
        yield channel, str(eds)


def run(gateway, patterns: list[str]) -> dict:
    channel, eds = gateway
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        results = run_suite(SuiteConfig(NODE_ID, eds, patterns=patterns, timing=TIMING), bus=bus)
    finally:
        bus.shutdown()
    return {r.case.id: r for r in results}


def break_front(monkeypatch, fault: str) -> None:
    """The front's ``method`` runs with ``inner`` doing nothing: the error it should end stays."""
    import importlib

    (module, cls_name), method, inner, _, _ = FAULTS[fault]
    cls = getattr(importlib.import_module(f"fieldgate.plugins.canopen.{module}"), cls_name)
    original = getattr(cls, method)

    def without_inner(self, *args, **kwargs):
        setattr(self, inner, lambda *a, **k: None)
        try:
            return original(self, *args, **kwargs)
        finally:
            delattr(self, inner)

    monkeypatch.setattr(cls, method, without_inner)


# 0x1006 = 0: SYNC-loss supervision is the device's choice, so a loss it keeps is INFO, not FAIL
INFO_ONLY = {"period_0_keeps_loss"}
# after reset communication CiA 301 asks for no error-reset EMCY (the EMCY state machine starts
# error-free, the boot-up tells the consumers): the error register kept decides the FAIL
BY_REGISTER = {"reset_keeps_errors"}


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_each_fault_fails_exactly_its_cases(gateway, monkeypatch, fault):
    *_, cases, pattern = FAULTS[fault]
    break_front(monkeypatch, fault)
    results = run(gateway, [pattern])
    report = text_report(list(results.values()))
    verdict = Verdict.INFO if fault in INFO_ONLY else Verdict.FAIL
    assert {cid for cid, r in results.items() if r.verdict is verdict} == cases, report
    assert len(results) > len(cases), report
    assert all(r.verdict is Verdict.PASS for cid, r in results.items() if cid not in cases), report
    for cid in cases:
        if fault in BY_REGISTER:
            assert results[cid].reason.startswith("0x1001 after") and results[cid].seen == "0x11"
            continue
        assert results[cid].seen == "no error-reset EMCY", report
        if verdict is Verdict.FAIL:
            assert results[cid].expected.startswith("EMCY 00 00"), report


def test_an_error_reset_with_the_old_register_fails(gateway, monkeypatch):
    """The error-reset EMCY comes, but its byte 2 still shows the ended error (0x1001 is right)."""
    from fieldgate.plugins.canopen.cia301.emcy import EmcyProducer

    def stale_register(self, keys, now):
        register = self.register
        for key in keys:
            del self.active[key]
        if keys:
            self._produce(0x0000, b"", now, register)
        return len(keys)

    monkeypatch.setattr(EmcyProducer, "_clear", stale_register)
    results = run(gateway, ["errctl.guard_off_ends_error"])
    bad = results["errctl.guard_off_ends_error"]
    assert bad.verdict is Verdict.FAIL and "byte 2 must be the error register left" in bad.reason, (
        text_report(list(results.values()))
    )
    assert bad.expected.startswith("00 00 00") and bad.seen.endswith("[8] 00 00 11 00 00 00 00 00")
