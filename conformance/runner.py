"""One call that runs a selection of cases against a device: the API behind the CLI and the tests."""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from .catalog import select
from .device import NMT_PREOP, Device
from .dnet import CHOICE_EXPLICIT, G2_UNCONNECTED, DnetDevice
from .framework import Case, CaseResult, Context, Options, Timing, Verdict, run_cases
from .identity import DeviceFacts, chosen_profiles
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
    shuffle: int | None = None  # run the cases in an order shuffled with this seed


def identity(device: Device) -> dict[str, str]:
    """What the device says it is (0x1008, 0x1018), for the report header; absent entries are left out."""
    out = {}
    for key, index, sub in (
        ("device name", 0x1008, 0),
        ("vendor-ID", 0x1018, 1),
        ("product code", 0x1018, 2),
        ("revision", 0x1018, 3),
        ("serial number", 0x1018, 4),
        ("device type", 0x1000, 0),
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


def device_facts(device: Device, ident: dict[str, str]) -> DeviceFacts:
    """What selects the profiles of ``--profile all`` (:mod:`.identity`)."""
    info = device.od.device_information
    profile = device.od_default(0x1000, 0, -1)
    if profile < 0 and "device type" in ident:
        profile = int(ident["device type"], 16)
    return DeviceFacts(
        vendor_id=int(ident["vendor-ID"], 16) if "vendor-ID" in ident else None,
        product_code=int(ident["product code"], 16) if "product code" in ident else None,
        name=ident.get("device name") or (info.product_name or ""),
        lss_supported=bool(info.LSS_supported),
        device_profile=profile & 0xFFFF if profile >= 0 else None,
        has_store=device.has(0x1010) or device.has(0x1011),
    )


def order(cases: list[Case], seed: int | None) -> list[Case]:
    if seed is None:
        return cases
    shuffled = list(cases)
    random.Random(seed).shuffle(shuffled)
    return shuffled


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
        ident = identity(device)
        facts = device_facts(device, ident)
        header = dict(ident)
        if "all" in config.profiles:
            choice = chosen_profiles(facts)
            header["profiles"] = ", ".join(p for p, why in choice.items() if why.startswith("runs"))
            header["left out"] = "; ".join(
                f"{p} ({why.removeprefix('left out: ')})"
                for p, why in choice.items()
                if not why.startswith("runs") and p not in config.profiles
            )
        if device.eds_notes:
            header["EDS notes"] = "; ".join(device.eds_notes)
        if on_start:
            on_start(header)
        selected = order(select(config.profiles, config.patterns, facts=facts), config.shuffle)
        return run_cases(selected, ctx, progress)
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
