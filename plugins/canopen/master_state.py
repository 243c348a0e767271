"""The one owner of a canopen front's "master lost" fact, as ``context.masters`` hears it.

Two things can say that the master is gone:

* error control's monitoring (life guarding, heartbeat consumer, bus-off, or not heard
  since the front restarted), told through ``node.on_master``;
* NMT Stopped, when ``stopped_is_error`` (the NA-9161's "Stopped is an error",
  ``error_on_stopped``), seen through ``node.on_nmt``.

The master is lost while either says so; ``masters.lost`` (which drives the outputs
to their error values) and ``masters.ok`` are called on each change of that
combination only, so leaving Stopped while guarding is still lost, or guarding
resuming while the node is still Stopped, reports nothing.

After a front restart (a fresh node, ``masters`` still saying lost from before), the
master stays lost until it is heard: at the node's first boot-up error control is
told :meth:`~.errctl.ErrorControl.assume_master_lost` (docs/canopen.md, "After a
front restart").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from .cia301.nmt import NmtState
from .cia301.service import NodeHost

RESTART_REASON = "master not heard since the front restarted"


class MasterState:
    def __init__(
        self,
        masters: Any,
        front: str,
        outputs: Iterable[str] | Callable[[], Iterable[str]],
        *,
        stopped_is_error: bool = False,
    ):
        self.masters = masters  # fieldgate.masters.MasterMonitor (lost / ok / is_ok)
        self.front = front
        self._outputs = outputs
        self.stopped_is_error = stopped_is_error
        self.monitoring_lost = False  # error control says lost
        self.stopped = False  # NMT Stopped, counted only when stopped_is_error
        self.lost = False  # as last told to masters
        self.losses = 0
        self.reason = ""
        self._booted = False
        self.node: NodeHost | None = None

    def attach(self, node: NodeHost) -> None:
        self.node = node
        node.on_master(self._monitoring)
        node.on_nmt(self._nmt)

    @property
    def outputs(self) -> list[str]:
        return list(self._outputs() if callable(self._outputs) else self._outputs)

    # -- the two sources ------------------------------------------------------------------
    def _monitoring(self, ok: bool, reason: str) -> None:
        self.monitoring_lost = not ok
        self._update(reason)

    def _nmt(self, old: NmtState, new: NmtState) -> None:
        if old is NmtState.INITIALISING and new is not NmtState.INITIALISING and not self._booted:
            self._booted = True
            self._restarted()
        self._update(
            "NMT Stopped"
            if new is NmtState.STOPPED
            else ("reset communication" if new is NmtState.INITIALISING else "left NMT Stopped")
        )

    def _restarted(self) -> None:
        """The node's first boot-up: a master lost before this node existed stays lost until heard."""
        if self.masters.is_ok(self.front):
            return
        if self.node is None:
            return
        try:
            errctl = self.node.service("error_control")
        except KeyError:
            return
        errctl.assume_master_lost(RESTART_REASON)

    # -- the one report -------------------------------------------------------------------
    def _update(self, reason: str) -> None:
        # the node's state, not the last NMT notification: error control reports from inside a
        # state change, before this owner's NMT listener hears of it
        self.stopped = (
            self.stopped_is_error and self.node is not None and self.node.state is NmtState.STOPPED
        )
        lost = self.monitoring_lost or self.stopped
        if lost == self.lost:
            return
        self.lost, self.reason = lost, reason
        if lost:
            self.losses += 1
            self.masters.lost(self.front, reason, self.outputs)
        else:
            self.masters.ok(self.front, reason)

    def status(self) -> dict[str, Any]:
        return {
            "lost": self.lost,
            "reason": self.reason,
            "monitoring_lost": self.monitoring_lost,
            "stopped_error": self.stopped,
            "losses": self.losses,
        }
