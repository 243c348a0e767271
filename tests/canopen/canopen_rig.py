"""Helpers for the CANopen engine tests: a seed-like node, hex frames, a fake clock."""

from __future__ import annotations

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame
from fieldgate.plugins.canopen.cia301.builder import Identity, NodeSettings, build_node


def frame(text: str) -> Frame:
    """``"601 2F 00 14 02 05 00 00 00"`` or ``"701 RTR"`` -> Frame."""
    parts = text.split()
    if parts[1:2] == ["RTR"]:
        return Frame(int(parts[0], 16), b"", rtr=True, dlc=0)
    return Frame(int(parts[0], 16), bytes.fromhex("".join(parts[1:])))


def show(frames) -> list[str]:
    return [
        f"{f.can_id:03X} {f.data.hex(' ').upper()}".strip() if not f.rtr else f"{f.can_id:03X} RTR"
        for f in frames
    ]


def seed_node(node_id: int | None, **settings):
    """A node (``node_id`` given: the manuals' vectors use 1) with the I-7232D examples' objects: 0x1008 = "CPS_DCON\\0", an 0x1400 stand-in."""
    identity = settings.pop(
        "identity", Identity(device_type=0x000F0191, device_name="CPS_DCON\x00", vendor_id=0x1234)
    )
    node = build_node(NodeSettings(node_id=node_id, identity=identity, **settings))
    node.od.add_record(
        0x1400,
        "RxPDO1 communication (test stand-in)",
        [
            (1, "COB-ID", dt.UNSIGNED32, "rw", 0x200, {"relative": True}),
            (2, "Transmission type", dt.UNSIGNED8, "rw", 0xFF),
        ],
    )
    node.od.add_variable(0x2100, "test string", dt.VISIBLE_STRING, "rw", "", max_size=64)
    node.od.add_variable(0x2101, "test domain", dt.DOMAIN, "rw", b"", max_size=4096)
    node.od.add_variable(0x2102, "test limited", dt.INTEGER16, "rw", 0, minimum=-100, maximum=1000)
    node.od.add_variable(0x2103, "test write-only", dt.UNSIGNED8, "wo", 0)
    return node


class Rig:
    """Drive a node with a fake clock: ``rig.send("601 40 00 14 00 00 00 00 00")``."""

    def __init__(self, node, now: float = 0.0):
        self.node = node
        self.now = now
        self.boot = show(node.boot(now))

    def send(self, text_or_frame) -> list[str]:
        f = frame(text_or_frame) if isinstance(text_or_frame, str) else text_or_frame
        return show(self.node.receive(f, self.now))

    def advance(self, seconds: float) -> list[str]:
        """Move the clock, running every deadline on the way in order."""
        end = self.now + seconds
        out = []
        while True:
            due = self.node.next_deadline()
            if due is None or due > end:
                break
            self.now = max(self.now, due)
            out += show(self.node.tick(self.now))
        self.now = end
        return out + show(self.node.tick(end))

    def sdo(self, text: str) -> str:
        out = self.send("601 " + text)
        assert len(out) == 1, out
        return out[0][4:]
