"""The suite over real SocketCAN (vcan0 inside User-Mode Linux, `.ci/socketcan/run`), skipped elsewhere.

The gateway runs as its own process (`fieldgate run`), the suite as another
(`python -m fieldgate.conformance`), exactly as a test engineer would use them.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import can
import pytest
from conformance_gateway import (
    DOCUMENTED_SKIPS,
    KNOWN_FINDINGS,
    NODE_ID,
    front_unavailable,
    topology,
    write_eds,
)
from socketcan_guest import SLOWDOWN, in_guest, scaled

CHANNEL = "vcan0"

pytestmark = in_guest(CHANNEL)


def wait_bootup(timeout: float) -> bool:
    with can.Bus(interface="socketcan", channel=CHANNEL) as bus:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = bus.recv(0.5)
            if (
                msg is not None
                and msg.arbitration_id == 0x700 + NODE_ID
                and bytes(msg.data) == b"\x00"
            ):
                return True
    return False


def test_suite_over_vcan0_against_the_gateway_process(tmp_path):
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    topo = topology(tmp_path / "state", CHANNEL)
    topo["fronts"][0]["interface"] = "socketcan"
    eds = write_eds(topo, tmp_path)
    source = tmp_path / "topology.yaml"
    source.write_text(json.dumps(topo))
    log = (tmp_path / "gateway.log").open("w")
    gateway = subprocess.Popen(
        [sys.executable, "-m", "fieldgate", "run", str(source)],
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        assert wait_bootup(scaled(30)), (tmp_path / "gateway.log").read_text()
        junit = tmp_path / "conformance.xml"
        run = subprocess.run(
            [
                sys.executable,
                "-m",
                "fieldgate.conformance",
                "--interface",
                "socketcan",
                "--channel",
                CHANNEL,
                "--node-id",
                str(NODE_ID),
                "--eds",
                str(eds),
                "--profile",
                "all",
                "--loopback",
                "--junit",
                str(junit),
                "--heartbeat-ms",
                "100",
                "--tolerance-ms",
                f"{40 * SLOWDOWN:.0f}",
            ],
            capture_output=True,
            text=True,
            timeout=scaled(600),
        )
        assert run.returncode in (0, 1), run.stdout[-3000:] + run.stderr[-2000:]
        suite = ET.parse(junit).getroot().find("testsuite")
        failures = {
            tc.get("name") for tc in suite.iter("testcase") if tc.find("failure") is not None
        }
        assert failures <= set(KNOWN_FINDINGS), run.stdout[-8000:]
        for tc in suite.iter("testcase"):
            skipped = tc.find("skipped")
            if skipped is not None:
                name = tc.get("name")
                assert name in DOCUMENTED_SKIPS and DOCUMENTED_SKIPS[name] in skipped.get(
                    "message"
                ), f"undocumented SKIP {name}"
        assert int(suite.get("tests")) >= 100
    finally:
        gateway.terminate()
        try:
            gateway.wait(scaled(10))
        except subprocess.TimeoutExpired:
            gateway.kill()
            gateway.wait()
        log.close()
