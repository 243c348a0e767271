"""The CI version of bench/fleet.py: 3 gateway processes, 10 s, a broker restart in the middle.

The full run (50 gateways, 60 s) is documented in docs/sparkplug.md; its speed and memory
figures are the bench's to print. What this test holds is what must be true at any size:
every sample each gateway saw in its process image reached the subscriber, once, in order.
The broker is SIGKILLed without persistence (--restart kill): everything after the outage
then comes from the gateways' journals, so a duplicate or a gap is the gateway's (a broker
restarted with SIGTERM and persistence redelivers QoS 1 messages: duplicates by design).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from .broker import require_mosquitto

BENCH = Path(__file__).resolve().parents[2] / "bench" / "fleet.py"


def test_a_small_fleet_loses_nothing_across_a_broker_restart(tmp_path):
    require_mosquitto()
    out = tmp_path / "fleet.json"
    run = subprocess.run(
        [
            sys.executable,
            str(BENCH),
            "--gateways",
            "3",
            "--duration",
            "10",
            "--points",
            "20",
            "--restart",
            "kill",
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=150,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(out.read_text())
    assert result["gateways_reporting"] == 3
    assert result["samples_per_s"] > 0 and result["outage_s"] >= 1.0
    assert (result["lost"], result["duplicated"], result["out_of_order"]) == (0, 0, 0)
    assert result["journal_dropped"] == 0 and result["backlog_left"] == 0
