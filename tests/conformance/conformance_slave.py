"""A tiny raw-frame CANopen slave for testing the conformance suite itself.

It implements just enough of CiA 301 to pass the cases its EDS makes applicable (SDO
expedited/segmented with the standard aborts, NMT with boot-up, heartbeat, node guarding)
and can be broken on purpose with ``faults``:

* ``wrong_abort_missing_sub``: a missing sub-index answers 0602 0000 instead of 0609 0011
* ``no_toggle_check``: upload segments are served whatever the toggle bit
* ``late_heartbeat``: heartbeats come 2 × the producer time apart
* ``stuck_guard_toggle``: the guarding toggle bit never alternates
* ``sdo_in_stopped``: SDO is still served in Stopped
"""

from __future__ import annotations

import struct
import threading
import time

import can

NODE_NAME = b"TinySlave conformance"

# (index, sub): (size or None for strings, access, default, low, high)
OBJECTS = {
    (0x1000, 0): (4, "ro", 0, None, None),
    (0x1001, 0): (1, "ro", 0, None, None),
    (0x1008, 0): (None, "const", NODE_NAME, None, None),
    (0x100C, 0): (2, "rw", 0, None, None),
    (0x100D, 0): (1, "rw", 0, None, None),
    (0x1017, 0): (2, "rw", 0, None, None),
    (0x1018, 0): (1, "const", 4, None, None),
    (0x1018, 1): (4, "ro", 0x0000ABCD, None, None),
    (0x1018, 2): (4, "ro", 0x00007232, None, None),
    (0x1018, 3): (4, "ro", 0x00010002, None, None),
    (0x1018, 4): (4, "ro", 0x12345678, None, None),
    (0x2000, 0): (2, "rw", 100, 10, 1000),
    (0x2001, 0): (4, "rw", 0, None, None),
}
TYPES = {1: "0x0005", 2: "0x0006", 4: "0x0007", None: "0x0009"}
ACCESS = {"ro": "ro", "rw": "rw", "const": "const"}


def eds_text(objects: dict | None = None, device_info: list[str] | None = None) -> str:
    """The slave's EDS, written by hand from ``objects`` (OBJECTS)."""
    objects = OBJECTS if objects is None else objects
    out = [
        "[FileInfo]",
        "FileName=tiny.eds",
        "EDSVersion=4.0",
        "",
        "[DeviceInfo]",
        *(
            device_info
            or ["VendorName=fieldgate tests", "ProductName=TinySlave", "LSS_Supported=0"]
        ),
        "",
        "[MandatoryObjects]",
        "SupportedObjects=2",
        "1=0x1000",
        "2=0x1001",
        "",
        "[OptionalObjects]",
    ]
    opt = sorted({i for i, _ in objects if i not in (0x1000, 0x1001) and i < 0x2000})
    man = sorted({i for i, _ in objects if i >= 0x2000})
    out += (
        [f"SupportedObjects={len(opt)}"]
        + [f"{n}=0x{i:04X}" for n, i in enumerate(opt, 1)]
        + ["", "[ManufacturerObjects]", f"SupportedObjects={len(man)}"]
        + [f"{n}=0x{i:04X}" for n, i in enumerate(man, 1)]
        + [""]
    )
    for index in sorted({i for i, _ in objects}):
        subs = sorted(s for i, s in objects if i == index)
        if subs == [0]:
            out += _var(f"{index:04X}", index, 0, objects)
        else:
            out += [
                f"[{index:04X}]",
                f"ParameterName=Object {index:04X}",
                "ObjectType=0x9",
                f"SubNumber={len(subs)}",
                "",
            ]
            for s in subs:
                out += _var(f"{index:04X}sub{s}", index, s, objects)
    return "\n".join(out) + "\n"


