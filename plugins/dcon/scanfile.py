"""Scan files: the DCON modules found on a line, as ``fieldgate scan dcon --output`` writes
them and a ``modules: auto`` back records its start scan.

A back with ``modules: auto`` builds its modules from the line when it starts. A scan file
stands in for the line where there is none: ``fieldgate validate``, both EDS generators and
``--simulate`` take the modules from it (named by the back's ``scan.file`` or
``--scan-file``), so the EDS can be made before the line is reachable. JSON, one object::

    {"format": "fieldgate-dcon-scan/1", "port": "/dev/ttyUSB0", "scanned": "2026-...Z",
     "addresses": "1-15", "baudrates": [9600], "checksums": [false],
     "modules": [{"address": 1, "baudrate": 9600, "checksum": false, "name": "7055D",
                  "firmware": "B1.3", "model": "I-7055", "type_code": 64, "data_format": "hex"}]}

``model`` is null for a module fieldgate does not support (it is left out of the image).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fieldgate.persist import write_atomic

from .formats import DataFormat
from .profiles import find_profile
from .tables import TABLES

FORMAT = "fieldgate-dcon-scan/1"


class ScanFileError(ValueError):
    """A scan file that cannot be read or is not one (the message is one line)."""


@dataclass(frozen=True)
class ScannedModule:
    address: int
    baudrate: int
    checksum: bool
    name: str  # what $AAM answered
    firmware: str = ""
    model: str | None = None  # the supported model it is, None: not supported
    type_code: int = 0x40
    data_format: str = "engineering"  # from $AA2 (meaningful for analog modules)

    @property
    def analog(self) -> bool:
        profile = find_profile(self.model) if self.model else None
        return bool(profile and (profile.ai or profile.ao))

    def describe(self) -> str:
        text = f"{self.model or 'unsupported ' + repr(self.name)} at {self.address}"
        if self.analog:
            profile = find_profile(self.model or "")
            key = profile and (profile.ai_table or profile.ao_table)
            rng = TABLES[key].get(self.type_code) if key else None
            text += (
                f" (type 0x{self.type_code:02X} {rng.label if rng else '?'}, {self.data_format})"
            )
        return text

    def module_config(self) -> dict[str, Any] | None:
        """The topology entry of the module (``DconModuleConfig`` fields); None when unsupported.
        Analog modules keep the type code and format they reported: the image's scaling."""
        if self.model is None:
            return None
        entry: dict[str, Any] = {"address": self.address, "model": self.model}
        if self.analog:
            entry["type_code"] = self.type_code
            entry["data_format"] = self.data_format
        return entry

    def image_key(self) -> tuple[object, ...]:
        """What shapes the image and its scaling: a change of any of it changes the image."""
        return (self.address, self.model, self.type_code if self.analog else None)


@dataclass
class ScanFile:
    port: str
    modules: list[ScannedModule]
    addresses: str = "1-15"
    baudrates: list[int] = field(default_factory=lambda: [9600])
    checksums: list[bool] = field(default_factory=lambda: [False])
    scanned: str = field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))

    def supported(self) -> list[ScannedModule]:
        return [m for m in sorted(self.modules, key=lambda m: m.address) if m.model is not None]

    def to_json(self) -> str:
        doc = {
            "format": FORMAT,
            "port": self.port,
            "scanned": self.scanned,
            "addresses": self.addresses,
            "baudrates": self.baudrates,
            "checksums": self.checksums,
            "modules": [asdict(m) for m in sorted(self.modules, key=lambda m: m.address)],
        }
        return json.dumps(doc, indent=1) + "\n"

    def write(self, path: Path) -> None:
        write_atomic(path, self.to_json().encode(), make_parents=False)

    @classmethod
    def read(cls, path: Path) -> ScanFile:
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ScanFileError(
                f"scan file {path}: cannot read it: {exc.strerror or exc}"
            ) from None
        except UnicodeDecodeError:
            raise ScanFileError(f"scan file {path}: not UTF-8 text") from None
        try:
            return cls.from_json(json.loads(text))
        except json.JSONDecodeError as exc:
            raise ScanFileError(
                f"scan file {path}: not JSON ({exc.msg}, line {exc.lineno})"
            ) from None
        except ScanFileError as exc:
            raise ScanFileError(f"scan file {path}: {exc}") from None

    @classmethod
    def from_json(cls, doc: Any) -> ScanFile:
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ScanFileError(f'not a DCON scan file (no "format": "{FORMAT}")')
        modules = doc.get("modules")
        if not isinstance(modules, list):
            raise ScanFileError('"modules" must be a list')
        found, seen = [], set()
        for n, entry in enumerate(modules):
            module = _module(entry, n)
            if module.address in seen:
                raise ScanFileError(f"modules[{n}]: address {module.address} appears twice")
            seen.add(module.address)
            found.append(module)
        try:
            return cls(
                port=str(doc.get("port", "")),
                modules=found,
                addresses=str(doc.get("addresses", "1-15")),
                baudrates=[int(b) for b in doc.get("baudrates", [9600])],
                checksums=[bool(c) for c in doc.get("checksums", [False])],
                scanned=str(doc.get("scanned", "")),
            )
        except (TypeError, ValueError) as exc:
            raise ScanFileError(f"bad probe settings: {exc}") from None


def _module(entry: Any, n: int) -> ScannedModule:
    where = f"modules[{n}]"
    if not isinstance(entry, dict):
        raise ScanFileError(f"{where} is not an object")
    try:
        address, baudrate = int(entry["address"]), int(entry.get("baudrate", 9600))
        type_code = int(entry.get("type_code", 0x40))
    except (KeyError, TypeError, ValueError):
        raise ScanFileError(f"{where}: address, baudrate and type_code must be numbers") from None
    if not 0 <= address <= 255 or not 0 <= type_code <= 0xFF:
        raise ScanFileError(f"{where}: address 0..255 and type_code 0..255")
    model = entry.get("model")
    profile = None if model is None else find_profile(str(model))
    if model is not None and profile is None:
        raise ScanFileError(f"{where}: unknown DCON module {model!r}")
    data_format = str(entry.get("data_format", "engineering"))
    if data_format not in {f.label for f in DataFormat}:
        raise ScanFileError(f"{where}: data_format {data_format!r} is not a DCON data format")
    return ScannedModule(
        address,
        baudrate,
        bool(entry.get("checksum", False)),
        str(entry.get("name", "")),
        str(entry.get("firmware", "")),
        None if profile is None else profile.model,
        type_code,
        data_format,
    )


def differences(before: list[ScannedModule], now: list[ScannedModule]) -> list[str]:
    """What changed on the line, one line each, in address order (empty: the same image)."""
    old = {m.address: m for m in before if m.model is not None}
    new = {m.address: m for m in now if m.model is not None}
    out = []
    for address in sorted(old.keys() | new.keys()):
        a, b = old.get(address), new.get(address)
        if b is None:
            out.append(f"{a.describe() if a else address} is missing")
        elif a is None:
            out.append(f"{b.describe()} is new")
        elif a.image_key() != b.image_key():
            out.append(f"{a.describe()} is now {b.describe()}")
    return out
