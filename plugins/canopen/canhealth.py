"""CAN controller health as EMCYs: error warning, error passive and overruns (sans-I/O).

The adapter (``fieldgate.can.adapter``) reports what it sees of the controller and the
gateway's own queues through the front: :meth:`CanHealth.controller` with the error state
(``error-active``, ``warning``, ``passive``), :meth:`CanHealth.overrun` with ``rx``
(the gateway's receive queue dropped frames), ``tx`` (the driver's transmit queue was
full, or the EMCY queue overflowed) or ``controller`` (the controller lost frames). Each
condition is an EMCY error of the style's table (:data:`.profiles.DeviceProfile.controller_emcy`):

| condition | icpdas (seed-000 §2.5) | na9161 (ours: its table is missing) |
|---|---|---|
| error warning | ``00 10 81 01`` CAN controller error | ``00 81 11 80`` |
| error passive | ``00 10 81 01`` CAN controller error | ``20 81 11 80`` |
| software Rx overrun | ``10 81 11 04`` | ``10 81 11 10`` |
| software Tx overrun (EMCY queue too) | ``10 81 11 05`` | ``10 81 11 20`` |
| controller overrun | ``10 81 11 06`` | ``10 81 11 10`` |

The error state's EMCY is active while the controller is in that state and cleared (error
reset EMCY) when it is error-active again; going from passive back to warning clears the
passive error and raises the warning one (the new error first, so 0x1001 never drops
while the controller is in error; nothing where the style gives both the same code, as
the I-7232D's single "CAN controller error"). An overrun is an event:
its error stays active until :data:`OVERRUN_QUIET_S` pass without another one, then it
is cleared. An overflow of the EMCY queue itself is reported at once, ahead of the queue
(the NA-9161's "an overflow EMCY is sent at once"). Bus-off stays error control's
(EMCY 0x8140 on recovery).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from .cia301.service import ALL_STATES, NodeHost, Service
from .profiles import ControllerEmcy

OVERRUN_QUIET_S = 1.0  # an overrun error ends after this long without another overrun
# the CAN interface could not be set as configured (bit rate at start or at an LSS switch,
# sample point, restart-ms; docs/can-link.md): ours in both styles, CiA 301's communication
# code with the next number of the ICP DAS table's manufacturer byte
LINK_EMCY: ControllerEmcy = (0x8100, 0x11, b"\x0d")
STATES = ("error-active", "warning", "passive")


def _key(error: ControllerEmcy) -> tuple[int, bytes]:
    """The EMCY producer's identity of an error: code and manufacturer bytes."""
    return error[0], error[2]


class CanHealth(Service):
    name = "can_health"
    active_states = ALL_STATES

    def __init__(self, emcys: dict[str, ControllerEmcy], quiet_s: float = OVERRUN_QUIET_S):
        super().__init__()
        self.emcys = emcys
        self.quiet_s = quiet_s
        self.state = "error-active"
        self.overruns: Counter[str] = Counter()
        self._overrun_since: dict[tuple[int, bytes], float] = {}  # active overrun -> last one
        self.link_problem: str | None = None

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        if node.emcy is not None:
            node.emcy.on_overflow = self._emcy_queue_overflow

    def _emcy_queue_overflow(self, now: float) -> None:
        self.overrun("tx", now, urgent=True)

    # -- what the adapter saw -------------------------------------------------------------
    def controller(self, state: str, now: float) -> None:
        """The controller's error state: error-active, warning or passive."""
        if state not in STATES or state == self.state:
            return
        old, self.state = self.state, state
        self.counters[f"state_{state}"] += 1
        emcy = self.node.emcy
        if emcy is None:
            return
        before, after = self._error(old), self._error(state)
        if after is not None:  # raised first: 0x1001 never drops while still in error
            emcy.raise_error(after[0], after[1], after[2], now)
        if before is not None and (after is None or _key(before) != _key(after)):
            emcy.clear_errors([_key(before)], now)

    def overrun(self, kind: str, now: float, *, urgent: bool = False) -> bool:
        """Frames lost: ``rx``, ``tx`` or ``controller``. True when this starts an overrun
        error (none of that code was active)."""
        self.overruns[kind] += 1
        code, register, manufacturer = self.emcys.get(f"{kind}_overrun", (0, 0, b""))
        if not code:
            return False
        key = (code, manufacturer)
        new = key not in self._overrun_since
        self._overrun_since[key] = now
        if self.node.emcy is not None:
            self.node.emcy.raise_error(code, register, manufacturer, now, urgent=urgent)
        return new

    def _error(self, state: str) -> ControllerEmcy | None:
        return self.emcys.get(state) if state != "error-active" else None

    def link(self, problem: str | None, now: float) -> None:
        """The CAN interface is not as configured (``problem``: why; EMCY ``00 81 11 0D``), or is
        now (its error reset)."""
        emcy = self.node.emcy
        self.link_problem = problem
        if emcy is None:
            return
        code, register, manufacturer = LINK_EMCY
        if problem is not None:
            if emcy.raise_error(code, register, manufacturer, now):
                self.counters["link_problems"] += 1
        else:
            emcy.clear_error(code, manufacturer, now)

    # -- timers ---------------------------------------------------------------------------
    def deadline(self) -> float | None:
        if not self._overrun_since:
            return None
        return min(self._overrun_since.values()) + self.quiet_s

    def poll(self, now: float) -> None:
        ended = [k for k, last in self._overrun_since.items() if now >= last + self.quiet_s]
        for key in ended:
            del self._overrun_since[key]
        if ended and self.node.emcy is not None:
            self.node.emcy.clear_errors(ended, now)

    def status(self) -> dict[str, Any]:
        return {
            **self.counters,
            "controller": self.state,
            "overruns": dict(self.overruns),
            "overrun_errors": [f"{c:04X}:{m.hex()}" for c, m in self._overrun_since],
            "link_problem": self.link_problem,
        }
