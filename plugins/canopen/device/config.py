"""The ``canopen-device`` front's configuration: a bus, a node-ID, an EDS/DCF, hooks, bindings.

YAML::

    fronts:
      - name: pack
        type: canopen-device
        interface: socketcan
        channel: can0
        node_id: 12
        eds: battery.eds          # or a .dcf; relative to the topology file
        hooks: battery_hooks.py   # or mypkg.battery, or an entry point of fieldgate.canopen_hooks
        bind:                     # entries that carry I/O of the process image
          "0x6000:1": io/m1/di0   # input channel -> the entry follows it (TPDO events)
          "0x6200:1": io/m1/do0   # entry written by SDO/RPDO -> the output channel

Everything CiA 301 configures (heartbeat, guarding, SYNC, EMCY, PDOs, SDO channels, the
identity) comes from the file; see docs/canopen-device.md.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError

from fieldgate.can.front import CanBusConfig
from fieldgate.topology import FrontConfig

from .hooks import HookError, load_setup
from .odfile import DeviceFileError, read_device_file

ENTRY = re.compile(r"^\s*(0x[0-9a-fA-F]{1,4}|\d+)\s*(?::\s*(0x[0-9a-fA-F]{1,2}|\d+))?\s*$")


OUTPUT_ID = re.compile(r"/(do|ao)\d+$")


def parse_entry(text: str) -> tuple[int, int]:
    """``"0x6000:1"`` (index:sub, sub 0 when left out) -> (0x6000, 1); ValueError otherwise."""
    match = ENTRY.match(text)
    if match is None:
        raise ValueError(f"{text!r}: write an entry as 'index:sub', e.g. '0x6000:1'")
    index, sub = int(match.group(1), 0), int(match.group(2) or "0", 0)
    if index > 0xFFFF or sub > 0xFF:
        raise ValueError(f"{text!r}: index 0..0xFFFF, sub-index 0..255")
    return index, sub


def _resolved(value: str, info: ValidationInfo) -> str:
    path = Path(value)
    if not path.is_absolute():
        path = Path((info.context or {}).get("base_dir") or Path.cwd()) / path
    return str(path)


class CanopenDeviceConfig(FrontConfig, CanBusConfig):
    type: Literal["canopen-device"] = "canopen-device"
    node_id: int | None = Field(
        ...,
        ge=1,
        le=127,
        description="node-ID 1..127, required; null = unconfigured, wait for LSS (the file must support LSS)",
    )
    eds: str = Field(
        description="the device's EDS or DCF (CiA 306), relative to the topology file; a DCF's ParameterValue replaces the DefaultValue"
    )
    hooks: str | None = Field(
        None,
        description="Python hooks: a file (x.py, relative to the topology file), a module (mypkg.battery) or an entry point of fieldgate.canopen_hooks; its setup(device) registers read/write callbacks",
    )
    bind: dict[str, str] = Field(
        default_factory=dict,
        description="entry ('0x6000:1') -> process-image channel: an input channel sets the entry (TPDO events), an entry written by SDO or RPDO writes an output channel",
    )
    hook_timeout_ms: int = Field(
        500,
        ge=10,
        le=60_000,
        description="an SDO transfer waits this long for a hook, then aborts 0800 0020 (write) / 0800 0024 (read)",
    )
    hook_workers: int = Field(
        4, ge=1, le=64, description="threads the hooks run on (one call per entry at a time)"
    )
    serial: int | None = Field(
        None, ge=0, le=0xFFFFFFFF, description="0x1018:4 serial number; default: the file's"
    )
    lss: bool | None = Field(
        None, description="serve LSS (CiA 305); default: the file's LSS_Supported"
    )
    sdo_timeout_ms: int = Field(
        1000, ge=10, le=60_000, description="server-side SDO transfer timeout"
    )
    store_file: str | None = Field(
        None,
        description="0x1010/0x1011 store file (relative to the state dir); default <front name>.canopen.json",
    )
    lss_store_file: str | None = Field(
        None,
        description="LSS store file (relative to the state dir); default <front name>.lss.json",
    )

    @field_validator("eds")
    @classmethod
    def _eds_path(cls, value: str, info: ValidationInfo) -> str:
        return _resolved(value, info)

    @field_validator("hooks")
    @classmethod
    def _hooks_path(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value is not None and (value.endswith(".py") or "/" in value):
            return _resolved(value, info)
        return value

    @field_validator("bind")
    @classmethod
    def _entries(cls, value: dict[str, str]) -> dict[str, str]:
        for key in value:
            parse_entry(key)
        return value

    @model_validator(mode="after")
    def _file(self) -> CanopenDeviceConfig:
        try:
            device = read_device_file(self.eds)
        except DeviceFileError as exc:
            raise PydanticCustomError(
                "canopen_device", str(exc).replace("{", "{{").replace("}", "}}"), {"loc": ("eds",)}
            ) from None
        for key in self.bind:
            index, sub = parse_entry(key)
            if not device.has(index, sub):
                raise PydanticCustomError(
                    "canopen_device",
                    f"bind: {key} is no entry of {Path(self.eds).name}",
                    {"loc": ("bind",)},
                )
        return self

    def written_outputs(self) -> list[str] | None:
        """The bound output channels (named ``.../doN`` / ``.../aoN``): this front writes no other."""
        return [cid for cid in self.bind.values() if OUTPUT_ID.search(cid)]

    def check(self, topology: Any) -> list[tuple[tuple[Any, ...], str]]:
        """Bound channels exist; the hook module loads (``validate`` imports it, as ``run`` does)."""
        ids = {c.id for c in topology.channel_specs}
        issues: list[tuple[tuple[Any, ...], str]] = [
            (("bind", key), f"{cid!r} is no channel of this topology")
            for key, cid in self.bind.items()
            if cid not in ids
        ]
        if self.hooks is not None:
            try:
                load_setup(self.hooks)
            except HookError as exc:
                issues.append((("hooks",), str(exc)))
        return issues
