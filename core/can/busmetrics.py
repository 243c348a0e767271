"""Metric samples of a :class:`~fieldgate.can.adapter.CanAdapter`, for a CAN front's ``metrics()``.

Read from the adapter's ``status()`` when ``/metrics`` is scraped (the adapter keeps these
counters anyway); in the format of the component metrics contract (fieldgate.http.metrics).
"""

from __future__ import annotations

from typing import Any

from ..metric_samples import Sample, counter, gauge, state_gauges

CONTROLLER_STATES = ("error-active", "warning", "passive", "bus-off")
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
    frames = "CAN frames by direction"
    dropped = "CAN frames dropped by the adapter, by reason"
    return [
        counter("can_frames_total", frames, status.get("rx", 0), direction="rx"),
        counter("can_frames_total", frames, status.get("tx", 0), direction="tx"),
        counter(
            "can_frames_ignored_total",
            "received CAN frames the protocol engine had no use for",
            ignored,
        ),
        counter(
            "can_tx_errors_total",
            "CAN frames the driver refused to send",
            status.get("tx_errors", 0),
        ),
        gauge("can_bus_off", "1 while the CAN controller is bus-off", bool(status.get("bus_off"))),
        counter(
            "can_bus_off_events_total",
            "times the CAN controller went bus-off",
            status.get("bus_off_events", 0),
        ),
        counter(
            "can_bus_off_recoveries_total",
            "times the CAN controller recovered from bus-off",
            status.get("bus_off_recoveries", 0),
        ),
        *_link_samples(status.get("link")),
        *(
            counter("can_frames_dropped_total", dropped, status.get(key, 0), reason=reason)
            for key, reason in _DROPPED.items()
        ),
        *state_gauges(
            "can_controller_state",
            "1 for the CAN controller's error state now",
            CONTROLLER_STATES,
            status.get("controller", "error-active"),
        ),
        *(
            counter(
                "can_overruns_total",
                "times frames were lost: rx = the gateway's receive queue, tx = the driver's "
                "transmit queue, controller = the CAN controller's buffers",
                value,
                kind=kind,
            )
            for kind, value in (status.get("overruns") or {}).items()
        ),
    ]


def _link_samples(link: dict[str, Any] | None) -> list[Sample]:
    """What the kernel reports of a SocketCAN interface fieldgate controls (docs/can-link.md):
    the controller's error counters and the restarts after bus-off, the kernel's and ours."""
    if not link:
        return []
    errors = "the CAN controller's transmit / receive error counter (as last read)"
    samples = [
        counter(
            "can_controller_restarts_total",
            "restarts of the CAN controller after bus-off, as the kernel counts them (its own "
            "after restart-ms, and fieldgate's)",
            link.get("restarts") or 0,
        ),
        counter(
            "can_controller_restarts_by_fieldgate_total",
            "restarts after bus-off fieldgate asked for (where the kernel has restart-ms 0)",
            link.get("restarts_by_fieldgate", 0),
        ),
        gauge(
            "can_link_error", "1 while the interface is not as configured", bool(link.get("error"))
        ),
    ]
    for direction in ("tx", "rx"):
        value = link.get(f"{direction}_errors")
        if value is not None:
            samples.append(gauge("can_error_counter", errors, value, direction=direction))
    return samples
