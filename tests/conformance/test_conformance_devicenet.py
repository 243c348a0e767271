"""The devicenet profile against fieldgate's devicenet front (in-process, virtual bus) and against
deliberately broken variants of it: every case passes on the front, and each fault fails exactly
the case that checks it."""

from __future__ import annotations

import subprocess
import sys
import uuid
import xml.etree.ElementTree as ET

import can
import pytest
from conformance_gateway import GatewayThread

from fieldgate.conformance import (
    DnetSuiteConfig,
    Options,
    Timing,
    Verdict,
    failed,
    run_devicenet_suite,
    select,
)
from fieldgate.conformance.cli import main as conformance_main
from fieldgate.plugins.devicenet import cip
from fieldgate.plugins.devicenet.allocation import Allocation
from fieldgate.plugins.devicenet.cip import CipError
from fieldgate.plugins.devicenet.connection import Connection
from fieldgate.plugins.devicenet.explicit import ExplicitServer
from fieldgate.plugins.devicenet.netaccess import NetworkAccess

MAC_ID = 5
TIMING = Timing(response=0.3, silence=0.15, bootup=1.0, heartbeat_ms=100)
# case id -> why it cannot apply to fieldgate's front (a substring of the SKIP reason); none today
DOCUMENTED_SKIPS: dict[str, str] = {}


def topology(state_dir, channel: str) -> dict:
    return {
        "gateway": {"name": "dnet-conformance", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "dnet",
                "type": "devicenet",
                "interface": "virtual",
                "channel": channel,
                "mac_id": MAC_ID,
                "baudrate": 500000,
                "dup_mac_timeout_ms": 50,
                "identity": {
                    "vendor_id": 803,
                    "serial": 42,
                    "product_name": "fieldgate conformance",
                },
                # COS and cyclic carry outputs too (the cos_consume / cyclic_both_ways cases)
                "io_paths": {
                    "cos": {"produce": "inputs", "consume": "outputs"},
                    "cyclic": {"produce": "inputs", "consume": "outputs"},
                },
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 3, "digital": 8, "analog": 2, "error_mode": {"value": 0}}],
            }
        ],
    }


@pytest.fixture
def device(tmp_path):
    """A gateway with a devicenet front on its own virtual channel; yields the channel name."""
    channel = f"dnet-conf-{uuid.uuid4().hex[:8]}"
    with GatewayThread(topology(tmp_path, channel)):
        yield channel


def run(channel: str, patterns: list[str] | None = None, loopback: bool = True):
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        return run_devicenet_suite(
            DnetSuiteConfig(
                MAC_ID, patterns=patterns or [], timing=TIMING, options=Options(loopback=loopback)
            ),
            bus=bus,
        )
    finally:
        bus.shutdown()


def test_every_case_passes_on_fieldgates_front(device):
    results = run(device)
    assert [r.case.id for r in results] == [c.id for c in select(protocol="devicenet")]
    assert len(results) >= 15
    for r in results:
        if r.verdict is Verdict.SKIP:
            assert r.case.id in DOCUMENTED_SKIPS and DOCUMENTED_SKIPS[r.case.id] in r.reason, (
                r.case.id,
                r.reason,
            )
        else:
            assert r.verdict is Verdict.PASS, (r.case.id, r.reason, r.expected, r.seen, r.frames)


def test_wrong_cip_error_fails_only_its_case(device, monkeypatch):
    original = ExplicitServer.error

    def wrong_code(self, header, err):  # answers "object does not exist" for an unknown attribute
        return original(
            self,
            header,
            CipError(cip.OBJECT_DOES_NOT_EXIST)
            if err.general == cip.ATTRIBUTE_NOT_SUPPORTED
            else err,
        )

    monkeypatch.setattr(ExplicitServer, "error", wrong_code)
    results = run(device)
    assert failed(results) == ["devicenet.error_unknown_attribute"]
    bad = next(r for r in results if r.verdict is Verdict.FAIL)
    assert "0x14" in bad.expected and "0x16" in bad.seen
    assert any("→" in line and "0E 01 01 63" in line for line in bad.frames)


def test_a_release_that_keeps_the_connections_fails(device, monkeypatch):
    monkeypatch.setattr(
        Allocation, "release", lambda self, choice, now: b""
    )  # answers CC, closes nothing
    assert failed(run(device, ["release"])) == ["devicenet.release"]


def test_loopback_case_skips_without_the_bench_and_fails_on_a_broken_loop(device, monkeypatch):
    skipped = run(device, ["loopback"], loopback=False)
    assert [(r.verdict, r.reason) for r in skipped] == [
        (Verdict.SKIP, "needs --loopback (a bench whose outputs are wired to its inputs)")
    ]
    from fieldgate.plugins.devicenet.assembly import Assemblies

    monkeypatch.setattr(
        Assemblies, "consume", lambda self, assembly, data: []
    )  # polled outputs are dropped
    assert failed(run(device, ["loopback"])) == ["devicenet.loopback_poll"]


def test_wrong_allocation_errors_fail(device, monkeypatch):
    original = Allocation.allocate

    def lax(self, choice, master, now):  # choice 0 refused with the wrong code
        if choice == 0:
            raise CipError(cip.RESOURCE_UNAVAILABLE, cip.INVALID_ALLOCATION_CHOICE)
        return original(self, choice, master, now)

    monkeypatch.setattr(Allocation, "allocate", lax)
    results = run(device, ["allocate_"])
    assert failed(results) == ["devicenet.allocate_validation"] and len(results) == 3


def test_no_inactivity_timeout_fails(device, monkeypatch):
    monkeypatch.setattr(Connection, "expired", lambda self, now: False)
    results = run(device, ["epr_", "inactivity"])
    assert {r.case.id: r.verdict for r in results} == {
        "devicenet.epr_keeps_alive": Verdict.PASS,
        "devicenet.inactivity_timeout": Verdict.FAIL,
    }


