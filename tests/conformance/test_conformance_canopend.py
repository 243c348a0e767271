"""Regression tests for the tool's defects found against CANopenNode's canopend (issue 31),
each against a fake device that behaves as canopend did (conformance_canopend.py), on
python-can's virtual bus. Each test names the defect it guards; before the fix each failed.
"""

from __future__ import annotations

import uuid

import can
import pytest
from conformance_canopend import CanopendLike, canopend_eds

from fieldgate.conformance import SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.catalog import select
from fieldgate.conformance.cli import main as conformance_main
from fieldgate.conformance.eds import EdsError, load_eds
from fieldgate.conformance.identity import DeviceFacts
from fieldgate.conformance.report import text_report
from fieldgate.conformance.runner import device_facts, identity

TIMING = dict(response=0.2, silence=0.1, heartbeat_ms=50, bootup=0.5, sdo_server_timeout=1.0)
GENERIC_CLAUSE = "bit 0, generic"


@pytest.fixture(scope="module")
def eds(tmp_path_factory):
    path = tmp_path_factory.mktemp("canopend") / "canopend.eds"
    path.write_text(canopend_eds())
    return str(path)


def run(eds: str, patterns=None, faults=(), profiles=("all",), **timing) -> dict:
    channel = f"cd-{uuid.uuid4().hex[:8]}"
    with CanopendLike(channel, 5, set(faults)):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            config = SuiteConfig(
                5,
                eds,
                profiles=list(profiles),
                patterns=list(patterns or []),
                timing=Timing(**{**TIMING, **timing}),
            )
            results = run_suite(config, bus=bus)
        finally:
            bus.shutdown()
    return {r.case.id: r for r in results}


def verdicts(results: dict) -> dict:
    return {cid: r.verdict for cid, r in results.items()}


def test_1_a_case_that_stops_mid_transfer_leaves_no_transfer_open(eds):
    """Defect 1: block_bad_seqno given too short a wait stops with the block download open;
    the cases after it must still get SDO answers (before: "no SDO response")."""
    cases = [
        "sdo.block_bad_seqno",
        "sdo.expedited_upload",
        "sdo.block_crc_error",
        "sdo.segmented_upload",
    ]
    results = run(eds, cases, sdo_server_timeout=0.1)  # 0.3 s wait: shorter than its 0.7 s
    report = text_report(list(results.values()))
    assert results["sdo.block_bad_seqno"].verdict is Verdict.FAIL, report
    assert any(
        "reset communication" in n or "SDO server timeout" in n
        for n in results["sdo.block_bad_seqno"].notes
    ), report
    assert all(results[c].verdict is Verdict.PASS for c in cases[1:]), report


def test_1_verdicts_do_not_depend_on_case_order(eds):
    """Defect 1: the whole suite in order and shuffled gives the same verdicts."""
    ordered = verdicts(run(eds))
    for seed in (31,):
        channel = f"cd-{uuid.uuid4().hex[:8]}"
        with CanopendLike(channel, 5):
            bus = can.Bus(interface="virtual", channel=channel)
            try:
                config = SuiteConfig(
                    5, eds, profiles=["all"], timing=Timing(**TIMING), shuffle=seed
                )
                shuffled = {r.case.id: r.verdict for r in run_suite(config, bus=bus)}
            finally:
                bus.shutdown()
        differ = {c: (v, shuffled[c]) for c, v in ordered.items() if shuffled[c] is not v}
        assert not differ, f"seed {seed}: {differ}"


def test_2_the_block_ack_after_the_servers_own_timeout_is_waited_for(eds):
    """Defect 2: the device acknowledges a wrong sequence number (ackseq 0) after its 0.7 s SDO
    timeout; the case waits --sdo-server-timeout + --timeout (was: 0.5 s)."""
    results = run(eds, ["sdo.block_bad_seqno"])
    assert results["sdo.block_bad_seqno"].verdict is Verdict.PASS, text_report(
        list(results.values())
    )


def test_3_the_state_comes_from_reports_after_the_device_acted(eds):
    """Defect 3: after an NMT command the device sends one heartbeat with its old state, then
    the new one (7F at +2 ms, 05 at +3 ms): the state is two agreeing reports."""
    results = run(eds, ["nmt.transitions", "nmt.broadcast", "nmt.other_node_ignored"])
    assert set(verdicts(results).values()) == {Verdict.PASS}, text_report(list(results.values()))


def test_4_what_cia_301_does_not_require_is_info_not_fail(eds):
    """Defect 4: no error-reset EMCY after reset communication (the consumer error cleared, the
    boot-up tells the consumers) and a SYNC loss 0x1006 = 0 does not end: INFO, not FAIL."""
    results = run(
        eds,
        [
            "errctl.consumer_reset_ends_error",
            "sync-pdo.sync_loss_ends_period_0",
            "sync-pdo.sync_loss_ends_on_sync",
        ],
        faults={"generic_bit"},
    )
    report = text_report(list(results.values()))
    assert results["errctl.consumer_reset_ends_error"].verdict is Verdict.INFO, report
    assert results["sync-pdo.sync_loss_ends_period_0"].verdict is Verdict.INFO, report
    assert results["sync-pdo.sync_loss_ends_on_sync"].verdict is Verdict.PASS, report


