"""The device under test as the tester sees it: its EDS, raw SDO, NMT and state probes.

Nothing here knows how the device is built; it only speaks CANopen on the bus.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from typing import Any, Protocol, overload

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo.client import SdoClient

from .link import Frame, Link
from .outcome import STOPPED_ANSWERING, Fail, Skip, Timing

NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
STATE_NAMES = {0x00: "boot-up", 0x04: "Stopped", 0x05: "Operational", 0x7F: "Pre-operational"}

ABORT_NAMES = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "command specifier not valid",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x06010000: "unsupported access",
    0x06010001: "read of a write-only object",
    0x06010002: "write of a read-only object",
    0x06020000: "object does not exist",
    0x06040041: "object cannot be mapped",
    0x06040042: "mapping exceeds PDO length",
    0x06040043: "general parameter incompatibility",
    0x06070010: "data type / length mismatch",
    0x06070012: "length too high",
    0x06070013: "length too low",
    0x06090011: "sub-index does not exist",
    0x06090030: "value range exceeded",
    0x06090031: "value too high",
    0x06090032: "value too low",
    0x08000000: "general error",
    0x08000020: "cannot store or transfer",
    0x08000021: "cannot transfer: local control",
    0x08000022: "cannot transfer: device state",
    0x08000024: "no data available",
}


def abort_text(code: int) -> str:
    return f"abort 0x{code:08X} ({ABORT_NAMES.get(code, 'unknown code')})"


class SdoAbort(Exception):
    def __init__(self, code: int, frame: Frame):
        super().__init__(abort_text(code))
        self.code = code
        self.frame = frame


def mux(index: int, sub: int) -> bytes:
    return struct.pack("<HB", index, sub)


class CaseContext(Protocol):
    """What the device needs of a running case (:class:`.framework.Context` is one): the
    device itself, the timing knobs and a place to register clean-ups."""

    @property
    def device(self) -> Device: ...

    @property
    def timing(self) -> Timing: ...

    def cleanup(self, fn: Callable[[], object]) -> None: ...


class Device:
    def __init__(self, link: Link, node_id: int, od: canopen.ObjectDictionary, timing: Timing):
        self.link = link
        self.node_id = node_id
        self.od = od
        self.timing = timing
        self.sdo_rx, self.sdo_tx = self.sdo_cobs()
        self.nmt_sent_at = 0.0  # when the last NMT command went out (time.time())
        self.eds_notes: list[str] = []  # what reading the EDS passed over (.eds)
        self.register_at_start: int | None = None  # 0x1001 when the case began

    @classmethod
    def from_eds(cls, link: Link, node_id: int, eds: str, timing: Timing) -> Device:
        from .eds import load_eds

        reading = load_eds(eds, node_id)
        device = cls(link, node_id, reading.od, timing)
        device.eds_notes = reading.notes
        return device

    # -- EDS -----------------------------------------------------------------
    def has(self, index: int, sub: int | None = None) -> bool:
        if index not in self.od:
            return False
        return sub is None or self.var(index, sub) is not None

    def var(self, index: int, sub: int = 0) -> ODVariable | None:
        if index not in self.od:
            return None
        obj = self.od[index]
        if isinstance(obj, ODVariable):
            return obj if sub == 0 else None
        entry: ODVariable | None
        if isinstance(obj, ODRecord):
            entry = obj.get(sub) if sub in obj else None
            return entry
        assert isinstance(obj, ODArray)  # (the third kind of object)
        if sub in obj.subindices:
            entry = obj.subindices[sub]
            return entry
        top = obj.subindices.get(0)
        limit = top.default if top is not None and isinstance(top.default, int) else 0
        return obj[sub] if 0 < sub <= limit else None

    def variables(self) -> list[ODVariable]:
        """Every entry the EDS lists; not the data types [DummyUsage] declares (0x0001-0x0007:
        canopen imports them as objects, but they are mapping placeholders, not entries)."""
        out = []
        for index in sorted(i for i in self.od.indices if isinstance(i, int) and i >= 0x1000):
            obj = self.od[index]
            if isinstance(obj, ODVariable):
                out.append(obj)
            else:
                out.extend(obj.subindices[s] for s in sorted(obj.subindices))
        return out

    @overload
    def require(self, index: int, sub: int, why: str = "") -> ODVariable: ...
    @overload
    def require(self, index: int, sub: None = None, why: str = "") -> None: ...
    def require(self, index: int, sub: int | None = None, why: str = "") -> ODVariable | None:
        """Skip the case unless the EDS lists ``index`` (``:sub``); the entry when ``sub`` is given."""
        if not self.has(index, sub):
            what = f"0x{index:04X}" + (f":{sub}" if sub is not None else "")
            raise Skip(f"EDS lists no {what}" + (f" ({why})" if why else ""))
        if sub is None:
            return None
        var = self.var(index, sub)
        assert var is not None  # (has() said so)
        return var

    def sdo_cobs(self) -> tuple[int, int]:
        rx = self.od_default(0x1200, 1, 0x600 + self.node_id)
        tx = self.od_default(0x1200, 2, 0x580 + self.node_id)
        return rx & 0x7FF, tx & 0x7FF

    def od_default(self, index: int, sub: int, fallback: int) -> int:
        var = self.var(index, sub)
        return var.default if var is not None and isinstance(var.default, int) else fallback

    # -- raw SDO ---------------------------------------------------------------
    def sdo_request(self, data: bytes | list[int], timeout: float | None = None) -> Frame | None:
        self.link.flush()
        self.link.send(self.sdo_rx, bytes(data).ljust(8, b"\0"))
        return self.link.expect(self.sdo_tx, self.timing.response if timeout is None else timeout)

    def sdo(self, data: bytes | list[int], what: str = "SDO response") -> Frame:
        """An answer that must come; an abort raises :class:`SdoAbort`."""
        frame = self.sdo_request(data)
        if frame is None:
            raise Fail(
                f"no {what} from the device",
                expected=f"a frame on 0x{self.sdo_tx:03X}",
                seen="nothing",
            )
        if len(frame.data) < 8:
            raise Fail(
                f"SDO response with DLC {len(frame.data)}", expected="DLC 8", seen=str(frame)
            )
        if frame.data[0] == 0x80:
            raise SdoAbort(struct.unpack_from("<I", frame.data, 4)[0], frame)
        return frame

    def upload(self, index: int, sub: int) -> bytes:
        """Expedited or segmented upload over raw frames, checking every protocol field."""
        frame = self.sdo(bytes([0x40]) + mux(index, sub))
        b0 = frame.data[0]
        expect_cs(frame, 2, "initiate upload response (scs 2)")
        expect_mux(frame, index, sub)
        if b0 & 0x02:
            n = (b0 >> 2) & 3 if b0 & 0x01 else 0
            return frame.data[4 : 8 - n]
        size = struct.unpack_from("<I", frame.data, 4)[0] if b0 & 0x01 else None
        data = bytearray()
        toggle = 0
        while True:
            seg = self.sdo(bytes([0x60 | toggle << 4]), "upload segment")
            expect_cs(seg, 0, "upload segment response (scs 0)")
            if (seg.data[0] >> 4) & 1 != toggle:
                raise Fail(
                    "upload segment with the wrong toggle bit",
                    expected=f"t={toggle}",
                    seen=str(seg),
                )
            n = (seg.data[0] >> 1) & 7
            data += seg.data[1 : 8 - n]
            if seg.data[0] & 0x01:
                break
            toggle ^= 1
            if len(data) > 1 << 20:
                raise Fail("segmented upload never ends")
        if size is not None and size != len(data):
            raise Fail(
                f"segmented upload of 0x{index:04X}:{sub} delivered {len(data)} bytes",
                expected=f"{size} bytes as announced",
                seen=f"{len(data)} bytes",
            )
        return bytes(data)

    def download(self, index: int, sub: int, data: bytes, segmented: bool = False) -> None:
        if len(data) <= 4 and not segmented:
            frame = self.sdo(
                bytes([0x23 | (4 - len(data)) << 2]) + mux(index, sub) + data.ljust(4, b"\0")
            )
            expect_cs(frame, 3, "download response (scs 3)")
            expect_mux(frame, index, sub)
            return
        frame = self.sdo(bytes([0x21]) + mux(index, sub) + struct.pack("<I", len(data)))
        expect_cs(frame, 3, "download response (scs 3)")
        expect_mux(frame, index, sub)
        toggle = 0
        for pos in range(0, len(data), 7):
            chunk = data[pos : pos + 7]
            last = pos + 7 >= len(data)
            seg = self.sdo(
                bytes([toggle << 4 | (7 - len(chunk)) << 1 | int(last)]) + chunk.ljust(7, b"\0"),
                "download segment response",
            )
            if seg.data[0] != 0x20 | toggle << 4:
                raise Fail(
                    "wrong download segment response",
                    expected=f"{0x20 | toggle << 4:02X} (scs 1, t={toggle})",
                    seen=str(seg),
                )
            toggle ^= 1

    def expect_abort(self, request: bytes, codes: tuple[int, ...], what: str) -> int:
        try:
            frame = self.sdo(request)
        except SdoAbort as exc:
            if exc.code not in codes:
                raise Fail(
                    f"{what}: wrong abort code",
                    expected=" or ".join(abort_text(c) for c in codes),
                    seen=abort_text(exc.code),
                ) from None
            if bytes(exc.frame.data[1:4]) != bytes(request[1:4]) and request[0] >> 5 in (1, 2):
                raise Fail(
                    f"{what}: abort does not echo the multiplexer",
                    expected=bytes(request[1:4]).hex(" "),
                    seen=str(exc.frame),
                ) from None
            return exc.code
        raise Fail(
            f"{what}: accepted", expected=" or ".join(abort_text(c) for c in codes), seen=str(frame)
        )

    def expect_write_abort(
        self, index: int, sub: int, data: bytes, codes: tuple[int, ...], what: str
    ) -> int:
        """Write ``data`` (expedited up to 4 bytes, else segmented); it must be refused with one of ``codes``."""
        if len(data) <= 4:
            return self.expect_abort(
                bytes([0x23 | (4 - len(data)) << 2]) + mux(index, sub) + data.ljust(4, b"\0"),
                codes,
                what,
            )
        wanted = " or ".join(abort_text(c) for c in codes)
        try:
            self.download(index, sub, data)
        except SdoAbort as exc:
            if exc.code in codes:
                return exc.code
            raise Fail(
                f"{what}: wrong abort code", expected=wanted, seen=abort_text(exc.code)
            ) from None
        raise Fail(f"{what}: accepted", expected=wanted)

    # -- typed access through the EDS --------------------------------------------
    def read(self, index: int, sub: int = 0) -> Any:
        """The value, decoded as the EDS types it (int, float, str or bytes)."""
        raw = self.upload(index, sub)
        var = self.var(index, sub)
        if var is None:
            return int.from_bytes(raw, "little")
        try:
            return var.decode_raw(raw)
        except Exception as exc:
            raise Fail(
                f"0x{index:04X}:{sub} value {raw.hex(' ')} does not decode as {type_name(var)}: {exc}"
            ) from None

    def write(self, index: int, sub: int, value: Any) -> None:
        var = self.var(index, sub)
        if isinstance(value, (bytes, bytearray)):
            data = bytes(value)
        elif var is not None:
            data = var.encode_raw(value)
        else:
            data = struct.pack("<I", value)
        self.download(index, sub, data)

    def patch(self, ctx: CaseContext, index: int, sub: int, value: Any) -> object:
        """Write ``value`` and restore the previous value when the case ends."""
        old = self.read(index, sub)
        self.write(index, sub, value)
        ctx.cleanup(lambda: self.write(index, sub, old))
        return old

    # -- canopen's client, for block transfers ---------------------------------------
    def block_client(self) -> SdoClient:
        client = SdoClient(self.sdo_rx, self.sdo_tx, self.od)
        client.network = self.link.network
        client.RESPONSE_TIMEOUT = self.timing.response
        self.link.network.subscribe(self.sdo_tx, client.on_response)
        return client

    def drop_client(self, client: SdoClient) -> None:
        self.link.network.unsubscribe(self.sdo_tx, client.on_response)

    # -- NMT and states -------------------------------------------------------------
    def nmt(self, cs: int, node: int | None = None, dlc: int = 2) -> None:
        frame = self.link.send(
            0x000, bytes([cs, self.node_id if node is None else node]).ljust(dlc, b"\0")
        )
        self.nmt_sent_at = frame.timestamp

    def reset(self, cs: int = NMT_RESET_COMM) -> Frame | None:
        """Reset node or communication; the boot-up frame, or None if none came."""
        self.link.flush()
        self.nmt(cs)
        return self.wait_bootup()

    def wait_bootup(self, node_id: int | None = None) -> Frame | None:
        cob = 0x700 + (node_id or self.node_id)
        return self.link.expect(
            lambda f: f.cob == cob and not f.rtr and f.data[:1] == b"\0", self.timing.bootup
        )

    def settle(self) -> None:
        """Back to Pre-operational between cases; pending frames are dropped."""
        self.nmt(NMT_PREOP)
        time.sleep(0.01)
        self.link.flush()

    # -- isolation between cases -------------------------------------------------------
    def answering(self) -> bool:
        """Whether the SDO server is idle and answers: an upload of 0x1000 is answered (a value
        or an abort echoing 1000:00), twice tried."""
        for _ in range(2):
            frame = self.sdo_request(bytes([0x40]) + mux(0x1000, 0))
            if frame is not None and len(frame.data) == 8 and frame.data[1:4] == mux(0x1000, 0):
                if frame.data[0] >> 5 == 2 or frame.data[0] == 0x80:
                    if frame.data[0] & 0x03 == 0x01:  # a segmented answer: end that transfer too
                        self.link.send(self.sdo_rx, client_abort(0x1000, 0))
                    return True
        return False

    def end_open_transfer(self) -> str | None:
        """Abort the SDO transfer the case's frames leave open (a failed case stops mid-transfer;
        NMT Enter Pre-operational does not end a transfer): what was done, or None."""
        open_mux = open_transfer(self.link.log, self.sdo_rx, self.sdo_tx)
        if open_mux is None:
            return None
        self.link.send(self.sdo_rx, bytes([0x80]) + open_mux + ABORT_GENERAL)
        time.sleep(0.01)
        index, sub = struct.unpack("<HB", open_mux)
        return f"the runner aborted the SDO transfer of 0x{index:04X}:{sub} the case left open"

    def leave_lss_configuration(self) -> bool:
        """Switch state global to waiting (CiA 305) if the case spoke LSS: an LSS slave left in
        configuration state answers what the next case does not expect."""
        if not any(d == "→" and f.cob == LSS_MASTER for _, d, f in self.link.log):
            return False
        self.link.send(LSS_MASTER, bytes([0x04, 0x00]).ljust(8, b"\0"))
        time.sleep(0.01)
        return True

    def begin(self) -> None:
        """Before a case: what 0x1001 shows (errors the case did not cause are not its to end)."""
        self.register_at_start = None
        if self.has(0x1001):
            frame = self.sdo_request(bytes([0x40]) + mux(0x1001, 0))
            if frame is not None and frame.data[:4] == bytes([0x4F]) + mux(0x1001, 0):
                self.register_at_start = frame.data[4]

    def new_errors(self) -> int:
        """Error register bits the device shows now and did not when the case began."""
        if self.register_at_start is None:
            return 0
        frame = self.sdo_request(bytes([0x40]) + mux(0x1001, 0))
        if frame is None or frame.data[:4] != bytes([0x4F]) + mux(0x1001, 0):
            return 0
        return frame.data[4] & ~self.register_at_start

    def monitoring_armed(self) -> bool:
        """Whether the case's frames may have started a monitoring that outlives it: node
        guarding remote frames arm life guarding (0x100C ≠ 0), another node's heartbeats a
        heartbeat consumer (0x1016), SYNCs the SYNC-loss supervision (0x1006 ≠ 0). Each runs
        on after the case and raises its error in the next one; reset communication (CiA 301
        §7.3.2) stops them all until the master starts them again."""
        sent = {f.cob for _, d, f in self.link.log if d == "→" and not f.data[:1] == b"\0"}
        rtr = any(d == "→" and f.rtr and f.cob == 0x700 + self.node_id for _, d, f in self.link.log)
        heartbeats = any(0x701 <= c <= 0x77F and c != 0x700 + self.node_id for c in sent)
        sync = self.od_default(0x1005, 0, 0x80) & 0x7FF in sent
        try:
            return (
                (rtr and self.has(0x100C) and bool(self.read(0x100C, 0)))
                or (heartbeats and self.has(0x1016))
                or (sync and self.has(0x1006) and bool(self.read(0x1006, 0)))
            )
        except Exception:  # unreadable: the answering check below decides
            return False

    def restore(self, reset: bool = False) -> list[str]:
        """Leave the device as the next case must find it: no transfer open, LSS waiting,
        answering. A device that does not answer gets its SDO server timeout to end what it
        holds, then NMT reset communication; ``reset`` (a case could not restore what it
        wrote) resets at once. What was done, as notes for the report."""
        notes = [n for n in (self.end_open_transfer(),) if n]
        self.leave_lss_configuration()
        self.link.flush()
        asked = reset
        reset = reset or self.monitoring_armed()
        if not reset and self.answering() and self.new_errors():
            reset = True  # an error the case raised is still shown: it must not meet the next
        if not reset:
            if self.answering():
                return notes
            time.sleep(self.timing.sdo_server_timeout)
            self.link.flush()
            if self.answering():
                return notes + ["the device answered SDO again only after its SDO server timeout"]
            notes.append("the device did not answer an SDO read of 0x1000 after the case")
        boot = self.reset(NMT_RESET_COMM)
        self.settle()
        if self.answering():
            left = self.new_errors()
            if left:
                notes.append(
                    f"0x1001 shows 0x{left:02X} the case raised, also after reset communication"
                )
            if not notes and not asked:  # routine: a monitoring or an error the case started
                return notes
            seen = "" if boot is not None else " (no boot-up seen)"
            return notes + [f"the runner reset communication{seen} before the next case"]
        return notes + [f"{STOPPED_ANSWERING}: no SDO answer even after reset communication"]

    def guard(self) -> Frame | None:
        self.link.flush()
        self.link.send(0x700 + self.node_id, rtr=True, dlc=1)
        return self.link.expect(0x700 + self.node_id, self.timing.response)


class StateProbe:
    """Reads the NMT state from heartbeats (0x1017) or, failing that, node guarding (0x100C).

    A state counts only when two reports in a row agree, both sent after the last NMT command:
    a device may send one more heartbeat with its old state after the command reached it (it
    was already queued, or its heartbeat timer ran before it processed the command), and CiA
    301 gives the device no deadline for acting on a command other than its next report."""

    def __init__(self, ctx: CaseContext):
        self.ctx = ctx
        self.dev = ctx.device
        self.period_ms = ctx.timing.heartbeat_ms
        if self.dev.has(0x1017):
            self.method = "heartbeat"
            self.arm()
            ctx.cleanup(self._disarm)
        elif self.dev.has(0x100C):
            self.method = "guarding"
        else:
            raise Skip(
                "the EDS lists neither 0x1017 (heartbeat) nor 0x100C (guarding): NMT state cannot be observed"
            )

    def arm(self) -> None:
        if self.method == "heartbeat":
            try:
                self.dev.write(0x1017, 0, self.ctx.timing.heartbeat_ms)
                self.period_ms = self.ctx.timing.heartbeat_ms
            except SdoAbort:  # a fixed producer time: use the device's own
                self.period_ms = int(self.dev.read(0x1017, 0))
                if not self.period_ms:
                    raise Skip("0x1017 refuses a producer time and is 0: no heartbeat") from None

    def _disarm(self) -> None:
        self.dev.write(0x1017, 0, self.dev.od_default(0x1017, 0, 0))

    def reports(self) -> list[int]:
        """The states reported after the last NMT command until two in a row agree (at most
        four reports, or none when nothing comes)."""
        seen: list[int] = []
        deadline = time.monotonic() + 4 * self.period_ms / 1000 + self.ctx.timing.response
        while len(seen) < 4:
            frame = self._next_report(deadline)
            if frame is None or not frame.data:
                break
            seen.append(frame.data[0] & 0x7F)
            if len(seen) >= 2 and seen[-1] == seen[-2]:
                break
        return seen

    def _next_report(self, deadline: float) -> Frame | None:
        dev = self.dev
        if self.method == "guarding":
            return dev.guard()
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        # a heartbeat received before the last NMT command went out can still be queued
        # here (a busy tester reads late): it shows the state before the command
        since = dev.nmt_sent_at
        return dev.link.expect(
            lambda f: (
                f.cob == 0x700 + dev.node_id
                and not f.rtr
                and f.data[:1] != b"\0"
                and f.timestamp >= since
            ),
            min(left, 2 * self.period_ms / 1000 + self.ctx.timing.response),
        )

    def state(self) -> int | None:
        """The confirmed state (two reports in a row), else the last report, else None."""
        seen = self.reports()
        return seen[-1] if seen else None

    def expect(self, state: int, after: str) -> None:
        seen = self.reports()
        if not seen or seen[-1] != state or (len(seen) >= 2 and seen[-2] != state):
            shown = ", ".join(f"{s:#04x} {STATE_NAMES.get(s, '')}".strip() for s in seen)
            raise Fail(
                f"after {after} the {self.method} reports the wrong state",
                expected=f"{state:#04x} {STATE_NAMES.get(state, '')} twice in a row",
                seen=shown or "no frame",
                clause="CiA 301 §7.3.2 (NMT state machine), §7.2.8.3.2 (error control reports the state)",
            )


LSS_MASTER = 0x7E5
ABORT_GENERAL = struct.pack("<I", 0x08000000)


def client_abort(index: int, sub: int) -> bytes:
    return bytes([0x80]) + mux(index, sub) + ABORT_GENERAL


def open_transfer(log: list[tuple[float, str, Frame]], rx: int, tx: int) -> bytes | None:
    """The multiplexer of an SDO transfer the logged frames leave open, or None: a transfer is
    open after an initiate that is not followed by its end (an abort either way, an expedited
    answer, the last segment and its answer, the block end and its answer)."""
    sdo = [(d, f) for _, d, f in log if (d, f.cob) in (("→", rx), ("←", tx)) and len(f.data) == 8]
    current: bytes | None = None
    block = False
    last_client = 0
    for direction, frame in sdo:
        b0 = frame.data[0]
        if direction == "→":
            last_client = b0
            if b0 == 0x80:
                current, block = None, False
            elif block:
                if b0 == 0xA1 and current is not None:  # block upload: the client's end response
                    current, block = None, False
            elif b0 >> 5 in (1, 2, 5, 6):
                current, block = bytes(frame.data[1:4]), b0 >> 5 in (5, 6)
            continue
        if b0 == 0x80:
            current, block = None, False
        elif current is None:
            continue
        elif b0 >> 5 == 2 and b0 & 0x02:  # expedited upload response
            current = None
        elif b0 >> 5 == 3 and last_client >> 5 == 1 and last_client & 0x02:  # expedited download
            current = None
        elif b0 >> 5 == 0 and b0 & 0x01 and last_client >> 5 == 3:  # last upload segment
            current = None
        elif b0 >> 5 == 1 and last_client >> 5 == 0 and last_client & 0x01:  # last download segment
            current = None
        elif block and b0 == 0xA1:  # block download end response
            current, block = None, False
    return current


def expect_cs(frame: Frame, cs: int, what: str) -> None:
    if frame.data[0] >> 5 != cs:
        raise Fail("unexpected SDO command specifier", expected=what, seen=str(frame))


def expect_mux(frame: Frame, index: int, sub: int) -> None:
    if bytes(frame.data[1:4]) != mux(index, sub):
        raise Fail(
            "SDO response does not echo the multiplexer",
            expected=mux(index, sub).hex(" ").upper(),
            seen=str(frame),
        )


def type_name(var: ODVariable) -> str:
    from canopen.objectdictionary import datatypes

    for name in dir(datatypes):
        if name.isupper() and getattr(datatypes, name) == var.data_type:
            return name
    return f"type 0x{var.data_type:04X}"
