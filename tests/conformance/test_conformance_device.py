"""The ``canopen-device`` front proved by the conformance tool (issue 35): the example
battery pack (examples/canopen-device) and CANopenNode's demo EDS (a third-party file,
tests/canopen/device/DS301_profile.eds) served on python-can's virtual bus, graded with
``--profile all`` against the EDS ``fieldgate eds`` writes; and that EDS round-trips: the
same objects, data types, access types, defaults, limits and PDO mapping flags as the file
the device was built from. Every case must pass or be one of the documented SKIPs below
(docs/canopen-device.md, "Conformance")."""

from __future__ import annotations

import shutil
import subprocess
import sys
import uuid
from collections import Counter
from pathlib import Path

import can
import pytest
from conformance_device import (
    CANOPENNODE_EDS,
    EXAMPLE,
    NODE_ID,
    battery_topology,
    canopennode_topology,
)
from conformance_gateway import GatewayThread, write_eds

from fieldgate.conformance import SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.report import text_report
from fieldgate.plugins.canopen.device.odfile import file_entries, read_device_file

# case -> a substring of its SKIP reason
BATTERY_SKIPS = {
    "od.read_write_only": "no write-only entry",
    "sync-pdo.bit_mapping": "byte granularity",
    "sync-pdo.granularity_whole_bytes": "maps single bits",  # 0x2103/0x2104 are BOOLEAN
}
# CANopenNode's demo lists no guarding objects, no RPDO mapping, no limits, no long values
NO_RPDO = "no valid, mapped any RPDO"
CANOPENNODE_SKIPS = {
    "od.read_write_only": "no write-only entry",
    "od.value_range": "no LowLimit/HighLimit",
    "sdo.segmented_upload": "longer than 4 bytes",
    "sdo.upload_toggle_error": "longer than 4 bytes",
    "nmt.reset_comm_vs_node": "no writable application entry",
    **{
        f"errctl.{case}": "no 0x100C"
        for case in (
            "guarding_toggle",
            "guarding_state",
            "life_guarding",
            "guarding_off_no_life_guard",
            "error_behaviour",
            "guard_off_ends_error",
            "guard_reset_ends_error",
        )
    },
    **{
        case: NO_RPDO
        for case in (
            "emcy.error_and_reset",
            "emcy.same_error_once",
            "emcy.history",
            "emcy.cobid_valid_bit",
            "emcy.inhibit",
            "sync-pdo.rpdo_length",
            "sync-pdo.rpdo_gated",
            "sync-pdo.rpdo_sync",
            "sync-pdo.dummy_mapping",
            "sync-pdo.dummy_undeclared",
        )
    },
    "sync-pdo.mapping_too_long": "cannot exceed 64 bits",
    "sync-pdo.bit_mapping": "byte granularity",
    # its TPDO COB-IDs set bit 30 (no RTR): the RTR cases have no PDO to ask
    **{
        f"sync-pdo.{case}": "bit 30 set (no RTR allowed)"
        for case in ("tpdo_rtr", "type252", "type253", "rtr_not_allowed")
    },
}
TOPOLOGIES = {
    "battery": (battery_topology, EXAMPLE.parent / "battery.eds", BATTERY_SKIPS, 95),
    "canopennode": (canopennode_topology, CANOPENNODE_EDS, CANOPENNODE_SKIPS, 70),
}


def grade(name: str, work):
    make, _, _, _ = TOPOLOGIES[name]
    channel = f"dev-{uuid.uuid4().hex[:8]}"
    topo = make(work / "state", channel)
    eds = write_eds(topo, work)
    timing = Timing(response=0.3, silence=0.1, heartbeat_ms=50, bootup=1.0, sdo_server_timeout=1.0)
    with GatewayThread(topo):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            results = run_suite(
                SuiteConfig(NODE_ID, str(eds), timing=timing, profiles=["all"]), bus=bus
            )
        finally:
            bus.shutdown()
    return eds, results


@pytest.fixture(scope="module", params=sorted(TOPOLOGIES))
def graded(request, tmp_path_factory):
    return request.param, *grade(request.param, tmp_path_factory.mktemp(request.param))


def test_every_case_passes_or_is_a_documented_skip(graded):
    name, _, results = graded
    _, _, skips, least = TOPOLOGIES[name]
    report = text_report(results)
    verdicts = Counter(r.verdict for r in results)
    assert verdicts[Verdict.FAIL] == 0, report
    assert verdicts[Verdict.INCONCLUSIVE] == 0, report
    assert verdicts[Verdict.PASS] >= least, verdicts
    for r in results:
        if r.verdict is Verdict.SKIP:
            assert r.case.id in skips, f"undocumented SKIP {r.case.id}: {r.reason}"
            assert skips[r.case.id] in r.reason, (
                f"{r.case.id} skipped for another reason: {r.reason}"
            )


def entries(path) -> dict:
    return {
        (v.index, v.subindex): (
            v.data_type,
            v.access_type,
            v.default,
            bool(getattr(v, "relative", False)),
            v.pdo_mappable,
            v.min,
            v.max,
        )
        for v in file_entries(read_device_file(path))
    }


def test_the_eds_round_trips(graded):
    name, eds, _ = graded
    source = TOPOLOGIES[name][1]
    assert entries(eds) == entries(source)


def test_the_written_eds_passes_lely_dcfchk(graded):
    _, eds, _ = graded
    dcfchk = shutil.which("dcfchk") or str(Path(sys.executable).with_name("dcfchk"))
    result = subprocess.run(
        [dcfchk, "-n", "5", str(eds)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0 and "Warning" not in result.stderr, result.stderr
