"""The suite against a tiny raw-frame slave, healthy and deliberately broken.

A healthy slave must pass every applicable case; each injected fault must make exactly
the cases that check that behaviour fail, and change nothing else.
"""

import uuid
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor

import can
import pytest
from conformance_slave import TinySlave, eds_text

from fieldgate.conformance import PROFILES, SuiteConfig, Timing, Verdict, failed, run_suite
from fieldgate.conformance.cli import main as conformance_main
from fieldgate.conformance.report import text_report

FAULTS = {
    "wrong_abort_missing_sub": {"od.missing_subindex", "seed.tv06_abort"},
    "no_toggle_check": {"sdo.upload_toggle_error"},
    "late_heartbeat": {"errctl.heartbeat_period", "delta-as300.heartbeat_producer"},
    "stuck_guard_toggle": {"errctl.guarding_toggle"},
    "sdo_in_stopped": {"nmt.sdo_gated"},
}
# the tiny slave has no heartbeat consumer (0x1016): not an AS300 slave out of the box, healthy
# or not, which the delta-as300 profile grades
NOT_FOR_AN_AS300 = {"delta-as300.master_heartbeat_watched"}
TIMING = dict(response=0.2, silence=0.1, heartbeat_ms=50, bootup=0.5, sdo_server_timeout=1.0)


@pytest.fixture(scope="module")
def eds(tmp_path_factory):
    path = tmp_path_factory.mktemp("eds") / "tiny.eds"
    path.write_text(eds_text())
    return str(path)


def run_against(eds: str, faults: set[str], **select):
    channel = f"tiny-{uuid.uuid4().hex[:8]}"
    with TinySlave(channel, 5, faults):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            # every profile: "all" leaves out what the tiny slave's EDS and identity do not
            # claim (LSS, store, CiA 401, the devices' profiles), so they are named
            select.setdefault("profiles", ["all", *PROFILES])
            return run_suite(SuiteConfig(5, eds, timing=Timing(**TIMING), **select), bus=bus)
        finally:
            bus.shutdown()


@pytest.fixture(scope="module")
def runs(eds):
    """The healthy and the broken slave, each on its own virtual channel, run side by side."""
    with ThreadPoolExecutor(2) as pool:
        futures = [pool.submit(run_against, eds, faults) for faults in (set(), set(FAULTS))]
        return [{r.case.id: r for r in f.result()} for f in futures]


@pytest.fixture(scope="module")
def healthy(runs):
    return runs[0]


@pytest.fixture(scope="module")
def broken(runs):
    return runs[1]


def test_healthy_slave_passes_every_applicable_case(healthy):
    report = text_report(list(healthy.values()))
    assert set(failed(list(healthy.values()))) == NOT_FOR_AN_AS300, report
    must_pass = {
        "od.eds_check",
        "od.read_all",
        "od.defaults",
        "od.write_read_only",
        "od.missing_object",
        "od.missing_subindex",
        "od.length_mismatch",
        "od.value_range",
        "sdo.expedited_upload",
        "sdo.expedited_download",
        "sdo.segmented_upload",
        "sdo.segmented_download",
        "sdo.upload_toggle_error",
        "sdo.download_toggle_error",
        "sdo.unknown_command",
        "sdo.client_abort",
        "sdo.server_timeout",
        "nmt.bootup_reset_node",
        "nmt.bootup_reset_comm",
        "nmt.transitions",
        "nmt.sdo_gated",
        "nmt.reset_comm_vs_node",
        "errctl.heartbeat_period",
        "errctl.heartbeat_disable",
        "errctl.guarding_toggle",
        "errctl.guarding_state",
        "store.unsaved_lost",
        "seed.tv02_segmented_upload",
        "seed.tv06_abort",
    }
    assert {cid for cid, r in healthy.items() if r.verdict is Verdict.PASS} >= must_pass, report


def test_features_the_eds_lacks_are_skipped_with_a_reason(healthy):
    assert healthy["sdo.block_upload"].verdict is Verdict.SKIP
    assert "0504 0001" in healthy["sdo.block_upload"].reason
    assert "LSS_Supported" in healthy["lss.fastscan"].reason
    assert "0x1014" in healthy["emcy.cobid"].reason
    assert "0x1010" in healthy["store.save_across_reset"].reason
    assert "not CiA 401" in healthy["cia401.objects"].reason
    assert all(r.reason for r in healthy.values() if r.verdict is Verdict.SKIP)


def test_broken_slave_fails_exactly_the_cases_for_its_faults(healthy, broken):
    expected = set().union(NOT_FOR_AN_AS300, *FAULTS.values())
    assert set(failed(list(broken.values()))) == expected, text_report(list(broken.values()))
    for cid, result in broken.items():
        if cid not in expected:
            assert result.verdict is healthy[cid].verdict, cid


def test_failure_reports_say_what_was_expected_and_seen(broken):
    toggle = broken["sdo.upload_toggle_error"]
    assert "05030000" in toggle.expected
    assert toggle.seen.startswith("585 [8] 10")
    assert any("→ 605 [8] 70" in line for line in toggle.frames)
    abort = broken["od.missing_subindex"]
    assert "0x06090011" in abort.expected and "0x06020000" in abort.seen
    guard = broken["errctl.guarding_toggle"]
    assert guard.expected == "0 1 0 1" and guard.seen == "0 0 0 0"


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_each_fault_alone_fails_its_cases(eds, fault, healthy):
    results = run_against(eds, {fault}, patterns=sorted(FAULTS[fault]))
    assert {r.case.id for r in results} == FAULTS[fault]
    assert set(failed(results)) == FAULTS[fault]
    assert all(healthy[cid].verdict is Verdict.PASS for cid in FAULTS[fault])


def test_cli_exit_code_junit_and_selection(eds, tmp_path, capsys):
    channel = f"tiny-{uuid.uuid4().hex[:8]}"
    junit = tmp_path / "report.xml"
    args = [
        "--interface",
        "virtual",
        "--channel",
        channel,
        "--node-id",
        "5",
        "--eds",
        eds,
        "--timeout",
        "0.2",
        "--silence",
        "0.1",
    ]
    with TinySlave(channel, 5, {"no_toggle_check"}):
        code = conformance_main(args + ["--profile", "sdo", "-k", "toggle", "--junit", str(junit)])
        out = capsys.readouterr().out
        assert code == 1
        assert "FAIL  sdo.upload_toggle_error" in out and "PASS  sdo.download_toggle_error" in out
        assert "od." not in out  # profile and -k selection
        assert "device: device name TinySlave conformance, vendor-ID 0x0000ABCD" in out
        suite = ET.parse(junit).getroot().find("testsuite")
        props = {p.get("name"): p.get("value") for p in suite.iter("property")}
        assert props["node-id"] == "5" and props["serial number"] == "0x12345678"
        assert suite.get("tests") == "2" and suite.get("failures") == "1"
        failure = suite.find("testcase[@name='sdo.upload_toggle_error']/failure")
        assert "05030000" in failure.get("message") + failure.text
        assert conformance_main(args + ["-k", "sdo.download_toggle*"]) == 0
