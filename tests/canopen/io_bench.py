"""Test bench for the CiA 401 I/O device: a process image, wiring, and a Node on a fake clock.

Not a test module (no ``test_`` prefix); the I/O-device tests import it.
"""

from __future__ import annotations

from fieldgate.can.frame import Frame
from fieldgate.health import HealthRegistry, ModuleHealth
from fieldgate.image import ChannelSpec, DataType, ErrorMode, Kind, ProcessImage, Source, channel_id
from fieldgate.layout import default_order
from fieldgate.masters import MasterMonitor
from fieldgate.plugins.canopen.cia301.builder import Identity, NodeSettings, build_node
from fieldgate.plugins.canopen.cia401.iodevice import IoDevice, IoSettings

BACK = "bus"


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def make_image(modules, clock=None, *, dtypes=None) -> ProcessImage:
    """``modules``: (address, di, do, ai, ao[, si, so]) counts; ``dtypes``: {(address, kind): DataType}."""
    image = ProcessImage(clock or Clock())
    for address, *counts in modules:
        # four counts (DI, DO, AI, AO) or six (with SI, SO): pairing stops at the shorter side
        for kind, count in zip(
            (Kind.DI, Kind.DO, Kind.AI, Kind.AO, Kind.SI, Kind.SO), counts, strict=False
        ):
            for i in range(count):
                dtype = (dtypes or {}).get((address, kind))
                image.add(
                    ChannelSpec(
                        channel_id(BACK, address, kind, i),
                        kind,
                        Source(BACK, address, i),
                        dtype=dtype,
                    )
                )
    return image


def wire(
    image: ProcessImage,
    out_address: int,
    in_address: int,
    kind: Kind = Kind.DO,
    invert: bool = False,
) -> None:
    """Loop outputs of one module to inputs of another, like the manuals' demo benches."""
    in_kind = Kind.DI if kind is Kind.DO else Kind.AI

    def echo(change) -> None:
        ch = change.channel
        target = channel_id(BACK, in_address, in_kind, ch.source.index)
        if target in image:
            image.update_input(target, (not ch.value) if invert else ch.value)

    outs = [c for c in image.channels(kind=kind, module=out_address)]
    image.subscribe(echo, ids=[c.id for c in outs])
    for c in outs:
        target = channel_id(BACK, in_address, in_kind, c.source.index)
        if target in image:
            image.update_input(target, (not c.value) if invert else c.value)


class Bench:
    """A booted node (node-ID 1 by default) with the I/O device, driven frame by frame."""

    def __init__(
        self,
        image: ProcessImage,
        settings: IoSettings | None = None,
        *,
        node_id: int = 1,
        health: HealthRegistry | None = None,
        guard: tuple[int, int] = (0, 0),
        store_path=None,
        **io_options,
    ):
        self.clock = image.clock if isinstance(image.clock, Clock) else Clock()
        self.image = image
        self.health = health or HealthRegistry()
        self.masters = MasterMonitor(image)
        self.masters.register("can")
        self.io = IoDevice(
            settings or IoSettings(),
            image,
            default_order(image),
            origin="can",
            health=self.health,
            masters=self.masters,
            front="can",
            **io_options,
        )
        node_settings = NodeSettings(
            node_id=node_id,
            identity=Identity(device_type=self.io.device_type),
            guard_time_ms=guard[0],
            life_time_factor=guard[1],
            store_path=store_path,
            pdo=self.io.pdo_config,
        )
        self.node = build_node(node_settings)
        self.node.add_service(self.io)
        self.node.service("store").load()
        self.out: list[Frame] = self.node.boot(self.clock.t)

    # -- driving --------------------------------------------------------------------------
    def rx(self, can_id: int, data: bytes | str = b"", rtr: bool = False) -> list[str]:
        if isinstance(data, str):
            data = bytes.fromhex(data)
        frames = self.node.receive(Frame(can_id, data, rtr), self.clock.t)
        return [str(f) for f in frames + self.node.flush()]

    def nmt(self, cs: int) -> list[str]:
        return self.rx(0x000, bytes([cs, self.node.node_id]))

    def start(self) -> list[str]:
        return self.nmt(0x01)

    def sync(self) -> list[str]:
        return self.rx(0x080)

    def flush(self) -> list[str]:
        """What the adapter does on wakeup: run due timers and queued events, take the frames."""
        return [str(f) for f in self.node.tick(self.clock.t) + self.node.flush()]

    def advance(self, seconds: float) -> list[str]:
        """Move the clock, running every deadline on the way."""
        end = self.clock.t + seconds
        out: list[str] = []
        while True:
            due = self.node.next_deadline()
            if due is None or due > end:
                break
            self.clock.t = max(self.clock.t, due)
            out += [str(f) for f in self.node.tick(self.clock.t) + self.node.flush()]
        self.clock.t = end
        out += [str(f) for f in self.node.tick(end) + self.node.flush()]
        return out

    def sdo(self, request: str) -> str:
        """One expedited SDO exchange; returns the answer as 'xx xx ...'."""
        frames = self.rx(0x600 + self.node.node_id, request)
        answers = [f for f in frames if f.startswith(f"{0x580 + self.node.node_id:03X}")]
        assert len(answers) == 1, frames
        return answers[0].split("] ", 1)[1]

    def write(self, index: int, sub: int, value: int, size: int) -> str:
        cs = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
        req = bytes([cs, index & 0xFF, index >> 8, sub]) + value.to_bytes(
            size, "little", signed=value < 0
        ).ljust(4, b"\x00")
        return self.sdo(req.hex())

    def read(self, index: int, sub: int) -> str:
        return self.sdo(bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]).hex())

    def value(self, index: int, sub: int) -> int:
        return self.node.od.get(index, sub)


def demo_7232d(**options) -> Bench:
    """seed-000 demo: addr 1 8 DI, addr 3 8 DO (wired to addr 1), addr 4 1 AO (wired to addr 5), addr 5 1 AI."""
    image = make_image([(1, 8, 0, 0, 0), (3, 0, 8, 0, 0), (4, 0, 0, 0, 1), (5, 0, 0, 1, 0)])
    wire(image, 3, 1)
    wire(image, 4, 5, Kind.AO)
    return Bench(image, **options)


def demo_7231d(**options) -> Bench:
    """seed-001 demo: 0x01 I-7043 16 DO, 0x02 I-7053 16 DI (reads 1 when OFF), 0x03 I-7021 1 AO, 0x04 I-7012 1 DI 2 DO 1 AI."""
    image = make_image([(1, 0, 16, 0, 0), (2, 16, 0, 0, 0), (3, 0, 0, 0, 1), (4, 1, 2, 1, 0)])
    wire(image, 1, 2, invert=True)
    wire(image, 3, 4, Kind.AO)
    image.update_input(channel_id(BACK, 4, Kind.DI, 0), True)  # I-7012 DI0 is OFF: reads 1
    return Bench(image, **options)


def module_health(bench_health: HealthRegistry, address: int, back: str = BACK) -> ModuleHealth:
    return bench_health.add(ModuleHealth(back, address))


__all__ = [
    "BACK",
    "Bench",
    "Clock",
    "DataType",
    "ErrorMode",
    "Kind",
    "demo_7231d",
    "demo_7232d",
    "make_image",
    "module_health",
    "wire",
]
