"""Helpers for a component's ``metrics()`` (the contract in :mod:`fieldgate.http.metrics`).

A front or back MAY have ``metrics(self) -> list[Sample]``; a sample is the plain tuple
``(name without the fieldgate_ prefix, "counter" | "gauge", help, value, labels)``. These
helpers only build such tuples (a plugin may as well write them by hand) and hold the
series that mean the same for every front.
"""

from __future__ import annotations

Sample = tuple[str, str, str, float, dict[str, str]]


def counter(name: str, help_text: str, value: float, **labels: str) -> Sample:
    """A counter sample; ``name`` ends in ``_total``."""
    return (name, "counter", help_text, float(value), labels)


def gauge(name: str, help_text: str, value: float, **labels: str) -> Sample:
    return (name, "gauge", help_text, float(value), labels)


def state_gauges(
    name: str,
    help_text: str,
    states: list[str] | tuple[str, ...],
    current: str,
    label: str = "state",
) -> list[Sample]:
    """One gauge per possible state, 1 for the current one (the Prometheus enum pattern)."""
    return [gauge(name, help_text, float(state == current), **{label: state}) for state in states]


def master_output_writes(value: float) -> Sample:
    """Output process data a front received from its master (any fieldbus)."""
    return counter(
        "master_output_writes_total",
        "output process data received from the master (RPDOs, DeviceNet polls with data)",
        value,
    )
