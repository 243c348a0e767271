"""LSS slave (CiA 305 layer setting services), sans-I/O.

The master talks on 0x7E5, the slave answers on 0x7E4; every LSS frame has 8 data bytes,
byte 0 is the command specifier (cs), 32-bit values are little-endian in bytes 1-4.

Feed requests with :meth:`LssSlave.on_frame` ``(can_id, data, now)``; it returns the frames
to send as ``(can_id, bytes)`` tuples. :meth:`LssSlave.on_timer` and
:meth:`LssSlave.next_deadline` drive the bit-timing switch delay. What the node must do
(reset communication with a new node-ID, change the bit rate) comes out of
:meth:`LssSlave.take_actions`; while a bit-rate switch is in progress
:meth:`LssSlave.transmit_allowed` is False and the node must stay silent.

Node-IDs: ``active_node_id`` is the one in use (0xFF = not configured); "configure
node-ID" sets ``pending_node_id``, which becomes active at the next reset communication
(:meth:`LssSlave.node_id_for_reset`). An unconfigured node that gets a node-ID and is
switched back to the waiting state asks for that reset communication at once.

:class:`LssService` plugs the engine into a :class:`~.node.Node`: the LSS address comes
from the node's 0x1018, node-ID changes go through ``node.set_node_id`` and
``node.reset_communication``, a bit-rate switch through ``node.request_bit_timing``.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import Any

from fieldgate.can.frame import Frame as CanFrame
from fieldgate.persist import CorruptStore, read_json, write_json_atomic

from ..cia301.service import ALL_STATES, NodeHost, Service

log = logging.getLogger("fieldgate.canopen.lss")

REQUEST_ID = 0x7E5
RESPONSE_ID = 0x7E4
UNCONFIGURED = 0xFF


class Cs(IntEnum):
    """LSS command specifiers (CiA 305)."""

    SWITCH_GLOBAL = 0x04
    CONFIGURE_NODE_ID = 0x11
    CONFIGURE_BIT_TIMING = 0x13
    ACTIVATE_BIT_TIMING = 0x15
    STORE_CONFIGURATION = 0x17
    SWITCH_SELECTIVE_VENDOR = 0x40
    SWITCH_SELECTIVE_PRODUCT = 0x41
    SWITCH_SELECTIVE_REVISION = 0x42
    SWITCH_SELECTIVE_SERIAL = 0x43
    SWITCH_SELECTIVE_RESPONSE = 0x44
    IDENTIFY_VENDOR = 0x46
    IDENTIFY_PRODUCT = 0x47
    IDENTIFY_REVISION_LOW = 0x48
    IDENTIFY_REVISION_HIGH = 0x49
    IDENTIFY_SERIAL_LOW = 0x4A
    IDENTIFY_SERIAL_HIGH = 0x4B
    IDENTIFY_NON_CONFIGURED = 0x4C
    IDENTIFY_SLAVE = 0x4F
    IDENTIFY_NON_CONFIGURED_SLAVE = 0x50
    FASTSCAN = 0x51
    INQUIRE_VENDOR = 0x5A
    INQUIRE_PRODUCT = 0x5B
    INQUIRE_REVISION = 0x5C
    INQUIRE_SERIAL = 0x5D
    INQUIRE_NODE_ID = 0x5E


class LssState(IntEnum):
    WAITING = 0
    CONFIGURATION = 1


# Error codes in byte 1 of the configure/store answers.
OK = 0
NODE_ID_OUT_OF_RANGE = 1
BIT_RATE_NOT_SUPPORTED = 1
STORE_NOT_SUPPORTED = 1
STORE_ACCESS_ERROR = 2

FASTSCAN_CONFIRM = 0x80

# Table selector 0 of "configure bit timing": index -> bit/s.
BIT_TIMING_TABLES: dict[str, dict[int, int]] = {
    # CiA 305 standard table (index 9 = auto bit rate, not offered).
    "cia": {
        0: 1_000_000,
        1: 800_000,
        2: 500_000,
        3: 250_000,
        4: 125_000,
        5: 100_000,
        6: 50_000,
        7: 20_000,
        8: 10_000,
    },
    # The I-7232D's own table (seed-000 §2.8): the reverse order, no 100 kbit/s.
    "i7232d": {
        0: 10_000,
        1: 20_000,
        2: 50_000,
        3: 125_000,
        4: 250_000,
        5: 500_000,
        6: 800_000,
        7: 1_000_000,
    },
}

RawFrame = tuple[int, bytes]


@dataclass(frozen=True)
class LssAddress:
    """The 128-bit LSS address: identity object 0x1018 sub 1-4."""

    vendor: int
    product: int
    revision: int
    serial: int

    def part(self, index: int) -> int:
        return (self.vendor, self.product, self.revision, self.serial)[index]


@dataclass(frozen=True)
class ResetCommunication:
    """The node must reset communication now; it comes back with ``node_id``."""

    node_id: int


@dataclass(frozen=True)
class SwitchBitRate:
    """The node must re-open its CAN interface at ``bitrate`` bit/s now."""

    bitrate: int


@dataclass
class StoredLss:
    node_id: int
    bitrate: int | None


class LssStore:
    """The LSS configuration file: node-ID and bit rate, written atomically."""

    FORMAT = "fieldgate-lss/1"

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def load(self) -> StoredLss | None:
        """The stored settings; None when there are none or they are unusable (one log line)."""
        try:
            obj = read_json(self.path)
        except (CorruptStore, OSError) as exc:
            log.warning("LSS store ignored, using the topology's settings: %s", exc)
            return None
        if obj is None:
            return None
        try:
            if not isinstance(obj, dict):
                raise TypeError(f"content: a JSON {type(obj).__name__}, not an object")
            if obj["format"] != self.FORMAT:
                raise ValueError(f"format {obj['format']!r}")
            node_id, bitrate = obj["node_id"], obj["bitrate"]
            if not (isinstance(node_id, int) and (1 <= node_id <= 127 or node_id == UNCONFIGURED)):
                raise ValueError(f"node_id {node_id!r}")
            if bitrate is not None and not (isinstance(bitrate, int) and bitrate > 0):
                raise ValueError(f"bitrate {bitrate!r}")
        except (KeyError, TypeError, ValueError) as exc:
            log.warning(
                "LSS store %s ignored, using the topology's settings: bad %s", self.path, exc
            )
            return None
        return StoredLss(node_id, bitrate)

    def save(self, settings: StoredLss) -> None:
        write_json_atomic(
            self.path,
            {"format": self.FORMAT, "node_id": settings.node_id, "bitrate": settings.bitrate},
        )


def _frame(cs: int, payload: bytes = b"") -> RawFrame:
    return (RESPONSE_ID, bytes([cs]) + payload + bytes(7 - len(payload)))


def _u32(data: bytes) -> int:
    value: int = struct.unpack_from("<I", data, 1)[0]
    return value


@dataclass
class LssCounters:
    received: int = 0
    answered: int = 0
    dropped_malformed: int = 0  # wrong DLC, RTR, unknown cs, invalid fastscan fields
    ignored_in_state: int = 0  # a configuration-only service in the waiting state


@dataclass
class _Sequence:
    """Progress through a multi-frame request (switch selective, identify remote slave)."""

    step: int = 0

    def advance(self, expected_step: int, matches: bool) -> bool:
        """True when this frame continues an unbroken matching sequence."""
        ok = matches and self.step == expected_step
        self.step = expected_step + 1 if ok else 0
        return ok


@dataclass
class LssSlave:
    address: LssAddress
    node_id: int = UNCONFIGURED  # the node-ID the node starts with
    bitrate: int | None = None  # the bit rate in use, if known
    table: str = "cia"
    store: LssStore | None = None
    state: LssState = LssState.WAITING
    counters: LssCounters = field(default_factory=LssCounters)

    def __post_init__(self) -> None:
        if self.table not in BIT_TIMING_TABLES:
            raise ValueError(
                f"unknown bit timing table {self.table!r}; expected one of {sorted(BIT_TIMING_TABLES)}"
            )
        self.active_node_id = self.node_id
        self.pending_node_id = self.node_id
        self.pending_bitrate: int | None = None
        self._selective = _Sequence()
        self._identify = _Sequence()
        self._fastscan_sub = 0
        self._actions: list[ResetCommunication | SwitchBitRate] = []
        self._switch_at: float | None = None  # bit-rate switch pending at this time
        self._silent_until: float | None = None  # no transmission before this time

    @classmethod
    def starting(
        cls,
        address: LssAddress,
        node_id: int = UNCONFIGURED,
        bitrate: int | None = None,
        table: str = "cia",
        store: LssStore | None = None,
    ) -> LssSlave:
        """The slave at power-on: what LSS stored overrides the configured node-ID and bit rate."""
        stored = store.load() if store is not None else None
        if stored is not None:
            node_id = stored.node_id
            bitrate = stored.bitrate if stored.bitrate is not None else bitrate
        return cls(address, node_id=node_id, bitrate=bitrate, table=table, store=store)

    # -- node interface ------------------------------------------------------------------

    @property
    def configured(self) -> bool:
        return self.active_node_id != UNCONFIGURED

    def node_id_for_reset(self) -> int:
        """Called by the node on every reset communication: the pending node-ID takes effect."""
        self.active_node_id = self.pending_node_id
        return self.active_node_id

    def take_actions(self) -> list[ResetCommunication | SwitchBitRate]:
        actions, self._actions = self._actions, []
        return actions

    def transmit_allowed(self, now: float) -> bool:
        return self._silent_until is None or now >= self._silent_until

    def next_deadline(self) -> float | None:
        return self._switch_at if self._switch_at is not None else self._silent_until

    def on_timer(self, now: float) -> list[RawFrame]:
        if self._switch_at is not None and now >= self._switch_at:
            self._switch_at = None
            if self.pending_bitrate is not None:
                self.bitrate = self.pending_bitrate
                self._actions.append(SwitchBitRate(self.bitrate))
        if self._switch_at is None and self._silent_until is not None and now >= self._silent_until:
            self._silent_until = None
        return []

    def status(self) -> dict[str, Any]:
        return {
            "state": self.state.name.lower(),
            "active_node_id": self.active_node_id,
            "pending_node_id": self.pending_node_id,
            "bitrate": self.bitrate,
            "pending_bitrate": self.pending_bitrate,
            **vars(self.counters),
        }

    # -- requests ------------------------------------------------------------------------

    def on_frame(
        self, can_id: int, data: bytes, now: float, *, rtr: bool = False
    ) -> list[RawFrame]:
        """Handle one frame on 0x7E5; anything malformed is counted and dropped."""
        if can_id != REQUEST_ID:
            return []
        self.counters.received += 1
        if rtr or len(data) != 8:
            self.counters.dropped_malformed += 1
            return []
        self.on_timer(now)
        answer = self._dispatch(bytes(data), now)
        if answer is None or not self.transmit_allowed(now):
            return []
        self.counters.answered += 1
        return [answer]

    def _dispatch(self, data: bytes, now: float) -> RawFrame | None:
        cs = data[0]
        handler = self._ANY_STATE.get(cs)
        if handler is not None:
            return handler(self, data, now)
        handler = self._CONFIGURATION_ONLY.get(cs)
        if handler is None:
            self.counters.dropped_malformed += 1
            return None
        if self.state != LssState.CONFIGURATION:
            self.counters.ignored_in_state += 1
            return None
        return handler(self, data, now)

    def _switch_global(self, data: bytes, now: float) -> None:
        mode = data[1]
        if mode not in (LssState.WAITING, LssState.CONFIGURATION):
            self.counters.dropped_malformed += 1
            return None
        leaving_configuration = self.state == LssState.CONFIGURATION and mode == LssState.WAITING
        self.state = LssState(mode)
        self._selective.step = 0
        if leaving_configuration and not self.configured and self.pending_node_id != UNCONFIGURED:
            # CiA 305: a node that had no node-ID starts with the new one right away.
            self._actions.append(ResetCommunication(self.node_id_for_reset()))
        return None

    def _switch_selective(self, data: bytes, now: float) -> RawFrame | None:
        part = data[0] - Cs.SWITCH_SELECTIVE_VENDOR
        if self.state != LssState.WAITING:
            self._selective.step = 0
            return None
        if self._selective.advance(part, _u32(data) == self.address.part(part)) and part == 3:
            self._selective.step = 0
            self.state = LssState.CONFIGURATION
            return _frame(Cs.SWITCH_SELECTIVE_RESPONSE)
        return None

    def _identify_remote(self, data: bytes, now: float) -> RawFrame | None:
        step = data[0] - Cs.IDENTIFY_VENDOR
        value = _u32(data)
        if step < 2:
            matches = value == self.address.part(step)
        elif step in (2, 4):  # low bound of revision / serial
            matches = self.address.part(1 + step // 2) >= value
        else:  # high bound
            matches = self.address.part(1 + step // 2) <= value
        if self._identify.advance(step, matches) and step == 5:
            self._identify.step = 0
            return _frame(Cs.IDENTIFY_SLAVE)
        return None

    def _identify_non_configured(self, data: bytes, now: float) -> RawFrame | None:
        if self.active_node_id == UNCONFIGURED and self.pending_node_id == UNCONFIGURED:
            return _frame(Cs.IDENTIFY_NON_CONFIGURED_SLAVE)
        return None

    def _fastscan(self, data: bytes, now: float) -> RawFrame | None:
        id_number, bit_check, sub, next_sub = struct.unpack_from("<IBBB", data, 1)
        if not (bit_check < 32 or bit_check == FASTSCAN_CONFIRM) or sub > 3 or next_sub > 3:
            self.counters.dropped_malformed += 1
            return None
        # Only unconfigured nodes in the waiting state take part (CiA 305).
        if (
            self.configured
            or self.pending_node_id != UNCONFIGURED
            or self.state != LssState.WAITING
        ):
            return None
        if bit_check == FASTSCAN_CONFIRM:
            self._fastscan_sub = 0
            return _frame(Cs.IDENTIFY_SLAVE)
        if sub != self._fastscan_sub:
            return None
        mask = (0xFFFFFFFF << bit_check) & 0xFFFFFFFF
        if (self.address.part(sub) ^ id_number) & mask:
            return None
        self._fastscan_sub = next_sub
        if bit_check == 0 and next_sub < sub:
            # All 128 bits matched: this node is selected.
            self._fastscan_sub = 0
            self.state = LssState.CONFIGURATION
        return _frame(Cs.IDENTIFY_SLAVE)

    def _configure_node_id(self, data: bytes, now: float) -> RawFrame:
        node_id = data[1]
        if not (1 <= node_id <= 127 or node_id == UNCONFIGURED):
            return _frame(Cs.CONFIGURE_NODE_ID, bytes([NODE_ID_OUT_OF_RANGE]))
        self.pending_node_id = node_id
        return _frame(Cs.CONFIGURE_NODE_ID, bytes([OK]))

    def _configure_bit_timing(self, data: bytes, now: float) -> RawFrame:
        selector, index = data[1], data[2]
        bitrate = BIT_TIMING_TABLES[self.table].get(index) if selector == 0 else None
        if bitrate is None:
            return _frame(Cs.CONFIGURE_BIT_TIMING, bytes([BIT_RATE_NOT_SUPPORTED]))
        self.pending_bitrate = bitrate
        return _frame(Cs.CONFIGURE_BIT_TIMING, bytes([OK]))

    def _activate_bit_timing(self, data: bytes, now: float) -> None:
        delay = struct.unpack_from("<H", data, 1)[0] / 1000.0
        # Stay silent for one delay, switch, stay silent for a second delay (CiA 305).
        self._switch_at = now + delay
        self._silent_until = now + 2 * delay
        self.on_timer(now)
        return None

    def _store_configuration(self, data: bytes, now: float) -> RawFrame:
        if self.store is None:
            return _frame(Cs.STORE_CONFIGURATION, bytes([STORE_NOT_SUPPORTED]))
        bitrate = self.pending_bitrate if self.pending_bitrate is not None else self.bitrate
        try:
            self.store.save(StoredLss(self.pending_node_id, bitrate))
        except OSError as exc:
            log.warning("LSS store configuration failed: %s", exc)
            return _frame(Cs.STORE_CONFIGURATION, bytes([STORE_ACCESS_ERROR]))
        return _frame(Cs.STORE_CONFIGURATION, bytes([OK]))

    def _inquire_address(self, data: bytes, now: float) -> RawFrame:
        value = self.address.part(data[0] - Cs.INQUIRE_VENDOR)
        return _frame(data[0], struct.pack("<I", value))

    def _inquire_node_id(self, data: bytes, now: float) -> RawFrame:
        return _frame(Cs.INQUIRE_NODE_ID, bytes([self.active_node_id]))

    _ANY_STATE = {
        Cs.SWITCH_GLOBAL: _switch_global,
        **dict.fromkeys(
            range(Cs.SWITCH_SELECTIVE_VENDOR, Cs.SWITCH_SELECTIVE_SERIAL + 1), _switch_selective
        ),
        **dict.fromkeys(range(Cs.IDENTIFY_VENDOR, Cs.IDENTIFY_SERIAL_HIGH + 1), _identify_remote),
        Cs.IDENTIFY_NON_CONFIGURED: _identify_non_configured,
        Cs.FASTSCAN: _fastscan,
    }
    _CONFIGURATION_ONLY = {
        Cs.CONFIGURE_NODE_ID: _configure_node_id,
        Cs.CONFIGURE_BIT_TIMING: _configure_bit_timing,
        Cs.ACTIVATE_BIT_TIMING: _activate_bit_timing,
        Cs.STORE_CONFIGURATION: _store_configuration,
        **dict.fromkeys(range(Cs.INQUIRE_VENDOR, Cs.INQUIRE_SERIAL + 1), _inquire_address),
        Cs.INQUIRE_NODE_ID: _inquire_node_id,
    }


class LssService(Service):
    """The LSS slave as a node service (active in every NMT state, and while unconfigured).

    ``store``: where "store configuration" writes (None: store answers "not supported").
    A stored node-ID and bit rate win over the configured ones at power-on; the front reads
    :attr:`bitrate` after ``add_service`` to open its bus.
    """

    name = "lss"
    active_states = ALL_STATES

    def __init__(
        self, *, bitrate: int | None = None, table: str = "cia", store: LssStore | None = None
    ):
        super().__init__()
        self._bitrate, self._table, self._store = bitrate, table, store
        self.slave: LssSlave | None = None

    @property
    def bitrate(self) -> int | None:
        return self.slave.bitrate if self.slave is not None else self._bitrate

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        self.slave = LssSlave.starting(
            self._address(),
            node_id=node.pending_node_id,
            bitrate=self._bitrate,
            table=self._table,
            store=self._store,
        )
        self._sync_pending_node_id()

    def _address(self) -> LssAddress:
        od = self.node.od
        parts = [int(od.get(0x1018, sub)) if (0x1018, sub) in od else 0 for sub in (1, 2, 3, 4)]
        return LssAddress(*parts)

    @property
    def _slave(self) -> LssSlave:
        if self.slave is None:
            raise RuntimeError("the LSS service is not attached to a node")
        return self.slave

    def _sync_pending_node_id(self) -> None:
        if self._slave.pending_node_id != self.node.pending_node_id:
            self.node.set_node_id(self._slave.pending_node_id)

    def listen_ids(self) -> tuple[int, ...]:
        return (REQUEST_ID,)

    def on_frame(self, frame: CanFrame, now: float) -> bool:
        if frame.can_id != REQUEST_ID:
            return False
        for can_id, data in self._slave.on_frame(frame.can_id, frame.data, now, rtr=frame.rtr):
            self.node.send(CanFrame(can_id, data))
        self._sync_pending_node_id()
        self._run_actions(now)
        return True

    def _run_actions(self, now: float) -> None:
        for action in self._slave.take_actions():
            if isinstance(action, ResetCommunication):
                self.node.reset_communication(now)
            else:
                self.node.request_bit_timing(action.bitrate, 0.0)

    def on_reset_communication(self, now: float) -> None:
        # The node took its pending node-ID; identity objects may have been reloaded.
        slave = self._slave
        slave.active_node_id = self.node.node_id
        slave.pending_node_id = self.node.pending_node_id
        slave.address = self._address()

    def deadline(self) -> float | None:
        return self.slave.next_deadline() if self.slave is not None else None

    def poll(self, now: float) -> None:
        self._slave.on_timer(now)
        self._run_actions(now)

    def transmit_allowed(self, now: float) -> bool:
        """False during an activate-bit-timing switch: the node must not transmit (CiA 305)."""
        return self.slave is None or self.slave.transmit_allowed(now)

    def status(self) -> dict[str, Any]:
        return self.slave.status() if self.slave is not None else {}