def test_silent_on_duplicate_mac_requests_fails(device, monkeypatch):
    original = NetworkAccess.dup_mac_frame

    def ignore_requests_online(self, data):
        if self.slave.state != "online":
            original(self, data)

    monkeypatch.setattr(NetworkAccess, "dup_mac_frame", ignore_requests_online)
    results = run(device, ["dup_mac"])
    assert {r.case.id: r.verdict for r in results} == {
        "devicenet.dup_mac_answer": Verdict.FAIL,
        "devicenet.dup_mac_at_reset": Verdict.PASS,
    }


def test_fragments_with_wrong_counts_fail(device, monkeypatch):
    from fieldgate.plugins.devicenet import explicit

    real_split = explicit.split
    monkeypatch.setattr(
        explicit,
        "split",
        lambda payload, chunk: [(frag & 0xC0, data) for frag, data in real_split(payload, chunk)],
    )  # count stuck at 0
    results = run(device, ["fragmented", "identity"])
    assert failed(results) == [
        "devicenet.identity",
        "devicenet.identity_get_all",
        "devicenet.fragmented_response",
    ]  # Get_Attributes_All is fragmented too


def test_get_attributes_all_in_the_wrong_order_fails(device, monkeypatch):
    from fieldgate.plugins.devicenet import objects

    monkeypatch.setattr(
        objects, "IDENTITY_ALL", (1, 2, 3, 4, 6, 5, 7)
    )  # serial number before status
    results = run(device, ["identity"])
    assert {r.case.id: r.verdict for r in results} == {
        "devicenet.identity": Verdict.PASS,
        "devicenet.identity_get_all": Verdict.FAIL,
    }
    bad = results[1]
    assert (
        "vendor ID, device type, product code, revision, status, serial number, product name"
        in bad.reason
    )
    assert bad.seen != bad.expected and sorted(bad.seen) == sorted(bad.expected)


def test_cli_devicenet_exit_codes_and_junit(device, tmp_path, monkeypatch):
    junit = tmp_path / "dnet.xml"
    args = [
        "--protocol",
        "devicenet",
        "--interface",
        "virtual",
        "--channel",
        device,
        "--mac-id",
        str(MAC_ID),
        "--timeout",
        "0.3",
        "--silence",
        "0.15",
    ]
    assert conformance_main(args + ["-k", "identity", "-k", "error_", "--junit", str(junit)]) == 0
    suite = next(ET.parse(junit).getroot().iter("testsuite"))
    assert suite.get("tests") == "6" and suite.get("failures") == "0"
    properties = {p.get("name"): p.get("value") for p in suite.iter("property")}
    assert properties["mac-id"] == "5" and properties["product name"] == "fieldgate conformance"
    monkeypatch.setattr(Allocation, "release", lambda self, choice, now: b"")
    assert conformance_main(args + ["-k", "release"]) == 1
    assert (
        conformance_main(args[:-6] + ["--mac-id", "9", "--bootup-timeout", "0.5"]) == 2
    )  # nobody at MAC 9


def test_cli_devicenet_list_and_arguments():
    listed = subprocess.run(
        [sys.executable, "-m", "fieldgate.conformance", "--protocol", "devicenet", "--list"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    ids = [line.split()[0] for line in listed.stdout.splitlines()]
    assert (
        listed.returncode == 0
        and ids == [c.id for c in select(protocol="devicenet")]
        and all(i.startswith("devicenet.") for i in ids)
    )
    assert not any(c.profile == "devicenet" for c in select()) and not any(
        c.profile == "devicenet" for c in select(["all"])
    )
    assert conformance_main(["--protocol", "devicenet", "--channel", "x"]) == 2  # no --mac-id
    assert conformance_main(["--protocol", "devicenet", "--mac-id", "0", "--master-mac", "0"]) == 2
    assert (
        conformance_main(["--profile", "devicenet", "--list"]) == 2
    )  # a DeviceNet profile needs --protocol devicenet
    assert conformance_main(["--protocol", "devicenet", "--profile", "sdo", "--list"]) == 2


def test_a_path_that_does_not_match_its_size_fails_io_paths(device, monkeypatch):
    from fieldgate.plugins.devicenet.connection_set import ConnectionSet

    original = ConnectionSet.select

    def one_byte_short(c, produces, consumes):
        original(c, produces, consumes)
        c.produced_size = max(0, c.produced_size - 1)

    monkeypatch.setattr(ConnectionSet, "select", staticmethod(one_byte_short))
    assert failed(run(device, ["io_paths"])) == ["devicenet.io_paths"]


def test_unacknowledged_master_data_fails_cos_and_cyclic(device, monkeypatch):
    from fieldgate.plugins.devicenet.io_messaging import IoMessaging

    original = IoMessaging.send

    def no_empty_acks(self, message, payload):
        if payload:
            original(self, message, payload)

    monkeypatch.setattr(IoMessaging, "send", no_empty_acks)
    results = run(device, ["cos_consume", "cyclic_both_ways", "poll_io"])
    assert {r.case.id: r.verdict for r in results} == {
        "devicenet.poll_io": Verdict.PASS,
        "devicenet.cos_consume": Verdict.FAIL,
        "devicenet.cyclic_both_ways": Verdict.FAIL,
    }


def test_application_lengths_that_disagree_with_the_data_fail(device, monkeypatch):
    from fieldgate.plugins.devicenet import application

    monkeypatch.setattr(application, "LENGTH_ATTR", 0x10)  # counts where lengths belong
    assert failed(run(device, ["application_object"])) == ["devicenet.application_object"]
