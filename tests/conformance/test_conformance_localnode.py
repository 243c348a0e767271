"""canopen's LocalNode as a third-party device: the suite must find the gaps the library
probe measured (docs: ../shared/spec/probe-python-libs.md §2) and pass what LocalNode does well.

The report of this run is kept in docs/conformance-localnode-report.txt
(regenerate: ``python tests/conformance/test_conformance_localnode.py > docs/conformance-localnode-report.txt``).
"""

import sys
import uuid
from pathlib import Path

import can
import pytest
from conformance_localnode import NODE_ID, LocalNodeDevice, write_eds

from fieldgate.conformance import SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.report import text_report

TIMING = dict(response=0.1, silence=0.05, heartbeat_ms=50, bootup=0.1, sdo_server_timeout=0.2)

# what the probe measured as missing in LocalNode, and the case that must catch it
PROBE_GAPS = {
    "nmt.bootup_reset_node": "no boot-up after reset node",
    "nmt.bootup_reset_comm": "no boot-up after reset communication",
    "nmt.sdo_gated": "SDO still served in STOPPED",
    "errctl.guarding_state": "remote frames dropped: no node guarding reply",
    "sdo.block_upload": "block upload falls back to a normal upload",
    "od.value_range": "LowLimit/HighLimit not checked",
    "sync-pdo.sync_type1": "no SYNC consumer",
    "sync-pdo.event_timer": "nothing scheduled from 0x1800",
    "sync-pdo.tpdo_rtr": "no RTR answer on the TPDO",
    "sync-pdo.rpdo_length": "no EMCY for a short RPDO",
    "sync-pdo.rpdo_gated": "RPDO data never reach the object dictionary",
}
# one deviation, one FAIL: the cases that need what a FAIL above already grades give no verdict
# (a case that needs guard replies) or SKIP (the block cases: the device has no block transfer)
FOLLOW_ONS = {
    "errctl.guard_off_ends_error": (Verdict.INCONCLUSIVE, "errctl.guarding_state grades that"),
    "nmt.preop_after_bootup": (Verdict.INCONCLUSIVE, "nmt.bootup_* grade that"),
    "sdo.block_download": (Verdict.SKIP, "sdo.block_upload grades that"),
}
PROBE_WORKS = {
    "sdo.expedited_upload",
    "sdo.expedited_download",
    "sdo.segmented_upload",
    "sdo.segmented_download",
    "od.missing_object",
    "od.write_read_only",
    "od.length_mismatch",
    "errctl.heartbeat_period",
    "nmt.transitions",
    "emcy.cobid",
}


def run_localnode(eds_dir: Path):
    channel = f"ln-{uuid.uuid4().hex[:8]}"
    eds = write_eds(eds_dir / "localnode.eds")
    with LocalNodeDevice(channel, eds):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            # default selection: LocalNode claims no I-7232D compatibility, so no seed profile
            return run_suite(SuiteConfig(NODE_ID, str(eds), timing=Timing(**TIMING)), bus=bus)
        finally:
            bus.shutdown()


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return {r.case.id: r for r in run_localnode(tmp_path_factory.mktemp("localnode"))}


@pytest.mark.parametrize("cid", sorted(PROBE_GAPS))
def test_suite_finds_the_gaps_the_probe_measured(results, cid):
    assert results[cid].verdict is Verdict.FAIL, f"{cid} should catch: {PROBE_GAPS[cid]}"


@pytest.mark.parametrize("cid", sorted(FOLLOW_ONS))
def test_a_gap_fails_once_and_its_follow_ons_say_why(results, cid):
    verdict, why = FOLLOW_ONS[cid]
    assert results[cid].verdict is verdict and why in results[cid].reason, results[cid]


def test_suite_passes_what_localnode_does_well(results):
    passed = {cid for cid, r in results.items() if r.verdict is Verdict.PASS}
    assert PROBE_WORKS <= passed, text_report(list(results.values()))


def test_features_outside_its_eds_are_skipped(results):
    assert "0x1016" in results["errctl.heartbeat_consumer"].reason
    assert (
        "0x1016" in results["errctl.consumer_off_ends_error"].reason
        and "0x1006" in results["sync-pdo.sync_loss_ends_on_sync"].reason
    )
    assert results["lss.fastscan"].verdict is Verdict.SKIP


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = run_localnode(Path(tmp))
    sys.stdout.write(
        text_report(
            out,
            header=f"fieldgate conformance against canopen {__import__('canopen').__version__} LocalNode (node {NODE_ID}, virtual bus)\n",
        )
    )
