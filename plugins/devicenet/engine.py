"""The sans-I/O DeviceNet Group 2 Only slave: fed ``(frame, now)``, returns frames to send.

Life cycle: :meth:`boot` starts the duplicate MAC ID check (two requests one second
apart, online one second after the second unless another node answered or checked the
same MAC: then *communication fault*, silent until restarted). Online, the slave serves
the Group 2 Only unconnected port (Allocate/Release only), the explicit connection
(Get/Set_Attribute_Single, Identity Reset, fragmented both ways), and the I/O
connections: poll, bit-strobe, change-of-state / cyclic.

The adapter calls :meth:`receive`, :meth:`tick` at :meth:`next_deadline`, and
:meth:`flush` after calling anything else (:meth:`inputs_changed`). The front hears of
master loss / return through :meth:`on_master` and of a duplicate MAC through
:meth:`on_fault`. Bad frames are counted in :attr:`counters`, never raised.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from typing import Any

from fieldgate.can.frame import Frame
from fieldgate.host_watchdog import HostWatchdogs

from . import cip, ids
from .allocation import BIT_ACK_SUPPRESS, BIT_COS, CONNECTION_BITS, UNALLOCATED, Allocation
from .application import ApplicationObject, module_views
from .assembly import Assemblies, Assembly
from .cip import CipError
from .connection import COS_CYCLIC, EXPLICIT, POLL, STROBE, Connection, State, TimeoutAction
from .fragment import ACK, ACK_OK, ACK_TOO_MUCH, EXPLICIT_CHUNK, Reassembler, io_frames, split
from .objects import AssemblyObject, ConnectionObject, DeviceNetObject, IdentityObject, u16
from .settings import BAUD_RATES, Settings

log = logging.getLogger("fieldgate.devicenet")

BIT_RATE_SWITCH_S = 0.01  # after a baud change at Reset: the adapter reopens the bus (at once) before the first duplicate MAC request
FRAGMENT_ACK_TIMEOUT_S = 1.0
FRAGMENT_RETRIES = 2
SHUTDOWN_CODE = 0x0004
EXPLICIT_MIN_SIZE = 0x20


class OutgoingFragments:
    """An explicit response longer than 8 bytes, sent one acknowledged fragment at a time."""

    def __init__(self, header: int, payload: bytes, now: float):
        self.header = header
        self.pieces = split(payload, EXPLICIT_CHUNK)
        self.index = 0
        self.retries = 0
        self.deadline = now + FRAGMENT_ACK_TIMEOUT_S

    def current(self) -> bytes:
        frag, data = self.pieces[self.index]
        return bytes([self.header | 0x80, frag]) + data


class DeviceNetSlave:
    def __init__(self, settings: Settings, assemblies: Assemblies):
        self.settings = settings
        self.assemblies = assemblies
        self.mac_id = settings.mac_id
        self.baud_code = settings.baud_code
        self.pending_baud_code: int | None = None
        self.state = "offline"
        self.counters: Counter[str] = Counter()
        self.master_mac = UNALLOCATED
        self.allocation_choice = 0
        self.bus_off_interrupt = 0
        self.bus_off_count = 0
        self.heartbeat_s = 0
        self.module_fault = False
        self.fault_reason = ""
        self.connections = {i: Connection(i) for i in (EXPLICIT, POLL, STROBE, COS_CYCLIC)}
        self.allocation = Allocation(self)
        self.module_errors: Callable[[str, int], int] = lambda back, address: (
            0
        )  # the front reads module health
        self.host_watchdogs = (
            HostWatchdogs()
        )  # the front gives the gateway's (Application attributes 0x08-0x0B)
        application = ApplicationObject(
            self,
            module_views(assemblies.channels),
            lambda back, address: self.module_errors(back, address),
        )
        self.objects = {
            o.class_id: o
            for o in (
                IdentityObject(self),
                DeviceNetObject(self),
                AssemblyObject(self),
                ConnectionObject(self),
                application,
            )
        }
        explicit_size = max(
            EXPLICIT_MIN_SIZE, max((a.size for a in assemblies.instances.values()), default=0) + 4
        )
        self.explicit_in = Reassembler(explicit_size)
        self.explicit_size = explicit_size
        self.io_in = Reassembler(assemblies.consumed_size)
        self.outgoing: OutgoingFragments | None = None
        self._out: list[Frame] = []
        self._dup_step = 0
        self._dup_at: float | None = None
        self._heartbeat_at: float | None = None
        self._produce_at: float | None = None
        self._last_produced = float("-inf")
        self._restart: int | None = None
        self._master_ok = True
        self._master_listeners: list[Callable[[bool, str], None]] = []
        self._fault_listeners: list[Callable[[str], None]] = []
        self._bit_timing: Callable[[int, float], None] | None = None
        self._settings_listeners: list[Callable[[int, int], None]] = []
        self.deadline_after_call: float | None = None
        self._now = 0.0
        self._new_mac: int | None = None
        self._listen: frozenset[int] = frozenset()
        self._listen_key: tuple[int, int] | None = None

    # -- listeners ------------------------------------------------------------------------
    def on_master(self, listener: Callable[[bool, str], None]) -> None:
        self._master_listeners.append(listener)

    def on_fault(self, listener: Callable[[str], None]) -> None:
        self._fault_listeners.append(listener)

    def on_settings(self, listener: Callable[[int, int], None]) -> None:
        """``listener(mac_id, baud_code)`` when either is changed over the network (to be stored)."""
        self._settings_listeners.append(listener)

    def settings_changed(self) -> None:
        mac = self.mac_id if self._new_mac is None else self._new_mac
        baud = self.baud_code if self.pending_baud_code is None else self.pending_baud_code
        for listener in list(self._settings_listeners):
            listener(mac, baud)

    def on_bit_timing(self, listener: Callable[[int, float], None]) -> None:
        self._bit_timing = listener

    @property
    def bitrate(self) -> int:
        return BAUD_RATES[self.baud_code]

    # -- adapter interface ----------------------------------------------------------------
    def boot(self, now: float) -> list[Frame]:
        """Start (or restart) with the duplicate MAC ID check."""
        self._start_dup_check(now)
        return self._done()

    def _start_dup_check(self, now: float, delay: float = 0.0) -> None:
        """Send the first duplicate MAC ID request now, or after ``delay`` (step 0 until then)."""
        self._now = now
        self.state = "dup-mac-check"
        if delay > 0:
            self._dup_step, self._dup_at = 0, now + delay
            return
        self._dup_step = 1
        self._dup_at = now + self.settings.dup_mac_interval_s
        self._send_dup_mac(response=False)

    def receive(self, frame: Frame, now: float) -> list[Frame]:
        self._now = now
        try:
            self._dispatch(frame, now)
            if self.state == "online" and self._produce_at is not None and now >= self._produce_at:
                self._produce(
                    now
                )  # a connection just established produces at once, after its response
        except Exception:  # never let a frame stop the gateway; count it (and show the first)
            self.counters["rx_internal_errors"] += 1
            if self.counters["rx_internal_errors"] == 1:
                log.exception("DeviceNet frame %s not handled", frame)
        return self._done()

    def tick(self, now: float) -> list[Frame]:
        self._now = now
        if self._dup_at is not None and now >= self._dup_at:
            self._dup_mac_step(now)
        if self.state == "online":
            self._check_watchdogs(now)
            self._check_fragments(now)
            if self._heartbeat_at is not None and now >= self._heartbeat_at:
                self._send_heartbeat()
                self._heartbeat_at = now + self.heartbeat_s
            if self._produce_at is not None and now >= self._produce_at:
                self._produce(now)
        return self._done()

    def flush(self) -> list[Frame]:
        return self._done()

    def listen_ids(self) -> frozenset[int]:
        """The CAN-IDs this slave takes frames on (the adapter's acceptance filters).

        Group 2 for its MAC ID (all eight message IDs: requests, poll, duplicate MAC ID
        check, ...), the allocated master's bit-strobe, and the Group 4 Offline Connection
        Set (0x7EC-0x7EF). The same object while the MAC ID and the master are unchanged.
        """
        key = (self.mac_id, self.master_mac)
        if key != self._listen_key:
            wanted = {ids.group2_id(self.mac_id, message) for message in range(8)}
            if self.master_mac != UNALLOCATED:
                wanted.add(ids.group2_id(self.master_mac, ids.G2_STROBE))
            wanted.update(ids.group4_id(message) for message in range(0x2C, 0x30))
            self._listen, self._listen_key = frozenset(wanted), key
        return self._listen

    def next_deadline(self) -> float | None:
        times = [self._dup_at, self._heartbeat_at, self._produce_at]
        times += [c.watchdog_at for c in self.connections.values()]
        if self.outgoing is not None:
            times.append(self.outgoing.deadline)
        due = [t for t in times if t is not None]
        return min(due) if due else None

    def _done(self) -> list[Frame]:
        out, self._out = self._out, []
        self.deadline_after_call = self.next_deadline()
        return out

    def _send(self, can_id: int, data: bytes) -> None:
        self._out.append(Frame(can_id, bytes(data)))

    def _send_explicit(self, data: bytes) -> None:
        self._send(ids.group2_id(self.mac_id, ids.G2_EXPLICIT_RESPONSE), data)

    # -- duplicate MAC ID check ---------------------------------------------------------------
    def _dup_mac_payload(self, response: bool) -> bytes:
        return (
            bytes([0x80 if response else 0x00])
            + u16(self.settings.vendor_id)
            + self.settings.serial.to_bytes(4, "little")
        )

    def _send_dup_mac(self, response: bool) -> None:
        self._send(ids.group2_id(self.mac_id, ids.G2_DUP_MAC), self._dup_mac_payload(response))

    def _dup_mac_step(self, now: float) -> None:
        if self._dup_step == 0:  # a delayed start (after a bit-rate switch)
            self._start_dup_check(now)
        elif self._dup_step == 1:
            self._dup_step = 2
            self._dup_at = now + self.settings.dup_mac_interval_s
            self._send_dup_mac(response=False)
        else:
            self._dup_step, self._dup_at = 0, None
            self.state = "online"
            if self.heartbeat_s:
                self._heartbeat_at = now + self.heartbeat_s

    def _dup_mac_frame(self, data: bytes) -> None:
        if len(data) != 7:
            self.counters["rx_malformed"] += 1
            return
        response = bool(data[0] & 0x80)
        if self.state == "dup-mac-check":
            self._enter_fault(
                f"duplicate MAC ID {self.mac_id}: another node {'answered our check' if response else 'checks the same MAC'} (vendor {int.from_bytes(data[1:3], 'little')}, serial {int.from_bytes(data[3:7], 'little')})"
            )
        elif self.state == "online" and not response:
            self.counters["dup_mac_checks_answered"] += 1
            self._send_dup_mac(response=True)
        else:
            self.counters["dup_mac_responses_ignored"] += 1

    def _offline_request(self, data: bytes, now: float) -> None:
        """Offline Connection Set (seed-003 §2.7): identify faulted nodes, or give one a new MAC ID."""
        if (
            len(data) >= 2 and data[1] == cip.ALLOCATE and not data[0] & 0x40
        ):  # identify, match bit clear
            self._send(
                ids.group4_id(ids.G4_FAULTED_RESPONSE), self._dup_mac_payload(response=False)
            )
        elif (
            len(data) == 8
            and data[1] == cip.HEARTBEAT
            and data[2:] == self._dup_mac_payload(False)[1:]
            and data[0] <= 63
        ):
            self.counters["offline_mac_changes"] += 1
            self.mac_id, self.fault_reason = data[0], ""
            self.settings_changed()
            self._start_dup_check(now)
        else:
            self.counters["rx_offline_ignored"] += 1

    def _enter_fault(self, reason: str) -> None:
        self.state, self.fault_reason = "comm-fault", reason
        self._dup_at = self._heartbeat_at = self._produce_at = None
        self.counters["dup_mac_faults"] += 1
        for listener in list(self._fault_listeners):
            listener(reason)

    # -- dispatch -----------------------------------------------------------------------------
    def _dispatch(self, frame: Frame, now: float) -> None:
        if frame.rtr:
            self.counters["rx_rtr_ignored"] += 1
            return
        group, message, mac = ids.decode(frame.can_id)
        if group == 4 and message == ids.G4_FAULTED_REQUEST:
            if self.state == "comm-fault":
                self._offline_request(frame.data, now)
            else:  # for faulted nodes only: counted, so a busy offline set shows in the status
                self.counters["rx_offline_not_faulted"] += 1
            return
        if group != 2:
            return  # group 1/3 traffic and other group 4 messages are for other nodes
        data = frame.data
        if mac == self.mac_id and message == ids.G2_DUP_MAC:
            self._dup_mac_frame(data)
            return
        if self.state != "online":
            if mac == self.mac_id:
                self.counters["rx_while_" + self.state] += 1
            return
        if message == ids.G2_STROBE and mac == self.master_mac:
            self._strobe(data, now)
        elif mac != self.mac_id:
            return
        elif message == ids.G2_UNCONNECTED_REQUEST:
            self._unconnected(data, now)
        elif message == ids.G2_EXPLICIT_REQUEST:
            self._explicit(data, now)
        elif message == ids.G2_POLL:
            self._poll(data, now)
        elif message == ids.G2_COS_ACK:
            self._cos_ack(now)
        else:
            self.counters["rx_unexpected"] += 1

    # -- explicit messaging -----------------------------------------------------------------
    def _unconnected(self, data: bytes, now: float) -> None:
        if len(data) < 2 or data[0] & 0x80 or data[1] & cip.RESPONSE:
            self.counters["rx_malformed"] += 1
            return
        header, service = data[0] & 0x7F, data[1]
        try:
            if service not in (cip.ALLOCATE, cip.RELEASE):
                raise CipError(cip.RESOURCE_UNAVAILABLE, cip.INVALID_UNCONNECTED_REQUEST)
            if len(data) < 4:
                raise CipError(cip.NOT_ENOUGH_DATA)
            if data[2] != DeviceNetObject.class_id or data[3] != 1:
                raise CipError(cip.OBJECT_DOES_NOT_EXIST)
            reply = bytes([header, service | cip.RESPONSE]) + self.allocation.handle(
                service, data[4:], now
            )
        except CipError as err:
            reply = self._error(header, err)
        self._send_explicit(reply)

    def _error(self, header: int, err: CipError) -> bytes:
        self.counters["cip_errors"] += 1
        return bytes([header, cip.ERROR_RESPONSE | cip.RESPONSE, err.general, err.additional])

    def _explicit(self, data: bytes, now: float) -> None:
        connection = self.connections[EXPLICIT]
        if not connection.established:
            self.counters["rx_explicit_without_connection"] += 1
            return
        if len(data) < 2:
            self.counters["rx_malformed"] += 1
            return
        connection.kick(now)
        header = data[0] & 0x7F
        if not data[0] & 0x80:
            self.outgoing = None  # a new request abandons an unacknowledged response
            self._request(header, data[1:], now)
            return
        frag = data[1]
        if frag & 0xC0 == ACK:
            self._fragment_ack(frag, data[2:3], now)
            return
        outcome, payload = self.explicit_in.feed(frag, data[2:])
        if outcome == "dropped":
            self.counters["rx_fragments_dropped"] += 1
            return
        status = ACK_TOO_MUCH if outcome == "overflow" else ACK_OK
        self._send_explicit(bytes([header | 0x80, ACK | (frag & 0x3F), status]))
        if payload is not None:
            self.outgoing = None
            self._request(header, payload, now)

    def _request(self, header: int, body: bytes, now: float) -> None:
        if not body or body[0] & cip.RESPONSE:
            self.counters["rx_malformed"] += 1
            return
        service = body[0]
        try:
            reply = self._serve(service, body[1:], now)
        except CipError as err:
            self._respond(header, self._error(header, err)[1:], now)
        else:
            self._respond(header, bytes([service | cip.RESPONSE]) + reply, now)
        if self._restart is not None:
            class_id, self._restart = self._restart, None
            self._restart_device(class_id, header, now)

    def _serve(self, service: int, path_and_data: bytes, now: float) -> bytes:
        if len(path_and_data) < 2:
            raise CipError(cip.NOT_ENOUGH_DATA)
        class_id, instance, rest = path_and_data[0], path_and_data[1], path_and_data[2:]
        obj = self.objects.get(class_id)
        if obj is None:
            raise CipError(cip.OBJECT_DOES_NOT_EXIST)
        if service in (cip.GET_ATTRIBUTE_SINGLE, cip.SET_ATTRIBUTE_SINGLE):
            if not rest:
                raise CipError(cip.NOT_ENOUGH_DATA)
            attribute = obj.attribute(instance, rest[0])
            if service == cip.GET_ATTRIBUTE_SINGLE:
                if len(rest) > 1:
                    raise CipError(cip.TOO_MUCH_DATA)
                if attribute.get is None:
                    raise CipError(cip.ATTRIBUTE_NOT_GETTABLE)
                return attribute.get()
            if attribute.set is None:
                raise CipError(cip.ATTRIBUTE_NOT_SETTABLE)
            return attribute.set(rest[1:])
        return obj.service(service, instance, rest, now)

    def _respond(self, header: int, payload: bytes, now: float) -> None:
        if len(payload) <= 7:
            self._send_explicit(bytes([header]) + payload)
            return
        self.outgoing = OutgoingFragments(header, payload, now)
        self.counters["tx_fragmented_responses"] += 1
        self._send_explicit(self.outgoing.current())

    def _fragment_ack(self, frag: int, status: bytes, now: float) -> None:
        out = self.outgoing
        if out is None or (frag & 0x3F) != out.pieces[out.index][0] & 0x3F:
            self.counters["rx_unexpected_acks"] += 1
            return
        if status and status[0] != ACK_OK:
            self.counters["tx_fragments_refused"] += 1
            self.outgoing = None
            return
        out.index += 1
        if out.index == len(out.pieces):
            self.outgoing = None
            return
        out.retries, out.deadline = 0, now + FRAGMENT_ACK_TIMEOUT_S
        self._send_explicit(out.current())

    def _check_fragments(self, now: float) -> None:
        out = self.outgoing
        if out is None or now < out.deadline:
            return
        if out.retries >= FRAGMENT_RETRIES:
            self.counters["tx_fragments_abandoned"] += 1
            self.outgoing = None
            return
        out.retries += 1
        out.deadline = now + FRAGMENT_ACK_TIMEOUT_S
        self._send_explicit(out.current())

    # -- objects' callbacks -----------------------------------------------------------------------
    @property
    def identity_status(self) -> int:
        return (0x0001 if self.allocation_choice else 0) | (0x0100 if self.module_fault else 0)

    def set_heartbeat(self, seconds: int) -> None:
        self.heartbeat_s = seconds
        self._heartbeat_at = self._now + seconds if seconds else None

    def _send_heartbeat(self) -> None:
        header = self.master_mac if self.master_mac != UNALLOCATED else self.mac_id
        self._send_explicit(
            bytes([header, cip.HEARTBEAT | cip.RESPONSE, 0x01, 0x00, 0x03, 0x00, 0x00, 0x00])
        )

    def schedule_restart(self, class_id: int) -> None:
        self._restart = class_id

    def change_mac(self, mac: int) -> None:
        self._new_mac = mac
        self._restart = DeviceNetObject.class_id
        self.settings_changed()

    def _restart_device(self, class_id: int, header: int, now: float) -> None:
        """Device Shutdown from the current MAC, connections gone, dup-MAC check at the new MAC/baud."""
        shutdown_header = self.master_mac if self.master_mac != UNALLOCATED else header
        self._send_explicit(
            bytes([shutdown_header, cip.SHUTDOWN | cip.RESPONSE])
            + u16(class_id)
            + u16(1)
            + u16(SHUTDOWN_CODE)
        )
        for instance in self.connections:
            self.close_connection(instance, "device reset")
        self.master_mac, self.allocation_choice = UNALLOCATED, 0
        if self._new_mac is not None:
            self.mac_id, self._new_mac = self._new_mac, None
        self._heartbeat_at = None
        delay = 0.0
        if self.pending_baud_code is not None and self.pending_baud_code != self.baud_code:
            self.baud_code = self.pending_baud_code
            if self._bit_timing is not None:
                self._bit_timing(self.bitrate, 0.0)
                delay = BIT_RATE_SWITCH_S  # the shutdown answer leaves at the old rate, the check at the new
        self.pending_baud_code = None
        self._start_dup_check(now, delay)

    def write_assembly(self, assembly: Assembly, data: bytes) -> None:
        assembly.write(self.assemblies.image, data, self.assemblies.origin)

    def set_epr(self, connection: Connection, ms: int) -> int:
        now = self._now
        granted = connection.set_epr(ms, now)
        if connection.instance == COS_CYCLIC and connection.established:
            self._produce_at = now if granted else None
        return granted

    # -- connections --------------------------------------------------------------------------
    def open_connection(self, instance: int, now: float) -> None:
        c = self.connections[instance]
        m, master = self.mac_id, self.master_mac
        c.open(now)
        produced, consumed = self.assemblies.produced_size, self.assemblies.consumed_size
        if instance == EXPLICIT:
            c.produced_id, c.consumed_id = (
                ids.group2_id(m, ids.G2_EXPLICIT_RESPONSE),
                ids.group2_id(m, ids.G2_EXPLICIT_REQUEST),
            )
            c.produced_size = c.consumed_size = self.explicit_size
            c.transport, c.comm_characteristics = 0x83, 0x21
        elif instance == POLL:
            c.produced_id, c.consumed_id = (
                ids.group1_id(ids.G1_POLL_RESPONSE, m),
                ids.group2_id(m, ids.G2_POLL),
            )
            c.produced_size, c.consumed_size = produced, consumed
            c.transport, c.comm_characteristics = 0x82, 0x01
        elif instance == STROBE:
            c.produced_id, c.consumed_id = (
                ids.group1_id(ids.G1_STROBE_RESPONSE, m),
                ids.group2_id(master, ids.G2_STROBE),
            )
            c.produced_size, c.consumed_size = min(produced, 8), 8
            c.transport, c.comm_characteristics = 0x82, 0x02
        else:
            c.acked = not self.allocation_choice & BIT_ACK_SUPPRESS
            c.produced_id = ids.group1_id(ids.G1_COS_CYCLIC, m)
            c.consumed_id = ids.group2_id(m, ids.G2_COS_ACK) if c.acked else 0xFFFF
            c.produced_size, c.consumed_size = produced, 0
            c.transport = (0x10 if self.allocation_choice & BIT_COS else 0x00) | (
                0x02 if c.acked else 0x00
            )
            c.comm_characteristics = 0x01 if c.acked else 0x0F
            c.inhibit_ms = 0
        self.io_in.reset()

    def close_connection(self, instance: int, reason: str) -> None:
        c = self.connections[instance]
        was_running = c.is_io and c.state is State.ESTABLISHED
        c.close()
        if (
            instance == EXPLICIT and self.outgoing is not None
        ):  # a fragmented answer dies with its connection
            self.counters["tx_fragments_dropped"] += 1
            self.outgoing = None
        bits = dict(CONNECTION_BITS)[instance]
        self.allocation_choice &= ~bits
        if instance == COS_CYCLIC:
            self.allocation_choice &= ~BIT_ACK_SUPPRESS
            self._produce_at = None
        if not any(conn.exists for conn in self.connections.values()):
            self.master_mac, self.allocation_choice = UNALLOCATED, 0
        if was_running:
            self._master_lost(f"{_NAMES[instance]} {reason}")

    def _check_watchdogs(self, now: float) -> None:
        for c in self.connections.values():
            if not c.expired(now):
                continue
            self.counters[f"{_NAMES[c.instance]}_timeouts"] += 1
            if c.action is TimeoutAction.AUTO_DELETE or not c.is_io:
                self.close_connection(c.instance, "timed out (deleted)")
            else:
                c.state, c.watchdog_at = State.TIMED_OUT, None
                if c.instance == COS_CYCLIC:
                    self._produce_at = None
                self._master_lost(f"{_NAMES[c.instance]} connection timed out ({c.epr_ms} ms x 4)")

    def _master_lost(self, reason: str) -> None:
        if not self._master_ok:
            return
        self._master_ok = False
        for listener in list(self._master_listeners):
            listener(False, reason)

    def master_back(self, reason: str) -> None:
        if self._master_ok:
            return
        self._master_ok = True
        for listener in list(self._master_listeners):
            listener(True, reason)

    # -- I/O ----------------------------------------------------------------------------------
    def _io_send(self, message: int, payload: bytes) -> None:
        for data in io_frames(payload):
            self._send(ids.group1_id(message, self.mac_id), data)

    def _poll(self, data: bytes, now: float) -> None:
        c = self.connections[POLL]
        if not c.established:
            self.counters["rx_poll_without_connection"] += 1
            return
        size = c.consumed_size
        if size > 8 and data:
            outcome, payload = self.io_in.feed(data[0], data[1:])
            if outcome == "dropped" or outcome == "overflow":
                self.counters["rx_io_fragments_dropped"] += 1
                return
            if payload is None:
                return
            data = payload
        if len(data) not in (0, size):
            self.counters["rx_poll_wrong_size"] += 1
            return
        c.kick(now)
        if data:  # zero-length poll = idle: outputs keep their values
            self.assemblies.consume(data)
            self.counters["rx_poll_outputs"] += 1
        else:
            self.counters["rx_poll_idle"] += 1
        self._io_send(ids.G1_POLL_RESPONSE, self.assemblies.produced())

    def _strobe(self, data: bytes, now: float) -> None:
        c = self.connections[STROBE]
        if not c.established:
            return
        if len(data) != 8:
            self.counters["rx_strobe_wrong_size"] += 1
            return
        c.kick(now)
        self._send(
            ids.group1_id(ids.G1_STROBE_RESPONSE, self.mac_id), self.assemblies.produced()[:8]
        )

    def _cos_ack(self, now: float) -> None:
        c = self.connections[COS_CYCLIC]
        if c.established and c.acked:
            c.kick(now)
        else:
            self.counters["rx_unexpected_acks"] += 1

    @property
    def _cos(self) -> bool:
        return bool(self.allocation_choice & BIT_COS)

    def _produce(self, now: float) -> None:
        c = self.connections[COS_CYCLIC]
        if not c.established or not c.epr_ms:
            self._produce_at = None
            return
        self._io_send(ids.G1_COS_CYCLIC, self.assemblies.produced())
        self._last_produced = now
        self._produce_at = now + c.epr_ms / 1000.0
        self.counters["cos_cyclic_produced"] += 1

    def inputs_changed(self, now: float) -> None:
        """An input of this front changed: a change-of-state connection produces (inhibit time permitting)."""
        c = self.connections[COS_CYCLIC]
        if self.state != "online" or not self._cos or not c.established or not c.epr_ms:
            return
        earliest = self._last_produced + c.inhibit_ms / 1000.0
        if now >= earliest:
            self._produce(now)
        elif self._produce_at is None or self._produce_at > earliest:
            self._produce_at = earliest
        self.deadline_after_call = self.next_deadline()

    def status(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "mac_id": self.mac_id,
            "bitrate": self.bitrate,
            "fault": self.fault_reason or None,
            "master_mac": None if self.master_mac == UNALLOCATED else self.master_mac,
            "allocation_choice": self.allocation_choice,
            "connections": {
                _NAMES[i]: {"state": c.state.name.lower(), "epr_ms": c.epr_ms}
                for i, c in self.connections.items()
                if c.exists
            },
            "produced_size": self.assemblies.produced_size,
            "consumed_size": self.assemblies.consumed_size,
            **self.counters,
        }


_NAMES = {EXPLICIT: "explicit", POLL: "poll", STROBE: "bit-strobe", COS_CYCLIC: "cos-cyclic"}
