"""Metric samples of a :class:`~fieldgate.can.adapter.CanAdapter`, for a CAN front's ``metrics()``.

Read from the adapter's ``status()`` when ``/metrics`` is scraped (the adapter keeps these
counters anyway); in the format of the component metrics contract (fieldgate.http.metrics).
"""

from __future__ import annotations

from typing import Any

Sample = tuple[str, str, str, float, dict[str, str]]

# adapter counters that count frames that were received or meant to be sent but not used
_DROPPED = {
    "rx_extended_dropped": "extended-id",
    "rx_fd_dropped": "can-fd",
    "rx_error_frames": "error-frame",
    "tx_suppressed": "tx-suppressed",
}


def can_bus_samples(status: dict[str, Any] | None, ignored: int = 0) -> list[Sample]:
    """Frames received and sent, dropped by reason, ignored by the engine, bus-off state.

    ``ignored``: frames the protocol engine received but had no use for (another node's
    traffic, a PDO it does not consume), counted by the engine.
    """
    if not status:
        return []
    samples: list[Sample] = [
        (
            "can_frames_total",
            "counter",
            "CAN frames by direction",
            float(status.get("rx", 0)),
            {"direction": "rx"},
        ),
        (
            "can_frames_total",
            "counter",
            "CAN frames by direction",
            float(status.get("tx", 0)),
            {"direction": "tx"},
        ),
        (
            "can_frames_ignored_total",
            "counter",
            "received CAN frames the protocol engine had no use for",
            float(ignored),
            {},
        ),
        (
            "can_tx_errors_total",
            "counter",
            "CAN frames the driver refused to send",
            float(status.get("tx_errors", 0)),
            {},
        ),
        (
            "can_bus_off",
            "gauge",
            "1 while the CAN controller is bus-off",
            float(bool(status.get("bus_off"))),
            {},
        ),
        (
            "can_bus_off_events_total",
            "counter",
            "times the CAN controller went bus-off",
            float(status.get("bus_off_events", 0)),
            {},
        ),
    ]
    for key, reason in _DROPPED.items():
        samples.append(
            (
                "can_frames_dropped_total",
                "counter",
                "CAN frames dropped by the adapter, by reason",
                float(status.get(key, 0)),
                {"reason": reason},
            )
        )
    return samples
