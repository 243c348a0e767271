"""Model presets: the channel declarations of common ICP DAS M-7000 modules.

``model: M-7055D`` in a topology expands to the groups below. Addresses are PDU
(0-based) addresses; ICP DAS tables give them 1-based ("Base 1"): coil 00001 is coil 0,
10033 is discrete input 32, 30001 is input register 0, 40001 is holding register 0.
Where each map comes from is in docs/modbus.md ("Model presets").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Preset:
    model: str
    description: str
    groups: tuple[dict[str, Any], ...]  # ChannelGroup fields
    source: str


def _di(count: int) -> dict[str, Any]:
    return {"kind": "di", "table": "discrete_inputs", "address": 32, "count": count}


def _do(count: int) -> dict[str, Any]:
    return {"kind": "do", "table": "coils", "address": 0, "count": count}


def _ai(count: int) -> dict[str, Any]:
    return {"kind": "ai", "table": "input_registers", "address": 0, "count": count, "type": "int16"}


def _ao(count: int) -> dict[str, Any]:
    return {
        "kind": "ao",
        "table": "holding_registers",
        "address": 0,
        "count": count,
        "type": "int16",
    }


_MAPPING = "ICP DAS, M-7000 Address Mapping (Base 1), rev. 1.13"

PRESETS: dict[str, Preset] = {
    p.model.upper(): p
    for p in (
        Preset("M-7002", "4 AI, 5 DI, 4 DO", (_ai(4), _di(5), _do(4)), f"{_MAPPING}, M-7002 table"),
        Preset(
            "M-7017R",
            "8 AI (differential)",
            (_ai(8),),
            "ICP DAS, I-7017R-A5/M-7017R-A5 Quick Start: 30001~30008 AI channels 0-7",
        ),
        Preset(
            "M-7017R-A5",
            "8 AI",
            (_ai(8),),
            "ICP DAS, I-7017R-A5/M-7017R-A5 Quick Start: 30001~30008 AI channels 0-7",
        ),
        Preset(
            "M-7024",
            "4 AO",
            (_ao(4),),
            "ICP DAS, I-7021/22/24 M-7022/24/28 User Manual §3 (03/06/16 address output channels from 0)",
        ),
        Preset(
            "M-7050D", "7 DI, 8 DO", (_di(7), _do(8)), f"{_MAPPING}: DO from 00001, DI from 10033"
        ),
        Preset("M-7052D", "8 DI", (_di(8),), f"{_MAPPING}: DI from 10033"),
        Preset(
            "M-7055D", "8 DI, 8 DO", (_di(8), _do(8)), f"{_MAPPING}: DO from 00001, DI from 10033"
        ),
        Preset(
            "M-7060D",
            "4 DI, 4 relay DO",
            (_di(4), _do(4)),
            f"{_MAPPING}: DO from 00001, DI from 10033",
        ),
    )
}


def find(model: str) -> Preset | None:
    return PRESETS.get(model.strip().upper())


def names() -> list[str]:
    return [p.model for p in PRESETS.values()]
