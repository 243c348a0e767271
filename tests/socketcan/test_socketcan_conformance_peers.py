"""`fieldgate conformance --profile all` against independent stacks over real SocketCAN, in
the SocketCAN stage (skipped elsewhere): canopen's LocalNode and durand each run as their own
process on vcan0, the suite as another, with the CLI's default timing (scaled by the guest's
slowdown); the verdicts must be the checked-in ones (tests/conformance/peers/, explained in
docs/conformance-peers.md)."""

from __future__ import annotations

import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from socketcan_guest import SLOWDOWN, in_guest, scaled

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "conformance"))
from conformance_peers import PEERS, differences  # noqa: E402

CHANNEL = "vcan0"
pytestmark = in_guest(CHANNEL)


def serve(name: str, workdir: Path) -> tuple[subprocess.Popen[bytes], Path]:
    eds = workdir / f"{name}.eds"
    log = (workdir / f"{name}.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, str(PEERS[name].script), "--channel", CHANNEL, "--eds", str(eds)],
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    deadline = time.monotonic() + scaled(30)
    while time.monotonic() < deadline and "up" not in (workdir / f"{name}.log").read_text():
        assert proc.poll() is None, (workdir / f"{name}.log").read_text()
        time.sleep(0.1)
    return proc, eds


@pytest.mark.timeout(600)
@pytest.mark.parametrize("name", sorted(PEERS))
def test_the_peer_gets_its_expected_verdicts_over_vcan0(name, tmp_path):
    proc, eds = serve(name, tmp_path)
    try:
        junit = tmp_path / "conformance.xml"
        run = subprocess.run(
            [
                sys.executable,
                "-m",
                "fieldgate.conformance",
                "--interface=socketcan",
                f"--channel={CHANNEL}",
                f"--node-id={PEERS[name].node_id}",
                f"--eds={eds}",
                "--profile=all",
                f"--junit={junit}",
                f"--timeout={0.5 * SLOWDOWN:.2f}",
                f"--silence={0.3 * SLOWDOWN:.2f}",
                f"--tolerance-ms={40 * SLOWDOWN:.0f}",
            ],
            capture_output=True,
            text=True,
            timeout=scaled(400),
        )
        assert run.returncode in (0, 1), run.stdout[-3000:] + run.stderr[-2000:]
        suite = ET.parse(junit).getroot().find("testsuite")
        assert suite is not None
        seen = {
            tc.get("name", ""): tc.find("properties/property[@name='verdict']").get("value", "")  # type: ignore[union-attr]
            for tc in suite.iter("testcase")
        }
        assert not differences(name, seen), f"{differences(name, seen)}\n{run.stdout[-6000:]}"
    finally:
        proc.terminate()
        try:
            proc.wait(scaled(10))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