def test_5_a_device_reporting_an_error_is_inconclusive_not_failed(eds):
    """Defect 5: EMCY 0x5000 after boot-up and 0x1001 = 0x01 (Start refused while it shows an
    error): the cases that need an error-free device give no verdict, and say why."""
    cases = ["nmt.transitions", "nmt.broadcast", "emcy.error_register_idle"]
    results = run(eds, cases, faults={"boot_error"})
    report = text_report(list(results.values()))
    for cid in cases:
        assert results[cid].verdict is Verdict.INCONCLUSIVE, report
        assert "reports an error" in results[cid].reason, report


def test_6_optional_lss_services_are_skips_and_fastscan_is_tested(eds):
    """Defect 6: identify remote / non-configured slave are optional; fastscan is graded itself.
    configure bit timing dropped silently stays a FAIL (the device's deviation), with its clause."""
    results = run(eds, ["lss.*"])
    report = text_report(list(results.values()))
    assert results["lss.identify_remote"].verdict is Verdict.SKIP, report
    assert "optional" in results["lss.identify_remote"].reason
    assert results["lss.identify_non_configured"].verdict is Verdict.PASS, report
    assert results["lss.fastscan"].verdict is Verdict.PASS, report
    bit_timing = results["lss.configure_bit_timing"]
    assert bit_timing.verdict is Verdict.FAIL and "CiA 305" in (bit_timing.clause or ""), report
    others = {c: v for c, v in verdicts(results).items() if c != "lss.configure_bit_timing"}
    assert Verdict.FAIL not in others.values(), report


def test_7_device_profiles_run_by_identity_or_by_name(eds):
    """Defect 7: vendor-ID 0, name CANopenNode: --profile all runs no seed/icpdas/na9161 case;
    named, TV-05 accepts A4 (CRC offered) as CiA 301 does."""
    results = run(eds)
    assert not [
        c for c in results if c.split(".")[0] in ("seed", "icpdas", "na9161", "delta-as300")
    ]
    facts = DeviceFacts(vendor_id=0x34E, name="fieldgate I-7232D style")
    assert {c.profile for c in select(["all"], facts=facts)} >= {"seed", "icpdas"}
    assert "na9161" in {c.profile for c in select(["all"], facts=DeviceFacts(vendor_id=0x029D))}
    named = run(eds, ["seed.tv05_block_download"], profiles=["seed"])
    assert named["seed.tv05_block_download"].verdict is Verdict.PASS, text_report(
        list(named.values())
    )


def test_8_the_generic_bit_rule_is_the_same_for_every_error_emcy(eds):
    """Defect 8: EMCYs with register 0x10 (no generic bit) fail the same way whether they come
    from SYNC loss or from the heartbeat consumer, with the same clause."""
    results = run(eds, ["errctl.heartbeat_consumer", "sync-pdo.sync_loss_ends_on_sync"])
    for r in results.values():
        assert r.verdict is Verdict.FAIL and GENERIC_CLAUSE in (r.clause or ""), text_report([r])
    fine = run(
        eds,
        ["errctl.heartbeat_consumer", "sync-pdo.sync_loss_ends_on_sync"],
        faults={"generic_bit"},
    )
    assert set(verdicts(fine).values()) == {Verdict.PASS}, text_report(list(fine.values()))


def test_9_the_devices_own_eds_with_empty_keys_is_read(eds, tmp_path, capsys):
    """Defect 9: VendorNumber= and ProductNumber= empty (CANopenNode's DS301_profile.eds) are
    read as absent; a wrong value stops the run naming file, line and key (exit 2)."""
    reading = load_eds(eds, 5)
    assert any("VendorNumber is empty" in n for n in reading.notes)
    assert reading.od[0x1014].default == 0x85  # $NODEID+0x80
    channel = f"cd-{uuid.uuid4().hex[:8]}"
    args = ["--interface", "virtual", "--channel", channel, "--node-id", "5", "--timeout", "0.2"]
    with CanopendLike(channel, 5):
        assert conformance_main([*args, "--eds", eds, "-k", "sdo.expedited_upload"]) == 0
        assert "EDS notes:" in capsys.readouterr().out
        bad = tmp_path / "bad.eds"
        bad.write_text(canopend_eds().replace("VendorNumber=", "VendorNumber=0x1x"))
        assert conformance_main([*args, "--eds", str(bad)]) == 2
        err = capsys.readouterr().err
        line = 1 + canopend_eds().splitlines().index("VendorNumber=")
        assert f"{bad} line {line}: [DeviceInfo] VendorNumber = '0x1x': not a number" in err
    with pytest.raises(EdsError, match="AccessType"):
        bad.write_text(canopend_eds().replace("AccessType=rw", "AccessType=readwrite", 1))
        load_eds(bad, 5)


def test_the_identity_and_eds_choose_the_profiles(eds):
    """--profile all = the CiA profiles the EDS supports (LSS_Supported=1, no CiA 401, no 0x1010)."""
    channel = f"cd-{uuid.uuid4().hex[:8]}"
    from fieldgate.conformance.device import Device
    from fieldgate.conformance.link import Link

    with CanopendLike(channel, 5):
        bus = can.Bus(interface="virtual", channel=channel)
        link = Link(bus)
        try:
            device = Device.from_eds(link, 5, eds, Timing(**TIMING))
            facts = device_facts(device, identity(device))
        finally:
            link.close()
            bus.shutdown()
    assert facts.vendor_id == 0 and facts.name == "CANopenNode" and facts.lss_supported
    profiles = {c.profile for c in select(["all"], facts=facts)}
    assert profiles == {"od", "sdo", "nmt", "errctl", "emcy", "sync-pdo", "lss"}
