"""Reading the device's EDS (or DCF) as real files come: tolerant where CiA 306 leaves a key
optional, precise where a file is wrong.

canopen's ``import_od`` does the reading; before it, every line is checked here so that
(a) what real files contain passes: an optional key left empty (CANopenNode's shipped
``DS301_profile.eds`` has ``VendorNumber=`` and ``ProductNumber=``), keys in any letter case,
a byte-order mark, Latin-1 text, ``$NODEID`` before or after the offset with or without blanks
(``$NODEID+0x180``, ``0x180 + $NODEID``); (b) a value that cannot be right stops the run with
the file, line and key named (``dev.eds line 7: [DeviceInfo] VendorNumber = 'x': not a number``)
instead of canopen's bare ``invalid literal for int()``.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import canopen

# [DeviceInfo] keys canopen reads as numbers (CiA 306 §4.5.1: all optional but the names)
DEVICE_INFO_NUMBERS = {
    "vendornumber": "VendorNumber",
    "productnumber": "ProductNumber",
    "revisionnumber": "RevisionNumber",
    "simplebootupmaster": "SimpleBootUpMaster",
    "simplebootupslave": "SimpleBootUpSlave",
    "granularity": "Granularity",
    "dynamicchannelssupported": "DynamicChannelsSupported",
    "groupmessaging": "GroupMessaging",
    "nrofrxpdo": "NrOfRXPDO",
    "nroftxpdo": "NrOfTXPDO",
    "lss_supported": "LSS_Supported",
    **{f"baudrate_{r}": f"BaudRate_{r}" for r in (10, 20, 50, 125, 250, 500, 800, 1000)},
}
# object-section keys that must be numbers when present
OBJECT_NUMBERS = {
    "objecttype": "ObjectType",
    "datatype": "DataType",
    "subnumber": "SubNumber",
    "pdomapping": "PDOMapping",
    "nrofentries": "NrOfEntries",
    "compactsubobj": "CompactSubObj",
}
# keys canopen reads with their exact spelling
OBJECT_KEYS = {
    "parametername": "ParameterName",
    "accesstype": "AccessType",
    "defaultvalue": "DefaultValue",
    "parametervalue": "ParameterValue",
    "lowlimit": "LowLimit",
    "highlimit": "HighLimit",
    "storagelocation": "StorageLocation",
    **OBJECT_NUMBERS,
}
OBJECT_SECTION = re.compile(r"^([0-9A-Fa-f]{4})(sub[0-9A-Fa-f]+|Name|Value)?$")
NODEID = re.compile(r"^\s*(?:\$NODEID\s*\+\s*(.+?)|(.+?)\s*\+\s*\$NODEID)\s*$", re.IGNORECASE)
ACCESS = {"ro", "wo", "rw", "rwr", "rww", "const"}


class EdsError(ValueError):
    """The EDS cannot be read; the message names the file, line and key."""


@dataclass
class EdsReading:
    od: canopen.ObjectDictionary
    notes: list[str] = field(default_factory=list)  # what was tolerated, with file and line


def _number(text: str) -> bool:
    try:
        int(text, 0)
    except ValueError:
        try:
            int(text, 10)  # a decimal with leading zeros ("0010") is no Python literal
        except ValueError:
            return False
    return True


def _normalise_number(text: str) -> str:
    try:
        int(text, 0)
        return text
    except ValueError:
        return str(int(text, 10))


def load_eds(path: str | Path, node_id: int) -> EdsReading:
    """The object dictionary of the EDS at ``path`` for ``node_id``; :class:`EdsError` names
    file, line and key of what cannot be right, and ``notes`` what was passed over."""
    name = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise EdsError(f"EDS {name}: cannot be read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # the encoding CiA 306 files were written in for years
    notes: list[str] = []
    out: list[str] = []
    section = ""
    for lineno, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        where = f"EDS {name} line {lineno}"
        if not stripped or stripped[0] in ";#":
            out.append(line)
            continue
        if stripped.startswith("["):
            if not stripped.endswith("]"):
                raise EdsError(f"{where}: section header {stripped!r} lacks its ']'")
            section = stripped[1:-1].strip()
            out.append(f"[{section}]")
            continue
        if "=" not in stripped:
            raise EdsError(f"{where}: [{section}] {stripped!r} is neither a section nor key=value")
        key, value = (part.strip() for part in stripped.split("=", 1))
        value = (
            value.split(";", 1)[0].strip() if ";" in value and not value.startswith('"') else value
        )
        low = key.lower()
        if section.lower() == "deviceinfo" and low in DEVICE_INFO_NUMBERS:
            key = DEVICE_INFO_NUMBERS[low]
            if not value:
                notes.append(f"{where}: [DeviceInfo] {key} is empty: read as absent")
                continue
            if not _number(value):
                raise EdsError(f"{where}: [DeviceInfo] {key} = {value!r}: not a number")
            value = _normalise_number(value)
        elif OBJECT_SECTION.match(section) and low in OBJECT_KEYS:
            key = OBJECT_KEYS[low]
            if low in OBJECT_NUMBERS:
                if not value:
                    notes.append(f"{where}: [{section}] {key} is empty: read as absent")
                    continue
                if not _number(value):
                    raise EdsError(f"{where}: [{section}] {key} = {value!r}: not a number")
                value = _normalise_number(value)
            elif low == "accesstype":
                if value.lower() not in ACCESS:
                    raise EdsError(
                        f"{where}: [{section}] AccessType = {value!r}: not one of {', '.join(sorted(ACCESS))}"
                    )
                value = value.lower()
            elif low in ("defaultvalue", "parametervalue", "lowlimit", "highlimit"):
                if not value and low != "defaultvalue":
                    notes.append(f"{where}: [{section}] {key} is empty: read as absent")
                    continue
                m = NODEID.match(value)
                if m:
                    value = f"$NODEID+{(m.group(1) or m.group(2)).strip()}"
        elif section.lower() == "dummyusage" and not value:
            notes.append(f"{where}: [DummyUsage] {key} is empty: read as 0")
            continue
        out.append(f"{key}={value}")
    cleaned = io.StringIO("\n".join(out) + "\n")
    cleaned.name = "cleaned.dcf" if name.lower().endswith(".dcf") else "cleaned.eds"
    try:
        od = canopen.import_od(cleaned, node_id)
    except Exception as exc:  # canopen's own message, with the file named
        raise EdsError(f"EDS {name}: {type(exc).__name__}: {exc}") from None
    return EdsReading(od, notes)
