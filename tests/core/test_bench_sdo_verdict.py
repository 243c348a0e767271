"""bench/canopen_sdo.py's verdict: faster, a tie inside the run's own spread, or slower."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from canopen_sdo import TIE, verdict  # noqa: E402


def test_faster_needs_both_ratios():
    assert verdict(1.02, 1.01, [0.99, 1.02, 1.05]) == "faster"
    assert (
        verdict(1.02, 0.99, [1.01, 1.02, 1.05]) == "slower"
    )  # every round faster, yet fewer req/s


def test_a_tie_lies_inside_the_spread_of_the_rounds():
    assert verdict(0.98, 0.99, [0.93, 0.99, 1.04]) == TIE


def test_outside_the_spread_or_beyond_three_percent_is_slower():
    assert verdict(0.98, 0.99, [0.95, 0.97, 0.99]) == "slower"  # no round was faster
    assert verdict(0.96, 0.99, [0.90, 0.96, 1.02]) == "slower"
