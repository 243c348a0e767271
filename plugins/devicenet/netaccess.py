"""Network access: the duplicate MAC ID check, communication fault and the Offline Connection
Set, Device Heartbeat, and the device restarts (Identity Reset, MAC ID and baud rate changes).

Life cycle: :meth:`NetworkAccess.boot` sends the first duplicate MAC ID request; a second
follows one check period later and the node goes online one period after that, unless
another node answered or checked the same MAC: then *communication fault*, silent but for
the Offline Connection Set (seed-003 §2.6, §2.7). A restart sends Device Shutdown from the
MAC being left, drops every connection and checks again (at the new MAC / bit rate).
"""

from __future__ import annotations

from collections.abc import Callable

from . import cip, ids
from .allocation import UNALLOCATED
from .connection_set import ConnectionSet
from .objects import u16
from .slave_state import DeviceState, SlaveState

# after a baud change at Reset the duplicate MAC check waits until the adapter has set the
# interface and reopened the bus (bit_timing_done); at most this long if it never says so
BIT_RATE_SWITCH_TIMEOUT_S = 5.0
SHUTDOWN_CODE = 0x0004
DEVICENET_CLASS = 0x03


class NetworkAccess:
    def __init__(self, slave: SlaveState, connections: ConnectionSet):
        self.slave = slave
        self.connections = connections
        self.fault_reason = ""
        self.heartbeat_s = 0
        self.dup_at: float | None = None
        self.heartbeat_at: float | None = None
        self.faulted_reply_at: float | None = None  # an identify request's delayed answer
        self._dup_step = 0
        self._restart: int | None = None
        self._new_mac: int | None = None
        self._fault_listeners: list[Callable[[str], None]] = []
        self._settings_listeners: list[Callable[[int, int], None]] = []
        self._bit_timing: Callable[[int, float], None] | None = None
        self.switching_bit_rate = False  # a baud change at Reset: the check waits for the switch

    # -- listeners ---------------------------------------------------------------------------
    def on_fault(self, listener: Callable[[str], None]) -> None:
        self._fault_listeners.append(listener)

    def on_settings(self, listener: Callable[[int, int], None]) -> None:
        self._settings_listeners.append(listener)

    def on_bit_timing(self, listener: Callable[[int, float], None]) -> None:
        self._bit_timing = listener

    def settings_changed(self) -> None:
        slave = self.slave
        mac = slave.mac_id if self._new_mac is None else self._new_mac
        baud = slave.baud_code if slave.pending_baud_code is None else slave.pending_baud_code
        for listener in list(self._settings_listeners):
            listener(mac, baud)

    def deadlines(self) -> list[float | None]:
        return [self.dup_at, self.heartbeat_at, self.faulted_reply_at]

    def _faulted_reply(self) -> None:
        self.faulted_reply_at = None
        if self.slave.state is DeviceState.COMM_FAULT:
            self.slave.send(
                ids.group4_id(ids.G4_FAULTED_RESPONSE), self.identity_payload(response=False)
            )

    # -- duplicate MAC ID check --------------------------------------------------------------
    def start_check(self, now: float, delay: float = 0.0) -> None:
        """Send the first duplicate MAC ID request now, or after ``delay`` (step 0 until then)."""
        slave = self.slave
        slave.now = now
        slave.move_to(DeviceState.DUP_MAC_CHECK)
        if delay > 0:
            self._dup_step, self.dup_at = 0, now + delay
            return
        self._dup_step = 1
        self.dup_at = now + slave.settings.dup_mac_interval_s
        self._send_dup_mac(response=False)

    def identity_payload(self, response: bool) -> bytes:
        """``[R/R | port 0][vendor LE16][serial LE32]``: duplicate MAC ID check and faulted response."""
        settings = self.slave.settings
        return (
            bytes([0x80 if response else 0x00])
            + u16(settings.vendor_id)
            + settings.serial.to_bytes(4, "little")
        )

    def _send_dup_mac(self, response: bool) -> None:
        slave = self.slave
        slave.send(ids.group2_id(slave.mac_id, ids.G2_DUP_MAC), self.identity_payload(response))

    def tick(self, now: float) -> None:
        if self.faulted_reply_at is not None and now >= self.faulted_reply_at:
            self._faulted_reply()
        if self.dup_at is not None and now >= self.dup_at:
            self._dup_mac_step(now)
        if self.slave.online and self.heartbeat_at is not None and now >= self.heartbeat_at:
            self._send_heartbeat()
            self.heartbeat_at = now + self.heartbeat_s

    def _dup_mac_step(self, now: float) -> None:
        if self._dup_step == 0:  # a delayed start (after a bit-rate switch)
            self.start_check(now)
        elif self._dup_step == 1:
            self._dup_step = 2
            self.dup_at = now + self.slave.settings.dup_mac_interval_s
            self._send_dup_mac(response=False)
        else:
            self._dup_step, self.dup_at = 0, None
            self.slave.move_to(DeviceState.ONLINE)
            if self.heartbeat_s:
                self.heartbeat_at = now + self.heartbeat_s

    def dup_mac_frame(self, data: bytes) -> None:
        """A duplicate MAC ID request or response on our MAC."""
        slave = self.slave
        if len(data) != 7:
            slave.counters["rx_malformed"] += 1
            return
        response = bool(data[0] & 0x80)
        if slave.state is DeviceState.DUP_MAC_CHECK:
            vendor, serial = (
                int.from_bytes(data[1:3], "little"),
                int.from_bytes(data[3:7], "little"),
            )
            self._enter_fault(
                f"duplicate MAC ID {slave.mac_id}: another node "
                f"{'answered our check' if response else 'checks the same MAC'} "
                f"(vendor {vendor}, serial {serial})"
            )
        elif slave.online and not response:
            slave.counters["dup_mac_checks_answered"] += 1
            self._send_dup_mac(response=True)
        else:
            slave.counters["dup_mac_responses_ignored"] += 1

    def _enter_fault(self, reason: str) -> None:
        self.slave.move_to(DeviceState.COMM_FAULT)
        self.fault_reason = reason
        self.dup_at = self.heartbeat_at = None
        self.slave.counters["dup_mac_faults"] += 1
        for listener in list(self._fault_listeners):
            listener(reason)

    # -- Offline Connection Set ----------------------------------------------------------------
    def offline_request(self, data: bytes, now: float) -> None:
        """Offline Connection Set (seed-003 §2.7), served while in communication fault:

        * identify faulted nodes, ``[match<<6 | value] 4B [time delay byte offset]``: with the
          match bit clear every faulted node answers, with it set only the one whose MAC ID is
          ``value``; the answer ``00 vendor serial`` on 0x7EC leaves after as many ms as the
          serial number's byte at the offset (LE, offset modulo 4) says, so that several
          faulted nodes do not answer at once (none without an offset: the seed's
          ``3F 4B 02`` with serial 1 answers at once);
        * change the MAC ID of the node named by vendor and serial, ``<MAC> 4D vendor serial``:
          the node restarts its duplicate MAC ID check there (TV-41/42).
        """
        slave = self.slave
        if (
            slave.state is not DeviceState.COMM_FAULT
        ):  # for faulted nodes only: counted, so a busy set shows
            slave.counters["rx_offline_not_faulted"] += 1
            return
        if len(data) in (2, 3) and data[1] == cip.ALLOCATE:
            match, value = bool(data[0] & 0x40), data[0] & 0x3F
            if data[0] & 0x80 or (match and value != slave.mac_id):
                slave.counters["rx_offline_ignored"] += 1
                return
            delay_ms = 0
            if len(data) == 3:
                delay_ms = slave.settings.serial.to_bytes(4, "little")[data[2] % 4]
            self.faulted_reply_at = now + delay_ms / 1000.0
            if not delay_ms:
                self._faulted_reply()
        elif (
            len(data) == 8
            and data[1] == cip.HEARTBEAT
            and data[2:] == self.identity_payload(False)[1:]
            and data[0] <= 63
        ):
            slave.counters["offline_mac_changes"] += 1
            slave.mac_id, self.fault_reason = data[0], ""
            self.settings_changed()
            self.start_check(now)
        else:
            slave.counters["rx_offline_ignored"] += 1

    # -- heartbeat -------------------------------------------------------------------------------
    def set_heartbeat(self, seconds: int) -> None:
        self.heartbeat_s = seconds
        self.heartbeat_at = self.slave.now + seconds if seconds else None

    def _send_heartbeat(self) -> None:
        slave = self.slave
        header = slave.master_mac if slave.master_mac != UNALLOCATED else slave.mac_id
        slave.send_explicit(
            bytes([header, cip.HEARTBEAT | cip.RESPONSE, 0x01, 0x00, 0x03, 0x00, 0x00, 0x00])
        )

    # -- restarts ----------------------------------------------------------------------------------
    def schedule_restart(self, class_id: int) -> None:
        """Restart once the current request has been answered (Identity Reset: class 1)."""
        self._restart = class_id

    def change_mac(self, mac: int) -> None:
        self._new_mac = mac
        self._restart = DEVICENET_CLASS
        self.settings_changed()

    def restart_if_scheduled(self, header: int, now: float) -> None:
        if self._restart is not None:
            class_id, self._restart = self._restart, None
            self._restart_device(class_id, header, now)

    def _restart_device(self, class_id: int, header: int, now: float) -> None:
        """Device Shutdown from the current MAC, connections gone, dup-MAC check at the new MAC/baud."""
        slave = self.slave
        shutdown_header = slave.master_mac if slave.master_mac != UNALLOCATED else header
        slave.send_explicit(
            bytes([shutdown_header, cip.SHUTDOWN | cip.RESPONSE])
            + u16(class_id)
            + u16(1)
            + u16(SHUTDOWN_CODE)
        )
        self.connections.close_all("device reset")
        slave.master_mac, slave.allocation_choice = UNALLOCATED, 0
        if self._new_mac is not None:
            slave.mac_id, self._new_mac = self._new_mac, None
        self.heartbeat_at = None
        delay = 0.0
        if slave.pending_baud_code is not None and slave.pending_baud_code != slave.baud_code:
            slave.baud_code = slave.pending_baud_code
            if self._bit_timing is not None:
                # the shutdown answer leaves at the old rate; the check starts at the new one
                # once the adapter has switched (bit_timing_done), before any other frame
                self.switching_bit_rate = True
                self._bit_timing(slave.bitrate, 0.0)
                delay = BIT_RATE_SWITCH_TIMEOUT_S
        slave.pending_baud_code = None
        self.start_check(now, delay)

    def bit_timing_done(self, ok: bool, now: float) -> None:
        """The adapter switched the bus (``ok``) or could not set the interface (the node runs at
        the rate the interface has; the front shows it in the Identity status): the duplicate
        MAC ID check starts now."""
        if self.switching_bit_rate:
            self.switching_bit_rate = False
            if self._dup_step == 0 and self.dup_at is not None:
                self.start_check(now)
