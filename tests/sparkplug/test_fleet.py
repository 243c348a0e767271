"""The CI version of bench/fleet.py: 3 gateway processes, 10 s, a broker restart in the middle.

The full run (50 gateways, 60 s) is documented in docs/sparkplug.md; its speed and memory
figures are the bench's to print. What this test holds is what must be true at any size:
every sample each gateway saw in its process image reached the subscriber, in order, and
once but for the DDATA in flight when the broker died (replayed: at-least-once).
The broker is SIGKILLed without persistence (--restart kill): everything after the outage
then comes from the gateways' journals, so a duplicate or a gap is the gateway's (a broker
restarted with SIGTERM and persistence redelivers QoS 1 messages: duplicates by design).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from .broker import in_flight_repeats, require_mosquitto

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
    assert (result["lost"], result["out_of_order"]) == (0, 0)
    # At-least-once across a SIGKILL: a DDATA the broker had passed on when it died, its sync
    # not yet back, is replayed as historical. Every repeat must be that (first seen before the
    # restart, again as historical after it), and there are at most a second's samples of them
    # (in one CI run: 20, one DDATA of one gateway; usually 0).
    assert result["duplicated"] == result["duplicated_in_flight"], result["examples"]
    assert result["duplicated_in_flight"] <= 3 * 20 * result["rate_hz"]
    assert result["journal_dropped"] == 0 and result["backlog_left"] == 0


def test_only_a_replay_of_what_was_in_flight_at_the_restart_counts_as_in_flight():
    restart = 100.0
    # (sample, arrived, historical)
    live_then_replayed = [((1, 5), 99.0, False), ((1, 5), 101.0, True)]
    assert in_flight_repeats(live_then_replayed, restart) == 1
    twice_live = [((1, 5), 99.0, False), ((1, 5), 99.5, False)]  # the gateway's fault
    assert in_flight_repeats(twice_live, restart) == 0
    replayed_live_after = [((1, 5), 99.0, False), ((1, 5), 101.0, False)]  # not historical
    assert in_flight_repeats(replayed_live_after, restart) == 0
    both_after = [((2, 6), 101.0, True), ((2, 6), 102.0, True)]  # replayed twice
    assert in_flight_repeats(both_after, restart) == 0
    other_sample = [((1, 5), 99.0, False), ((2, 5), 101.0, True)]  # same value, another time
    assert in_flight_repeats(other_sample, restart) == 0
