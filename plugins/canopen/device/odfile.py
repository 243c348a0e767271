"""An object dictionary read from an EDS or DCF, and the CiA 301 services it configures.

The file is read with canopen's CiA 306 import (``canopen.import_od``, node-ID 0, so a
``$NODEID+0x180`` default keeps its base and stays relative). A DCF's ``ParameterValue``
replaces the ``DefaultValue`` of its entry: the device starts from the configured value.

:func:`node_settings` gives the CiA 301 node of the file (heartbeat producer 0x1017 and
consumers 0x1016, guarding 0x100C/0x100D, SYNC 0x1005/0x1006/0x1019 through the SYNC
service's own objects, EMCY history depth 0x1003, SDO server channels 0x1200.., identity
0x1000/0x1018 and 0x1008-0x100A) and :func:`pdo_defaults` its PDO set (0x1400-/0x1600-,
0x1800-/0x1A00-). :func:`file_entries` lists every entry of the file, which the front lays
over the node's own objects (:func:`.front.build_device_node`).
"""

from __future__ import annotations

import configparser
import io
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import canopen
from canopen import objectdictionary as cod

from ..cia301.builder import Identity
from ..cia301.pdo.defaults import COB_INVALID, PdoDefault

log = logging.getLogger("fieldgate.canopen.device")

RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
PDO_AREA = range(0x1400, 0x1C00)
MANDATORY = (0x1000, 0x1001, 0x1018)
NO_RTR = 1 << 30  # sub 1 bit 30: no remote request of this PDO
EMPTY_KEY = re.compile(r"^[ \t]*[A-Za-z_0-9]+[ \t]*=[ \t]*(;.*)?$", re.MULTILINE)


class DeviceFileError(ValueError):
    """The EDS/DCF cannot be served: not readable, not CiA 306, a mandatory object missing."""


@dataclass
class DeviceFile:
    path: Path
    model: cod.ObjectDictionary
    dcf: bool
    lss: bool = False
    notes: list[str] = field(default_factory=list)

    def has(self, index: int, sub: int = 0) -> bool:
        obj = self.model.indices.get(index)
        if obj is None:
            return False
        return sub == 0 if isinstance(obj, cod.ODVariable) else sub in obj.subindices

    def var(self, index: int, sub: int = 0) -> cod.ODVariable | None:
        obj = self.model.indices.get(index)
        if obj is None:
            return None
        if isinstance(obj, cod.ODVariable):
            return obj if sub == 0 else None
        found: cod.ODVariable | None = obj.subindices.get(sub)
        return found

    def integer(self, index: int, sub: int = 0, fallback: int = 0) -> int:
        var = self.var(index, sub)
        value = getattr(var, "default", None) if var is not None else None
        return value if isinstance(value, int) else fallback

    def text(self, index: int, fallback: str = "") -> str:
        var = self.var(index)
        value = getattr(var, "default", None) if var is not None else None
        return value if isinstance(value, str) else fallback

    def subs(self, index: int) -> list[int]:
        """The sub-indices 1.. of a record or array (empty for a VAR or a missing object)."""
        obj = self.model.indices.get(index)
        if obj is None or isinstance(obj, cod.ODVariable):
            return []
        return sorted(s for s in obj.subindices if s)


def read_device_file(path: str | Path) -> DeviceFile:
    """The file's dictionary (DeviceFileError: one line naming the file and the problem)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="latin-1")
    except OSError as exc:
        raise DeviceFileError(f"{path}: cannot read it ({exc})") from None
    # CiA 306 lets optional keys be empty (VendorNumber=, a string's DefaultValue=); canopen's
    # reader trips on them: an empty key is a key not given
    source = io.StringIO(EMPTY_KEY.sub("", text))
    source.name = path.name
    try:
        model = canopen.import_od(source, 0)
    except (configparser.Error, ValueError, KeyError) as exc:
        raise DeviceFileError(f"{path}: not a CiA 306 EDS/DCF ({exc})") from None
    missing = [f"0x{i:04X}" for i in MANDATORY if i not in model.indices]
    if missing:
        raise DeviceFileError(f"{path}: CiA 301 mandatory object(s) {', '.join(missing)} missing")
    dcf = path.suffix.lower() == ".dcf"
    device = DeviceFile(path, model, dcf, lss=bool(model.device_information.LSS_supported))
    for var in _variables(model):
        value = getattr(var, "value", None)
        if value is not None:  # a DCF's ParameterValue: the configured value
            var.default = value
            raw = getattr(var, "value_raw", None)
            var.default_raw = raw  # type: ignore[attr-defined]  # (canopen sets it on import, undeclared)
            var.relative = isinstance(raw, str) and "$NODEID" in raw.upper()
    return device


def _variables(model: cod.ObjectDictionary) -> list[cod.ODVariable]:
    out: list[cod.ODVariable] = []
    for obj in model.values():
        if isinstance(obj, cod.ODVariable):
            out.append(obj)
        else:
            out += list(obj.subindices.values())
    return out


def file_entries(device: DeviceFile) -> list[cod.ODVariable]:
    return _variables(device.model)


def identity(device: DeviceFile, serial: int | None) -> Identity:
    return Identity(
        device_type=device.integer(0x1000),
        vendor_id=device.integer(0x1018, 1),
        product_code=device.integer(0x1018, 2),
        revision=device.integer(0x1018, 3),
        serial=device.integer(0x1018, 4) if serial is None else serial,
        device_name=device.text(0x1008, device.model.device_information.product_name or ""),
        hardware_version=device.text(0x1009),
        software_version=device.text(0x100A),
    )


def sdo_server_count(device: DeviceFile) -> int:
    count = 1
    while device.has(0x1200 + count):
        count += 1
    return count


def _pdo_count(device: DeviceFile, comm: int) -> int:
    numbers = [i - comm for i in device.model.indices if comm <= i < comm + 0x200]
    return max(numbers) + 1 if numbers else 0


def pdo_defaults(device: DeviceFile, transmit: bool) -> list[PdoDefault]:
    """The PDO set of one direction as the file defines it (at least one PDO: a direction the
    file has none of gets one invalid PDO, which the front hides)."""
    comm, mapping = (TPDO_COMM, TPDO_MAP) if transmit else (RPDO_COMM, RPDO_MAP)
    out: list[PdoDefault] = []
    for n in range(max(1, _pdo_count(device, comm))):
        cob_var = device.var(comm + n, 1)
        if cob_var is None:
            out.append(PdoDefault(None, False, 255 if transmit else 254))
            continue
        raw = device.integer(comm + n, 1, COB_INVALID)
        count = device.integer(mapping + n, 0)
        entries = [device.integer(mapping + n, s) for s in range(1, count + 1)]
        out.append(
            PdoDefault(
                raw & 0x7FF,
                not raw & COB_INVALID,
                device.integer(comm + n, 2, 255 if transmit else 254),
                device.integer(comm + n, 3),
                device.integer(comm + n, 5),
                [e for e in entries if e],
                absolute=not bool(getattr(cob_var, "relative", False)),
                flags=raw & NO_RTR,
            )
        )
    return out


def rpdo_timing(device: DeviceFile) -> bool:
    """RPDOs list sub 3/5 (inhibit time, event timer) in the file."""
    return any(
        device.has(i, 5) or device.has(i, 3)
        for i in device.model.indices
        if RPDO_COMM <= i < RPDO_COMM + 0x200
    )
