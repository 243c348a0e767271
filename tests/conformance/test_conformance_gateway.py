"""The whole suite against fieldgate's own canopen front, in-process on the virtual bus.

The gateway is a black box here: a loopback back behind a canopen front, the EDS from
``fieldgate eds``, and the suite on a second python-can bus on the same virtual channel.
Every case must pass or be a documented SKIP; open findings against the front are listed
in KNOWN_FINDINGS (and in docs/conformance.md) and must fail for the stated reason only.
"""

import uuid

import can
import pytest
from conformance_gateway import (
    DOCUMENTED_SKIPS,
    KNOWN_FINDINGS,
    NODE_ID,
    GatewayThread,
    front_unavailable,
    patch_out,
    topology,
    write_eds,
)

from fieldgate.conformance import Options, SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.framework import OPT_IN
from fieldgate.conformance.report import text_report


def run_gateway(work, style: str = "icpdas", **select):
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    channel = f"gw-{uuid.uuid4().hex[:8]}"
    topo = topology(work / "state", channel)
    topo["fronts"][0]["style"] = style
    eds = write_eds(topo, work)
    timing = Timing(response=0.3, silence=0.1, heartbeat_ms=50, bootup=1.0, sdo_server_timeout=1.0)
    with GatewayThread(topo):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            return run_suite(
                SuiteConfig(
                    NODE_ID, str(eds), timing=timing, options=Options(loopback=True), **select
                ),
                bus=bus,
            )
        finally:
            bus.shutdown()


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return run_gateway(tmp_path_factory.mktemp("gateway"), profiles=["all", *OPT_IN])


def test_every_case_passes_or_is_a_documented_skip(results):
    report = text_report(results)
    by_id = {r.case.id: r for r in results}
    failures = {cid for cid, r in by_id.items() if r.verdict is Verdict.FAIL}
    assert failures <= set(KNOWN_FINDINGS), report
    for cid, r in by_id.items():
        assert r.verdict in (Verdict.PASS, Verdict.FAIL, Verdict.SKIP), (
            f"{cid}: {r.verdict} {r.reason}\n{report}"
        )
        if r.verdict is Verdict.SKIP:
            assert cid in DOCUMENTED_SKIPS and DOCUMENTED_SKIPS[cid] in r.reason, (
                f"undocumented SKIP {cid}: {r.reason}"
            )
        assert not r.notes, f"{cid} left the device to be restored: {r.notes}\n{report}"


def test_the_suite_really_exercised_the_gateway(results):
    passed = {r.case.id for r in results if r.verdict is Verdict.PASS}
    assert len(passed) >= 100
    for cid in (
        "sdo.block_download_crc",
        "lss.fastscan",
        "sync-pdo.sync_type_n",
        "cia401.error_mode_do",
        "seed.tv19_emcy_length_error",
        "store.save_across_reset",
        "errctl.guard_off_ends_error",
        "errctl.consumer_reset_ends_error",
        "sync-pdo.sync_loss_ends_on_sync",
        "sync-pdo.sync_loss_ends_period_0",
    ):
        assert cid in passed


def test_known_findings_still_fail(results):
    """A finding that passes now must leave KNOWN_FINDINGS and docs/conformance.md."""
    by_id = {r.case.id: r for r in results}
    fixed = [cid for cid in KNOWN_FINDINGS if by_id[cid].verdict is Verdict.PASS]
    assert not fixed, f"fixed in the front, update KNOWN_FINDINGS: {fixed}"


def test_na9161_layout_passes_the_layout_sensitive_cases(tmp_path):
    """The same suite on the front's NA-9161 layout (8 PDOs, PDO sub 0 = 5, 500 ms default TPDO
    inhibit): nothing in the generic profiles may assume the I-7232D layout."""
    patterns = [
        "sync-pdo.event_timer",
        "sync-pdo.inhibit_time",
        "sync-pdo.sync_type1",
        "sync-pdo.tpdo_rtr",
        "sync-pdo.rpdo_gated",
        "cia401.*",
        "od.eds_check",
    ]
    results = run_gateway(tmp_path, style="na9161", patterns=patterns)
    assert len(results) >= 12
    assert [r.case.id for r in results if r.verdict is not Verdict.PASS] == [], text_report(results)


def refuse_short_writes(self, index, length, convert):
    """A Dictionary that takes no 2-byte writes (CiA 401's widths only)."""


@pytest.mark.parametrize(
    "target, attribute, broken, case_id",
    [
        (
            "fieldgate.plugins.canopen.cia301.emcy.EmcyProducer",
            "signal",
            lambda self, *args, **kwargs: None,  # no EMCY for the reset request
            "icpdas.nmt_reset_emcy",
        ),
        (
            "fieldgate.plugins.canopen.cia301.od.Dictionary",
            "accept_short_writes",
            refuse_short_writes,
            "icpdas.ao_error_two_byte_writes",
        ),
        (
            "fieldgate.plugins.canopen.cia401.analog.AnalogInterrupts",
            "fires",
            lambda self, change: True,  # every analog change an event
            "icpdas.analog_change_no_tpdo",
        ),
        (
            "fieldgate.plugins.canopen.cia301.errctl.ErrorControl",
            "_master_lost",
            lambda self, error, reason, now: None,  # a consumer timeout reported nowhere
            "delta-as300.master_heartbeat_watched",
        ),
    ],
)
def test_a_broken_front_fails_the_profile_case_that_checks_it(
    tmp_path, monkeypatch, target, attribute, broken, case_id
):
    patch_out(monkeypatch, target, attribute, broken)
    results = run_gateway(tmp_path, profiles=["all", *OPT_IN], patterns=[case_id])
    assert {r.case.id: r.verdict for r in results} == {case_id: Verdict.FAIL}, text_report(results)
