"""A fake kernel for the CAN interface logic on the host (no SocketCAN here): what
:class:`fieldgate.can.interface.LinkOps` calls, answered from one interface's state.

It compares with core's own :func:`fieldgate.can.link.plan`, so "what differs" is decided as on
a real kernel; the real drivers are exercised in the SocketCAN stage's QEMU guest
(tests/socketcan/test_socketcan_can_gateway.py).
"""

from __future__ import annotations

import errno

from fieldgate.can import link as canlink
from fieldgate.can.interface import LinkOps
from fieldgate.can.link import Applied, LinkError, LinkSettings
from fieldgate.can.rtnetlink import RawLink


class FakeKernel:
    """One CAN controller: its bit rate, restart-ms, state; ``refuse`` makes every change fail
    as without CAP_NET_ADMIN; ``restart_ms_unsupported`` as slcan."""

    def __init__(self, bitrate: int | None = 250_000, restart_ms: int = 0, kind: str = "can"):
        self.bitrate, self.restart_ms, self.kind = bitrate, restart_ms, kind
        self.sample_point: float | None = 0.875 if bitrate else None
        self.state, self.up = "error-active", True
        self.refuse = False
        self.restart_ms_unsupported = False
        self.calls: list[tuple[str, object]] = []
        self.bus_off_count = self.restarts = 0

    def read_link(self, name: str) -> RawLink:
        return RawLink(
            name=name,
            index=3,
            up=self.up,
            kind=self.kind,
            bitrate=self.bitrate,
            sample_point=self.sample_point,
            state=self.state if self.up else "stopped",
            listen_only=False,
            restart_ms=self.restart_ms,
            tx_errors=0,
            rx_errors=0,
            counters={"bus_off": self.bus_off_count, "restarts": self.restarts},
        )

    def apply_settings(self, name: str, wanted: LinkSettings) -> Applied:
        self.calls.append(("apply", wanted))
        steps = canlink.plan(self.read_link(name), wanted)
        if steps.impossible:
            raise LinkError(steps.impossible)
        if steps.change is not None:
            if self.refuse:
                raise LinkError(
                    f"{name}: {'; '.join(steps.differences)}: changing the interface needs the "
                    "capability CAP_NET_ADMIN (run as root, or grant it: "
                    "AmbientCapabilities=CAP_NET_ADMIN, docs/deploy.md)",
                    errno.EPERM,
                )
            if steps.change.restart_ms is not None and self.restart_ms_unsupported:
                raise LinkError(f"{name}: restart-ms: not supported", errno.EOPNOTSUPP)
            if steps.change.bitrate is not None:
                self.bitrate = steps.change.bitrate
                self.sample_point = steps.change.sample_point or 0.875
            if steps.change.restart_ms is not None:
                self.restart_ms = steps.change.restart_ms
        self.up = True
        return Applied(self.read_link(name), steps.differences, steps.note)

    def restart(self, name: str) -> str:
        self.calls.append(("restart", name))
        if self.refuse:
            raise LinkError(f"{name}: restarting the controller needs CAP_NET_ADMIN", errno.EPERM)
        if self.state != "bus-off":
            raise LinkError(f"{name}: not restarted: the controller is not bus-off", errno.EBUSY)
        self.state = "error-active"
        self.restarts += 1
        return "restart"

    def go_bus_off(self) -> None:
        self.state = "bus-off"
        self.bus_off_count += 1

    @property
    def ops(self) -> LinkOps:
        return LinkOps(self.read_link, self.apply_settings, self.restart)

    def applied_rates(self) -> list[int]:
        return [w.bitrate for kind, w in self.calls if kind == "apply"]  # type: ignore[union-attr]
