"""Helpers for the DeviceNet engine tests: a small process image, hex frames, a fake clock."""

from __future__ import annotations

from fieldgate.can.frame import Frame
from fieldgate.image import ChannelSpec, ErrorMode, Kind, ProcessImage, Source, channel_id
from fieldgate.layout import default_order
from fieldgate.plugins.devicenet.assembly import Assemblies
from fieldgate.plugins.devicenet.engine import DeviceNetSlave, Settings

SLAVE, MASTER = 0x09, 0x0A


def image_with(modules: list[tuple[int, dict[Kind, int]]], back: str = "io") -> ProcessImage:
    """``[(address, {Kind.DI: 16, ...}), ...]`` -> a process image; outputs go to 0 / 0x55 on master loss."""
    image = ProcessImage(clock=lambda: 0.0)
    for address, counts in modules:
        for kind, count in counts.items():
            for i in range(count):
                mode = (
                    ErrorMode.to(False if kind.is_digital else 0x55)
                    if kind.is_output
                    else ErrorMode()
                )
                image.add(
                    ChannelSpec(
                        channel_id(back, address, kind, i),
                        kind,
                        Source(back, address, i),
                        error_mode=mode,
                    )
                )
    return image


def seed_image() -> ProcessImage:
    """16 DI and 16 DO on one module: the seed's 2-byte poll (``FF FF`` out, ``FF DF`` in)."""
    return image_with([(1, {Kind.DI: 16, Kind.DO: 16})])


def frame(text: str) -> Frame:
    """``"44E 0A 4B 03 01 07 0A"`` -> Frame."""
    parts = text.split()
    return Frame(int(parts[0], 16), bytes.fromhex("".join(parts[1:])))


def show(frames) -> list[str]:
    return [f"{f.can_id:03X} {f.data.hex(' ').upper()}".strip() for f in frames]


class Rig:
    """Drive a slave with a fake clock; boots and finishes the duplicate MAC check unless told not to."""

    def __init__(
        self, image: ProcessImage | None = None, online: bool = True, now: float = 100.0, **settings
    ):
        self.image = image or seed_image()
        self.assemblies = Assemblies(self.image, default_order(self.image))
        settings.setdefault("mac_id", SLAVE)
        settings.setdefault("product_name", "ICPDAS-I7241D")
        self.slave = DeviceNetSlave(Settings(**settings), self.assemblies)
        self.master_events: list[tuple[bool, str]] = []
        self.faults: list[str] = []
        self.slave.on_master(lambda ok, reason: self.master_events.append((ok, reason)))
        self.slave.on_fault(self.faults.append)
        self.now = now
        self.boot = show(self.slave.boot(now))
        if online:
            self.advance(2.0)
            assert self.slave.state == "online"

    def send(self, text: str) -> list[str]:
        return show(self.slave.receive(frame(text), self.now))

    def advance(self, seconds: float) -> list[str]:
        """Move the clock, running every deadline on the way in order."""
        end, out = self.now + seconds, []
        while True:
            due = self.slave.next_deadline()
            if due is None or due > end:
                break
            self.now = max(self.now, due)
            out += show(self.slave.tick(self.now))
        self.now = end
        return out + show(self.slave.tick(end))

    def explicit(self, body: str) -> str:
        """One request from master 0x0A on G2/4 (in fragments when longer than a frame) -> the
        response data."""
        if len(bytes.fromhex(body)) > 7:
            return self.explicit_long(body)
        out = self.send(f"44C 0A {body}")
        assert len(out) == 1 and out[0].startswith("44B "), out
        return out[0][4:]

    def explicit_long(self, body: str) -> str:
        """A request longer than one frame, in acknowledged fragments of 6 bytes (each
        acknowledged ``44B 8A C<n> 00``) -> the response data."""
        data = bytes.fromhex(body)
        chunks = [data[i : i + 6] for i in range(0, len(data), 6)]
        out: list[str] = []
        for n, chunk in enumerate(chunks):
            kind = 0x00 if n == 0 else 0x80 if n == len(chunks) - 1 else 0x40
            out = self.send(f"44C 8A {kind | n:02X} {chunk.hex(' ')}")
            assert out[0] == f"44B 8A {0xC0 | n:02X} 00", out
        assert len(out) == 2, out
        return out[1][4:]

    def allocate(self, choice: int) -> str:
        out = self.send(f"44E 0A 4B 03 01 {choice:02X} 0A")
        assert len(out) == 1, out
        return out[0]