def _var(section: str, index: int, sub: int, objects: dict) -> list[str]:
    size, access, default, lo, hi = objects[(index, sub)]
    lines = [
        f"[{section}]",
        f"ParameterName=Entry {index:04X}:{sub}",
        "ObjectType=0x7",
        f"DataType={TYPES[size]}",
        f"AccessType={ACCESS[access]}",
        f"DefaultValue={default.decode() if isinstance(default, bytes) else default if isinstance(default, str) else hex(default)}",
        "PDOMapping=0",
    ]
    if lo is not None:
        lines += [f"LowLimit={lo}", f"HighLimit={hi}"]
    return lines + [""]


def encode(size, value) -> bytes:
    return value if size is None else value.to_bytes(size, "little")


def initial(size, default, node_id: int):
    """An entry's value at boot: a ``"$NODEID+0x80"`` default is the offset plus the node-ID."""
    if isinstance(default, str):
        return encode(size, int(default.split("+", 1)[1], 0) + node_id)
    return encode(size, default)


class TinySlave:
    objects = OBJECTS
    sdo_timeout = 0.3  # a stalled segmented transfer is aborted after this

    def __init__(self, channel: str, node_id: int = 5, faults: set[str] | None = None):
        self.node_id = node_id
        self.faults = faults or set()
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.values = {
            key: initial(spec[0], spec[2], node_id) for key, spec in self.objects.items()
        }
        self.state = 0x7F
        self.toggle = 0
        self.transfer = None  # (kind, index, sub, data, toggle, last_activity)
        self.next_heartbeat = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def __enter__(self):
        self._thread.start()
        self._boot()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(2)
        self.bus.shutdown()

    # -- plumbing ------------------------------------------------------------
    def send(self, cob: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))

    def _loop(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.002)
            if msg is not None:
                self._handle(msg)
            self._timers()

    def _timers(self) -> None:
        now = time.monotonic()
        period = int.from_bytes(self.values[(0x1017, 0)], "little") / 1000
        if period and self.next_heartbeat is not None and now >= self.next_heartbeat:
            self.send(0x700 + self.node_id, bytes([self.state]))
            self.next_heartbeat = now + period * (2.0 if "late_heartbeat" in self.faults else 1.0)
        if self.transfer and now - self.transfer[5] > self.sdo_timeout:
            self._abort(self.transfer[1], self.transfer[2], 0x05040000)

    def _boot(self, comm_only: bool = False) -> None:
        for key, spec in self.objects.items():
            if not comm_only or key[0] < 0x2000:
                self.values[key] = initial(spec[0], spec[2], self.node_id)
        self.toggle = 0
        self.transfer = None
        self.send(0x700 + self.node_id, b"\x00")
        self.state = 0x7F
        self.next_heartbeat = None

    def _handle(self, msg: can.Message) -> None:
        cob, data = msg.arbitration_id, bytes(msg.data)
        if cob == 0 and len(data) >= 2 and data[1] in (0, self.node_id):
            self._nmt(data[0])
        elif cob == 0x700 + self.node_id and msg.is_remote_frame:
            self.send(cob, bytes([self.toggle << 7 | self.state]))
            if "stuck_guard_toggle" not in self.faults:
                self.toggle ^= 1
        elif cob == 0x600 + self.node_id and len(data) == 8 and not msg.is_remote_frame:
            if self.state != 0x04 or "sdo_in_stopped" in self.faults:
                self._sdo(data)

    def _nmt(self, cs: int) -> None:
        states = {0x01: 0x05, 0x02: 0x04, 0x80: 0x7F}
        if cs in states:
            self.state = states[cs]
        elif cs in (0x81, 0x82):
            self._boot(comm_only=cs == 0x82)

    # -- SDO server ------------------------------------------------------------
    def _abort(self, index: int, sub: int, code: int) -> None:
        self.transfer = None
        self.send(0x580 + self.node_id, struct.pack("<BHBI", 0x80, index, sub, code))

    def _reply(self, data: bytes) -> None:
        self.send(0x580 + self.node_id, data.ljust(8, b"\0"))

    def _lookup(self, index: int, sub: int) -> int | None:
        if (index, sub) in self.objects:
            return None
        if any(i == index for i, _ in self.objects):
            return 0x06020000 if "wrong_abort_missing_sub" in self.faults else 0x06090011
        return 0x06020000

    def _sdo(self, data: bytes) -> None:
        b0 = data[0]
        ccs = b0 >> 5
        index, sub = struct.unpack_from("<HB", data, 1)
        if b0 == 0x80:
            self.transfer = None
            return
        if ccs == 2:
            self._initiate_upload(index, sub)
        elif ccs == 3:
            self._upload_segment(b0)
        elif ccs == 1:
            self._initiate_download(index, sub, data)
        elif ccs == 0:
            self._download_segment(data)
        else:
            self._abort(index, sub, 0x05040001)

    def _initiate_upload(self, index: int, sub: int) -> None:
        error = self._lookup(index, sub)
        if error:
            return self._abort(index, sub, error)
        value = self.values[(index, sub)]
        if len(value) <= 4:
            return self._reply(
                bytes([0x43 | (4 - len(value)) << 2]) + struct.pack("<HB", index, sub) + value
            )
        self.transfer = ("up", index, sub, value, 0, time.monotonic())
        self._reply(bytes([0x41]) + struct.pack("<HBI", index, sub, len(value)))

    def _upload_segment(self, b0: int) -> None:
        if not self.transfer or self.transfer[0] != "up":
            return self._abort(0, 0, 0x05040001)
        kind, index, sub, rest, toggle, _ = self.transfer
        t = (b0 >> 4) & 1
        if t != toggle and "no_toggle_check" not in self.faults:
            return self._abort(index, sub, 0x05030000)
        chunk, rest = rest[:7], rest[7:]
        last = not rest
        self._reply(bytes([t << 4 | (7 - len(chunk)) << 1 | int(last)]) + chunk)
        self.transfer = None if last else (kind, index, sub, rest, toggle ^ 1, time.monotonic())

    def _initiate_download(self, index: int, sub: int, data: bytes) -> None:
        error = self._lookup(index, sub)
        if error:
            return self._abort(index, sub, error)
        b0 = data[0]
        if b0 & 0x02:
            n = (b0 >> 2) & 3 if b0 & 0x01 else 0
            self._store(index, sub, data[4 : 8 - n])
            return
        if self.objects[(index, sub)][1] != "rw":
            return self._abort(index, sub, 0x06010002)
        self.transfer = ("down", index, sub, b"", 0, time.monotonic())
        self._reply(bytes([0x60]) + struct.pack("<HB", index, sub))

    def _download_segment(self, data: bytes) -> None:
        if not self.transfer or self.transfer[0] != "down":
            return self._abort(0, 0, 0x05040001)
        kind, index, sub, got, toggle, _ = self.transfer
        t = (data[0] >> 4) & 1
        if t != toggle:
            return self._abort(index, sub, 0x05030000)
        got += data[1 : 8 - ((data[0] >> 1) & 7)]
        if not data[0] & 1:
            self.transfer = (kind, index, sub, got, toggle ^ 1, time.monotonic())
            return self._reply(bytes([0x20 | t << 4]))
        self.transfer = None
        if self._store(index, sub, got, reply=False):
            self._reply(bytes([0x20 | t << 4]))

    def _store(self, index: int, sub: int, value: bytes, reply: bool = True) -> bool:
        """Write an entry; an abort is sent and False returned if the value is refused."""
        size, access, _, lo, hi = self.objects[(index, sub)]
        number = int.from_bytes(value, "little")
        error = None
        if access != "rw":
            error = 0x06010002
        elif size is not None and len(value) != size:
            error = 0x06070012 if len(value) > size else 0x06070013
        elif hi is not None and number > hi:
            error = 0x06090031
        elif lo is not None and number < lo:
            error = 0x06090032
        if error:
            self._abort(index, sub, error)
            return False
        self.values[(index, sub)] = value
        if index == 0x1017:
            self.next_heartbeat = time.monotonic() + number / 1000 if number else None
        if reply:
            self._reply(bytes([0x60]) + struct.pack("<HB", index, sub))
        return True
