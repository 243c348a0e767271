"""Which profiles a device's EDS and identity call for: ``--profile all``.

The CiA profiles run where the device's EDS says it supports them (CiA 301 always; CiA 305
LSS where ``[DeviceInfo] LSS_Supported=1``; CiA 401 where 0x1000 names profile 401; the
store profile where 0x1010 or 0x1011 exist). The device-specific profiles run where the
device says it is such a device: its identity object 0x1018 (vendor-ID) or its name (0x1008,
else the EDS ``ProductName``) matches the products the profile was written from. The
master-fit ``delta-as300`` runs only when named. Every profile named with ``--profile`` runs.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from .framework import CIA_PROFILES, MASTER_PROFILES, OPT_IN


@dataclass(frozen=True)
class DeviceFacts:
    """What the EDS and the device say they are, read once before any case."""

    vendor_id: int | None = None
    product_code: int | None = None
    name: str = ""  # 0x1008, else the EDS ProductName
    lss_supported: bool = False
    device_profile: int | None = None  # 0x1000 bits 0-15 (the EDS default, else read)
    has_store: bool = False


# device-specific profile -> (vendor-IDs, a pattern on the product name), from the manuals:
# seed-000/-001 (I-7232D, I-7231D; the manuals' SDO examples name "CPS_DCON", the tables
# "I-8x21"), seed-004 (CREVIS NA-9161, vendor-ID 0x029D)
ICPDAS_NAMES = re.compile(r"I-?723[12]D|I-8x21|CPS_DCON", re.IGNORECASE)
DEVICE_MATCH: dict[str, tuple[tuple[int, ...], re.Pattern[str]]] = {
    "seed": ((), ICPDAS_NAMES),
    "icpdas": ((), ICPDAS_NAMES),
    "na9161": ((0x029D,), re.compile(r"NA-?9161", re.IGNORECASE)),
}


def cia_supported(facts: DeviceFacts) -> dict[str, str]:
    """Each CiA profile: why it runs (starts with "runs") or why not."""
    out = {p: "runs: CiA 301, every device" for p in CIA_PROFILES}
    out["lss"] = (
        "runs: EDS LSS_Supported=1"
        if facts.lss_supported
        else "left out: EDS [DeviceInfo] does not set LSS_Supported=1 (CiA 305)"
    )
    out["cia401"] = (
        "runs: 0x1000 names CiA 401"
        if facts.device_profile == 401
        else f"left out: 0x1000 names profile {facts.device_profile}, not CiA 401"
    )
    out["store"] = (
        "runs: EDS lists 0x1010/0x1011"
        if facts.has_store
        else "left out: EDS lists neither 0x1010 nor 0x1011"
    )
    return out


def device_match(profile: str, facts: DeviceFacts) -> str | None:
    """Why ``profile`` fits the device (vendor-ID or name), or None."""
    if profile not in DEVICE_MATCH:
        return None
    vendors, names = DEVICE_MATCH[profile]
    if facts.vendor_id is not None and facts.vendor_id in vendors:
        return f"runs: vendor-ID 0x{facts.vendor_id:08X}"
    if facts.name and names.search(facts.name):
        return f"runs: device name {facts.name!r}"
    return None


def chosen_profiles(facts: DeviceFacts) -> dict[str, str]:
    """Every profile of ``--profile all`` with why it runs or is left out."""
    out = cia_supported(facts)
    who = f"vendor-ID {'?' if facts.vendor_id is None else f'0x{facts.vendor_id:08X}'}, name {facts.name!r}"
    for profile in OPT_IN:
        if profile in MASTER_PROFILES:
            out[profile] = "left out: a master-fit profile, runs when named"
        else:
            out[profile] = (
                device_match(profile, facts) or f"left out: the device ({who}) is not one"
            )
    return out
