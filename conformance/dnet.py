"""A DeviceNet Group 2 Only slave as the tester sees it: the tester is its master.

Only the bus is used (11-bit identifiers of the Predefined Master/Slave Connection Set):
Group 2 message 6 (unconnected request: Allocate 0x4B / Release 0x4C), 4 (explicit
request), 3 (explicit response), 5 (poll), 7 (duplicate MAC ID check), Group 1 message 15
(poll response). Explicit messages use the 8/8 body format (class and instance one byte).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from .link import Frame, Link
from .outcome import Fail, Timing

# Group 2 message ids, Group 1 messages of the slave
G2_EXPLICIT_RESPONSE, G2_EXPLICIT_REQUEST, G2_POLL, G2_UNCONNECTED, G2_DUP_MAC = 3, 4, 5, 6, 7
G2_COS_ACK = 2
G1_COS_CYCLIC, G1_STROBE_RESPONSE, G1_POLL_RESPONSE = 0xD, 0xE, 0xF
ALLOCATE, RELEASE, GET, SET, RESET, ERROR = 0x4B, 0x4C, 0x0E, 0x10, 0x05, 0x14
CHOICE_EXPLICIT, CHOICE_POLL, CHOICE_STROBE, CHOICE_COS = 0x01, 0x02, 0x04, 0x10
CHOICE_CYCLIC, CHOICE_ACK_SUPPRESS = 0x20, 0x40
FIRST, MIDDLE, LAST, ACK = 0x00, 0x40, 0x80, 0xC0

STATUS_NAMES = {
    0x02: "resource unavailable",
    0x05: "path destination unknown",
    0x08: "service not supported",
    0x09: "invalid attribute value",
    0x0B: "already in requested mode/state",
    0x0C: "object state conflict",
    0x0E: "attribute not settable",
    0x13: "not enough data",
    0x14: "attribute not supported",
    0x15: "too much data",
    0x16: "object does not exist",
    0x20: "invalid parameter",
}


def status_text(code: int) -> str:
    return f"0x{code:02X} ({STATUS_NAMES.get(code, 'other')})"


def group1_id(message: int, mac: int) -> int:
    return (message & 0xF) << 6 | (mac & 0x3F)


def group2_id(mac: int, message: int) -> int:
    return 0x400 | (mac & 0x3F) << 3 | (message & 0x7)


class CipErrorSeen(Exception):
    """The device answered an error response ``[hdr] 94 general additional``."""

    def __init__(self, general: int, additional: int, frame: Frame | None):
        super().__init__(f"CIP error {status_text(general)}, additional 0x{additional:02X}")
        self.general, self.additional, self.frame = general, additional, frame


@dataclass
class Reply:
    """An explicit response: service byte, data, and the frames it came in (several if fragmented)."""

    service: int
    data: bytes
    frames: list[Frame]


class DnetDevice:
    """Raw-frame DeviceNet master for one slave; ``settle`` releases every connection between cases."""

    def __init__(self, link: Link, mac_id: int, master_mac: int, timing: Timing):
        self.link, self.mac_id, self.master_mac, self.timing = link, mac_id, master_mac, timing

    def g2(self, message: int) -> int:
        return group2_id(self.mac_id, message)

    @property
    def poll_response_id(self) -> int:
        return group1_id(G1_POLL_RESPONSE, self.mac_id)

    def _explicit_response(self, timeout: float | None = None) -> Frame | None:
        return self.link.expect(
            self.g2(G2_EXPLICIT_RESPONSE), self.timing.response if timeout is None else timeout
        )

    # -- unconnected port: Allocate / Release ---------------------------------------
    def unconnected(self, service: int, body: bytes, master: int | None = None) -> Frame | None:
        self.link.flush()
        mac = self.master_mac if master is None else master
        self.link.send(self.g2(G2_UNCONNECTED), bytes([mac, service, 0x03, 0x01]) + body)
        return self._explicit_response()

    def allocate(self, choice: int, master: int | None = None) -> Frame:
        """Allocate; the success frame ``[hdr] CB <body format>`` or raises CipErrorSeen / Fail."""
        mac = self.master_mac if master is None else master
        frame = self.unconnected(ALLOCATE, bytes([choice, mac]), master=mac)
        return self._unconnected_reply(frame, ALLOCATE, f"Allocate 0x{choice:02X}")

    def release(self, choice: int, master: int | None = None) -> Frame:
        return self._unconnected_reply(
            self.unconnected(RELEASE, bytes([choice]), master=master),
            RELEASE,
            f"Release 0x{choice:02X}",
        )

    def expect_unconnected_error(
        self, service: int, body: bytes, codes: tuple[int, int], what: str
    ) -> None:
        """An unconnected request that must be refused with ``(general, additional)``."""
        frame = self.unconnected(service, body)
        want = f"[hdr] 94 {codes[0]:02X} {codes[1]:02X} ({STATUS_NAMES.get(codes[0], 'error')})"
        if frame is None:
            raise Fail(f"{what}: no response", expected=want, seen="nothing")
        data = frame.data
        if len(data) < 2 or data[1] != ERROR | 0x80:
            raise Fail(f"{what}: accepted", expected=want, seen=str(frame))
        if tuple(data[2:4]) != codes:
            raise Fail(f"{what}: wrong error codes", expected=want, seen=str(frame))

    def _unconnected_reply(self, frame: Frame | None, service: int, what: str) -> Frame:
        if frame is None:
            raise Fail(
                f"no response to {what}",
                expected=f"a frame on 0x{self.g2(G2_EXPLICIT_RESPONSE):03X}",
                seen="nothing",
            )
        check_error(frame.data, frame)
        if len(frame.data) < 2 or frame.data[1] != service | 0x80:
            raise Fail(
                f"wrong response to {what}",
                expected=f"[hdr] {service | 0x80:02X} ...",
                seen=str(frame),
            )
        return frame

    # -- explicit connection ------------------------------------------------------------
    def request(self, body: bytes, timeout: float | None = None) -> Reply | None:
        """One explicit request (service, class, instance, ...); the response, fragments acknowledged
        and reassembled; None if nothing came."""
        self.link.flush()
        if len(body) <= 7:
            self.link.send(self.g2(G2_EXPLICIT_REQUEST), bytes([self.master_mac]) + body)
        else:
            self._send_fragmented(body)
        frames: list[Frame] = []
        payload = b""
        expected_count = 0
        while True:
            frame = self._explicit_response(timeout)
            if frame is None:
                if frames:
                    raise Fail(
                        "fragmented response stopped",
                        expected=f"fragment {expected_count}",
                        seen="nothing",
                    )
                return None
            frames.append(frame)
            data = frame.data
            if not data:
                raise Fail("empty explicit response", seen=str(frame))
            if not data[0] & 0x80:
                if frames[:-1]:
                    raise Fail("unfragmented frame inside a fragmented response", seen=str(frame))
                return Reply(data[1] if len(data) > 1 else -1, bytes(data[2:]), frames)
            if len(data) < 2:
                raise Fail("fragment without fragmentation byte", seen=str(frame))
            frag = data[1]
            kind, count = frag & 0xC0, frag & 0x3F
            want_kind = (FIRST,) if not frames[:-1] else (MIDDLE, LAST)
            if kind not in want_kind or count != expected_count & 0x3F:
                raise Fail(
                    "explicit fragment out of sequence",
                    expected=f"type {'first' if not frames[:-1] else 'middle/last'}, count {expected_count}",
                    seen=str(frame),
                )
            if kind != LAST and len(data) != 8:
                raise Fail(
                    "a fragment before the last one is not full (6 data bytes)", seen=str(frame)
                )
            self.link.send(
                self.g2(G2_EXPLICIT_REQUEST), bytes([self.master_mac | 0x80, ACK | count, 0x00])
            )
            payload += data[2:]
            expected_count += 1
            if kind == LAST:
                return Reply(payload[0] if payload else -1, payload[1:], frames)
            if expected_count > 200:
                raise Fail("fragmented response never ends")

    def _send_fragmented(self, body: bytes) -> None:
        """A request longer than one frame: acknowledged fragments of 6 bytes, each sent after
        the device acknowledged the one before (``[hdr|80] C0|n 00``)."""
        chunks = [body[i : i + 6] for i in range(0, len(body), 6)]
        for n, chunk in enumerate(chunks):
            kind = FIRST if n == 0 else LAST if n == len(chunks) - 1 else MIDDLE
            self.link.send(
                self.g2(G2_EXPLICIT_REQUEST),
                bytes([self.master_mac | 0x80, kind | n & 0x3F]) + chunk,
            )
            ack = self._explicit_response()
            want = bytes([self.master_mac | 0x80, ACK | n & 0x3F, 0x00])
            if ack is None or ack.data != want:
                raise Fail(
                    f"fragment {n} of a {len(body)}-byte request not acknowledged",
                    expected=want.hex(" ").upper(),
                    seen=str(ack) if ack else "nothing",
                )

    def call(
        self, service: int, class_id: int, instance: int, rest: bytes = b"", what: str = ""
    ) -> Reply:
        """A request that must succeed: the reply, or Fail / CipErrorSeen."""
        what = what or f"service 0x{service:02X} class 0x{class_id:02X} instance {instance}"
        reply = self.request(bytes([service, class_id, instance]) + rest)
        if reply is None:
            raise Fail(
                f"no response to {what}",
                expected=f"a frame on 0x{self.g2(G2_EXPLICIT_RESPONSE):03X}",
                seen="nothing",
            )
        if reply.service == ERROR | 0x80:
            raise CipErrorSeen(
                reply.data[0] if reply.data else -1,
                reply.data[1] if len(reply.data) > 1 else -1,
                reply.frames[-1],
            )
        if reply.service != service | 0x80:
            raise Fail(
                f"wrong service in the response to {what}",
                expected=f"0x{service | 0x80:02X}",
                seen=str(reply.frames[-1]),
            )
        return reply

    def get(self, class_id: int, instance: int, attribute: int) -> bytes:
        return self.call(
            GET,
            class_id,
            instance,
            bytes([attribute]),
            f"Get_Attribute_Single {class_id}/{instance}/{attribute}",
        ).data

    def set(self, class_id: int, instance: int, attribute: int, value: bytes) -> bytes:
        return self.call(
            SET,
            class_id,
            instance,
            bytes([attribute]) + value,
            f"Set_Attribute_Single {class_id}/{instance}/{attribute}",
        ).data

    def expect_error(self, body: bytes, codes: tuple[int, ...], what: str) -> int:
        reply = self.request(body)
        if reply is None:
            raise Fail(
                f"{what}: no response",
                expected="error response [hdr] 94 " + " or ".join(f"{c:02X}" for c in codes),
                seen="nothing",
            )
        if reply.service != ERROR | 0x80:
            raise Fail(
                f"{what}: accepted",
                expected="an error response (service 0x94)",
                seen=str(reply.frames[-1]),
            )
        general = reply.data[0] if reply.data else -1
        if general not in codes:
            raise Fail(
                f"{what}: wrong general status",
                expected=" or ".join(status_text(c) for c in codes),
                seen=f"{status_text(general)}: {reply.frames[-1]}",
            )
        return general

    # -- I/O ---------------------------------------------------------------------------
    def poll(self, outputs: bytes, timeout: float | None = None) -> bytes | None:
        """Poll (I/O-fragmented above 8 bytes); the produced data reassembled, or None."""
        self.link.flush()
        if len(outputs) <= 8:
            self.link.send(self.g2(G2_POLL), outputs)
        else:
            chunks = [outputs[i : i + 7] for i in range(0, len(outputs), 7)]
            for n, chunk in enumerate(chunks):
                kind = FIRST if n == 0 else LAST if n == len(chunks) - 1 else MIDDLE
                self.link.send(self.g2(G2_POLL), bytes([kind | n & 0x3F]) + chunk)
        wait = self.timing.response if timeout is None else timeout
        first = self.link.expect(self.poll_response_id, wait)
        return None if first is None else first.data

    def poll_fragments(self, first: bytes, size: int) -> bytes:
        """The rest of an I/O-fragmented poll response of ``size`` bytes."""
        if size <= 8:
            return first
        data, count = first[1:], 1
        while len(data) < size:
            frame = self.link.expect(self.poll_response_id, self.timing.response)
            if frame is None:
                raise Fail(
                    "I/O fragmented poll response stopped",
                    expected=f"{size} bytes",
                    seen=f"{len(data)} bytes",
                )
            if frame.data[0] & 0x3F != count & 0x3F:
                raise Fail(
                    "I/O fragment out of sequence", expected=f"count {count}", seen=str(frame)
                )
            data += frame.data[1:]
            count += 1
        return data

    def g1(self, message: int) -> int:
        return group1_id(message, self.mac_id)

    def send_io(self, can_id: int, data: bytes) -> None:
        """An I/O message, in unacknowledged fragments of 7 bytes above 8 bytes."""
        if len(data) <= 8:
            self.link.send(can_id, data)
            return
        chunks = [data[i : i + 7] for i in range(0, len(data), 7)]
        for n, chunk in enumerate(chunks):
            kind = FIRST if n == 0 else LAST if n == len(chunks) - 1 else MIDDLE
            self.link.send(can_id, bytes([kind | n & 0x3F]) + chunk)

    def io_message(self, can_id: int, size: int, timeout: float | None = None) -> bytes | None:
        """One produced I/O message of ``size`` bytes (reassembled), or None if none came."""
        wait = self.timing.response if timeout is None else timeout
        first = self.link.expect(can_id, wait)
        if first is None:
            return None
        if size <= 8:
            return first.data
        data, count = first.data[1:], 1
        while len(data) < size:
            frame = self.link.expect(can_id, self.timing.response)
            if frame is None or frame.data[0] & 0x3F != count & 0x3F:
                raise Fail(
                    "I/O fragmented message broken",
                    expected=f"fragment {count} of {size} bytes",
                    seen=str(frame) if frame else "nothing",
                )
            data += frame.data[1:]
            count += 1
        return data

    # -- between cases ---------------------------------------------------------------------
    def settle(self) -> None:
        """Release every connection the tester may hold, each Release after the previous one's answer.

        The answers (errors for what was not held) are dropped. Waiting for each one, not a
        fixed pause, keeps a late answer from being read as the next case's (seen under load).
        """
        for choice in (CHOICE_POLL, CHOICE_STROBE, CHOICE_COS, CHOICE_EXPLICIT):
            self.unconnected(RELEASE, bytes([choice]))
        self.link.flush()

    def begin(self) -> None:
        """Before a case: nothing to note (every case starts unallocated)."""

    def restore(self, reset: bool = False) -> list[str]:
        """Isolation between cases: :meth:`settle` already released every connection."""
        return []

    def wait_online(self, within: float) -> bool:
        """Whether the device answers an Allocate of the explicit connection within ``within`` seconds
        (it may still be checking its MAC ID); the connection is released again."""
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            frame = self.unconnected(ALLOCATE, bytes([CHOICE_EXPLICIT, self.master_mac]))
            if frame is not None:
                self.settle()
                return True
        return False


def check_error(data: bytes, frame: Frame | None) -> None:
    if len(data) >= 3 and data[1] == ERROR | 0x80:
        raise CipErrorSeen(data[2], data[3] if len(data) > 3 else -1, frame)
