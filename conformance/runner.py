"""One call that runs a selection of cases against a device: the API behind the CLI and the tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import can

from .catalog import select
from .device import NMT_PREOP, Device
from .dnet import CHOICE_EXPLICIT, G2_UNCONNECTED, DnetDevice
from .framework import CaseResult, Context, Options, Timing, Verdict, run_cases
from .link import Link
from .outcome import DeviceSilent


@dataclass
class SuiteConfig:
    node_id: int
    eds: str
    profiles: list[str] = field(default_factory=list)
    patterns: list[str] = field(default_factory=list)
    timing: Timing = field(default_factory=Timing)
    options: Options = field(default_factory=Options)


def identity(device: Device) -> dict[str, str]:
    """What the device says it is (0x1008, 0x1018), for the report header; absent entries are left out."""
    out = {}
    for key, index, sub in (
        ("device name", 0x1008, 0),
        ("vendor-ID", 0x1018, 1),
        ("product code", 0x1018, 2),
        ("revision", 0x1018, 3),
        ("serial number", 0x1018, 4),
    ):
        if not device.has(index, sub):
            continue
        try:
            value = device.read(index, sub)
        except (
            Exception
        ):  # the header must not stop the run; od.read_all reports unreadable entries
            continue
        out[key] = value.rstrip("\0") if isinstance(value, str) else f"0x{value:08X}"
    return out


def run_suite(
    config: SuiteConfig,
    bus: can.BusABC | None = None,
    *,
    interface: str = "virtual",
    channel: str = "vcan0",
    bitrate: int | None = None,
    progress: Callable[[CaseResult], None] | None = None,
    on_start: Callable[[dict[str, str]], None] | None = None,
) -> list[CaseResult]:
    """Run the selected cases. Pass ``bus`` to reuse an open python-can bus (left open afterwards).
    ``on_start`` gets the device's identity once it answered; ``progress`` every result."""
    link = Link(bus) if bus is not None else Link.open(interface, channel, bitrate)
    try:
        device = Device.from_eds(link, config.node_id, config.eds, config.timing)
        ctx = Context(device, config.timing, config.options)
        device.nmt(NMT_PREOP)
        if not any(device.sdo_request(bytes([0x40, 0x00, 0x10, 0x00])) for _ in range(2)):
            raise DeviceSilent(
                f"node {config.node_id} does not answer an SDO read of 0x1000 on 0x{device.sdo_rx:03X}: wrong node-ID or bus, or the device is not running"
            )
        if on_start:
            on_start(identity(device))
        return run_cases(select(config.profiles, config.patterns), ctx, progress)
    finally:
        link.close()


def failed(results: list[CaseResult]) -> list[str]:
    return [r.case.id for r in results if r.verdict is Verdict.FAIL]


@dataclass
class DnetSuiteConfig:
    mac_id: int
    master_mac: int = 0  # the tester's own MAC ID (must be free on the bus)
    profiles: list[str] = field(default_factory=list)
    patterns: list[str] = field(default_factory=list)
    timing: Timing = field(default_factory=Timing)
    options: Options = field(default_factory=Options)


def dnet_identity(device: DnetDevice) -> dict[str, str]:
    """Identity object attributes for the report header; what cannot be read is left out."""
    out: dict[str, str] = {}
    try:
        device.allocate(CHOICE_EXPLICIT)
    except Exception:
        return out
    for key, attribute in (
        ("vendor", 1),
        ("device type", 2),
        ("product code", 3),
        ("serial number", 6),
        ("product name", 7),
    ):
        try:
            data = device.get(1, 1, attribute)
        except Exception:  # the header must not stop the run; the identity case reports it
            continue
        out[key] = (
            data[1 : 1 + data[0]].decode("latin-1")
            if attribute == 7 and data
            else f"0x{int.from_bytes(data, 'little'):X}"
        )
    device.settle()
    return out


def run_devicenet_suite(
    config: DnetSuiteConfig,
    bus: can.BusABC | None = None,
    *,
    interface: str = "virtual",
    channel: str = "vcan0",
    bitrate: int | None = None,
    progress: Callable[[CaseResult], None] | None = None,
    on_start: Callable[[dict[str, str]], None] | None = None,
) -> list[CaseResult]:
    """Run the selected DeviceNet cases against the slave at ``config.mac_id`` (see run_suite)."""
    link = Link(bus) if bus is not None else Link.open(interface, channel, bitrate)
    try:
        device = DnetDevice(link, config.mac_id, config.master_mac, config.timing)
        ctx = Context(device, config.timing, config.options)
        device.settle()
        if not device.wait_online(config.timing.bootup):
            raise DeviceSilent(
                f"MAC ID {config.mac_id} does not answer an Allocate on 0x{device.g2(G2_UNCONNECTED):03X}: wrong MAC ID or bus, or the device is not online"
            )
        if on_start:
            on_start(dnet_identity(device))
        return run_cases(
            select(config.profiles, config.patterns, protocol="devicenet"), ctx, progress
        )
    finally:
        link.close()
