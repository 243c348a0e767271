"""What every service of the DeviceNet slave shares: the node's identity on the bus, its owner,
its counters, the time of the current call and the frames the call sends.

:class:`~.engine.DeviceNetSlave` is one (it adds the services); the services
(:mod:`.netaccess`, :mod:`.explicit`, :mod:`.connection_set`, :mod:`.io_messaging`) are
given it as this type, so none of them imports the engine.
"""

from __future__ import annotations

from collections import Counter
from enum import StrEnum

from fieldgate.can.frame import Frame

from . import ids
from .allocation import UNALLOCATED
from .assembly import Assemblies
from .paths import IoPath, resolve
from .settings import BAUD_RATES, Settings


class DeviceState(StrEnum):
    """The node's network state (seed-003 §2.6, §2.7); its value is what the status shows."""

    OFFLINE = "offline"  # powered, not yet checking (before boot)
    DUP_MAC_CHECK = "dup-mac-check"  # two duplicate MAC ID requests, a check period each
    ONLINE = "online"  # nobody answered: the node serves the network
    COMM_FAULT = (
        "comm-fault"  # another node has this MAC: silent but for the Offline Connection Set
    )


# Where each state may go: anything else is a bug of the engine, never the network's doing.
TRANSITIONS: dict[DeviceState, frozenset[DeviceState]] = {
    DeviceState.OFFLINE: frozenset({DeviceState.DUP_MAC_CHECK}),  # boot: the check starts
    DeviceState.DUP_MAC_CHECK: frozenset(
        {
            DeviceState.DUP_MAC_CHECK,  # a delayed check starts (after a bit-rate switch)
            DeviceState.ONLINE,  # two check periods without an answer
            DeviceState.COMM_FAULT,  # another node answered or checks the same MAC
        }
    ),
    DeviceState.ONLINE: frozenset({DeviceState.DUP_MAC_CHECK}),  # a restart: reset, MAC, baud
    DeviceState.COMM_FAULT: frozenset({DeviceState.DUP_MAC_CHECK}),  # a new MAC (Offline Set)
}
DEVICE_STATES = tuple(DeviceState)
ACK_TIMER_MS, ACK_RETRY_LIMIT = 16, 1  # Acknowledge Handler defaults (class 0x2B)


class SlaveState:
    def __init__(self, settings: Settings, assemblies: Assemblies):
        self.settings = settings
        self.assemblies = assemblies
        self.paths: dict[str, IoPath] = resolve(assemblies, settings.io_paths)  # ValueError
        self.ack_timer_ms = ACK_TIMER_MS
        self.ack_retry_limit = ACK_RETRY_LIMIT
        self.mac_id = settings.mac_id
        self.baud_code = settings.baud_code
        self.pending_baud_code: int | None = None
        self.state = DeviceState.OFFLINE
        self.counters: Counter[str] = Counter()
        self.master_mac = UNALLOCATED
        self.allocation_choice = 0
        self.now = 0.0  # the time of the call being served
        self._out: list[Frame] = []

    @property
    def bitrate(self) -> int:
        return BAUD_RATES[self.baud_code]

    @property
    def online(self) -> bool:
        return self.state is DeviceState.ONLINE

    def move_to(self, state: DeviceState) -> None:
        """Change the network state along :data:`TRANSITIONS` (ValueError otherwise: a bug)."""
        if state not in TRANSITIONS[self.state]:
            raise ValueError(f"DeviceNet state {self.state} cannot go to {state}")
        self.state = state

    def send(self, can_id: int, data: bytes) -> None:
        self._out.append(Frame(can_id, bytes(data)))

    def send_explicit(self, data: bytes) -> None:
        """On Group 2 message 3 of this node: explicit responses, heartbeat, shutdown."""
        self.send(ids.group2_id(self.mac_id, ids.G2_EXPLICIT_RESPONSE), data)

    def take_frames(self) -> list[Frame]:
        out, self._out = self._out, []
        return out
