"""Store / restore parameters (0x1010 / 0x1011) persisted to one file.

* 0x1010 sub 1 (all), 2 (communication 0x1000-0x1FFF), 3 (application): writing the
  signature "save" (0x65766173, bytes ``73 61 76 65``) stores the current values of
  every writable, unbound entry of that area; any other value aborts 0800 0020.
  Reading gives 1 ("saves on command").
* 0x1011 sub 1/2/3: "load" (0x64616F6C) forgets the stored values of that area, so the
  defaults come back at the next reset node / reset communication (CiA 301); other
  values abort 0800 0020.
* The file (JSON) is written with :func:`fieldgate.persist.write_atomic`, so a crash
  mid-write keeps the previous copy. It carries a fingerprint of the module set (the
  front's channel list plus what services add with :meth:`add_fingerprint`, e.g. the
  I/O layout style): a store saved for another module set, or an unreadable one, is
  ignored as a whole (values and sections: defaults), logged once and reported with an
  EMCY once the node is pre-operational: corrupt store ``00 50 81 02 ..`` (the
  I-7232D's EEPROM error), other module set ``00 63 81 0C ..`` (0x6300 "data set").
  A successful save clears them. A device that announces running on defaults
  (``announce_defaults``, the NA-9161: "Changed HW configuration" at power-on until a save)
  sends ``00 63 81 0C`` once at power-on as an event (0x1001 stays 0 and 0x1003 does not
  keep it: nothing is wrong with a head on its defaults) while nothing was saved, or after a
  "load".
* ``keep_node_id_entries`` (the NA-9161, [AMBIG-24]): a "save" stores the node-ID-dependent
  entries (0x1014, the PDO COB-IDs) whatever their value, so after a node-ID change the
  stored values stay instead of following the new node-ID.
* A save that cannot be written (a read-only or full state directory) answers SDO abort
  0606 0000 and raises EMCY ``00 50 81 02`` (the I-7232D's "EEPROM access error"); a later
  save that works ends it.
* Services whose parameters do not live in the dictionary keep them as named sections
  of the same file: :meth:`add_area_hook` lets them update their section
  (:meth:`set_section`) inside each "save" / "load", so one atomic write carries
  everything; :meth:`section` reads it back.
"""

from __future__ import annotations

import base64
import hashlib
import json
import logging
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from canopen.objectdictionary import datatypes as dt

from fieldgate.persist import CorruptStore, read_json, write_atomic

from . import abort
from .abort import SdoAbort
from .nmt import NmtState
from .od import Setter, Value
from .service import ALL_STATES, NodeHost, Service

SAVE = 0x65766173
LOAD = 0x64616F6C
FORMAT = "fieldgate-canopen-store/1"
CORRUPT_CODE, CORRUPT_MFR = 0x5000, b"\x02"
OTHER_SET_CODE, OTHER_SET_MFR = 0x6300, b"\x0c"
AREAS = {1: (True, True), 2: (True, False), 3: (False, True)}

log = logging.getLogger("fieldgate.canopen.store")

AreaHook = Callable[
    [bool, bool, bool], None
]  # (communication, application, saving) inside a save / load


def _key(index: int, sub: int) -> str:
    return f"{index:04X}.{sub:02X}"


def _parse_key(text: str) -> tuple[int, int]:
    index, sub = text.split(".")
    return int(index, 16), int(sub, 16)


def _to_json(value: Value) -> Value | dict[str, str]:
    return {"b64": base64.b64encode(value).decode()} if isinstance(value, bytes) else value


def _from_json(value: Value | dict[str, str]) -> Value:
    return base64.b64decode(value["b64"]) if isinstance(value, dict) else value


def _ignoring_value(action: Callable[[int], None], sub: int) -> Setter:
    """A setter that runs ``action(sub)`` whatever value is written (the signature is checked first)."""
    return lambda value: action(sub)


class StoreService(Service):
    name = "store"
    active_states = ALL_STATES

    def __init__(
        self,
        path: str | Path | None,
        fingerprint: str = "",
        *,
        announce_defaults: bool = False,
        keep_node_id_entries: bool = False,
    ):
        super().__init__()
        self.path = Path(path) if path is not None else None
        self.announce_defaults = announce_defaults
        self.keep_node_id_entries = keep_node_id_entries
        self.on_defaults = True  # nothing saved (no file, or "load" since the last save)
        self.write_failed = False
        self._fingerprint_parts = [fingerprint]
        self._area_hooks: list[AreaHook] = []
        self.values: dict[tuple[int, int], Value] = {}
        self.sections: dict[str, object] = {}
        self.problem: tuple[int, bytes] | None = None
        self._reported = False

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        od = node.od
        for index, name, sig in (
            (0x1010, "Store parameters", SAVE),
            (0x1011, "Restore default parameters", LOAD),
        ):
            od.add_array(
                index,
                name,
                [
                    (s, ("all", "communication", "application")[s - 1], dt.UNSIGNED32, "rw", 1)
                    for s in AREAS
                ],
            )
            od.add_validator(index, partial(self._check_signature, sig))
            for sub in AREAS:
                od.bind(
                    index,
                    sub,
                    getter=lambda: 1,
                    setter=_ignoring_value(self.save if sig == SAVE else self.restore, sub),
                    thread_safe=True,
                )

    @property
    def fingerprint(self) -> str:
        """The front's module-set fingerprint, extended by what services added."""
        base, *added = self._fingerprint_parts
        return (
            hashlib.sha256("\n".join(self._fingerprint_parts).encode()).hexdigest()[:16]
            if added
            else base
        )

    def add_fingerprint(self, part: str) -> None:
        """A fact the stored data depend on beyond the channel list (call before :meth:`load`)."""
        self._fingerprint_parts.append(part)

    def add_area_hook(self, hook: AreaHook) -> None:
        """``hook(communication, application, saving)`` runs inside every "save" / "load" before the write."""
        self._area_hooks.append(hook)

    @staticmethod
    def _check_signature(expected: int, sub: int, value: int) -> None:
        if value != expected:
            raise SdoAbort(abort.CANNOT_STORE, "wrong signature")

    # -- file -------------------------------------------------------------------------------
    def load(self) -> None:
        """Read the file (before ``node.boot``): stored values become the reset values."""
        if self.path is None:
            return
        try:
            doc = read_json(self.path)
            if doc is None:
                return  # never saved: on defaults
            if not isinstance(doc, dict) or doc.get("format") != FORMAT:
                raise CorruptStore(f"{self.path}: not a {FORMAT} file")
            values = {_parse_key(k): _from_json(v) for k, v in doc.get("values", {}).items()}
            sections = dict(doc.get("sections", {}))
        except (CorruptStore, OSError, ValueError, TypeError, AttributeError, KeyError) as exc:
            self._problem(
                CORRUPT_CODE, CORRUPT_MFR, f"stored parameters unreadable, using defaults: {exc}"
            )
            return
        if doc.get("fingerprint") != self.fingerprint:
            self._problem(
                OTHER_SET_CODE,
                OTHER_SET_MFR,
                f"{self.path}: stored for another module set, using defaults",
            )
            return
        self.values = values
        self.sections = sections
        self.on_defaults = not doc.get("saved", True)  # (files of older releases: saved)
        self.node.od.set_stored(values)

    def _problem(self, code: int, mfr: bytes, text: str) -> None:
        log.warning("%s: %s", self.node.name, text)
        self.problem = (code, mfr)
        self.counters["load_problems"] += 1

    def _write(self, saved: bool) -> None:
        if self.path is None:
            raise SdoAbort(abort.CANNOT_STORE, "no store file configured")
        doc = {
            "format": FORMAT,
            "fingerprint": self.fingerprint,
            "saved": saved,
            "values": {_key(*k): _to_json(v) for k, v in sorted(self.values.items())},
            "sections": self.sections,
        }
        try:
            write_atomic(self.path, json.dumps(doc, indent=1, sort_keys=True).encode())
        except OSError as exc:
            log.error("%s: cannot write %s: %s", self.node.name, self.path, exc)
            self.counters["write_failures"] += 1
            self.write_failed = True
            if self.node.emcy is not None:  # the I-7232D's "EEPROM access error"
                self.node.emcy.raise_error(CORRUPT_CODE, 0x81, CORRUPT_MFR)
            raise SdoAbort(abort.HARDWARE_ERROR, str(exc)) from exc
        if self.write_failed:
            self.write_failed = False
            if self.node.emcy is not None:
                self.node.emcy.clear_error(CORRUPT_CODE, CORRUPT_MFR)

    # -- 0x1010 / 0x1011 ---------------------------------------------------------------------
    def save(self, sub: int = 1) -> None:
        communication, application = AREAS[sub]
        od = self.node.od
        keep = {
            k: v for k, v in self.values.items() if not _in_area(k[0], communication, application)
        }
        changed = {
            k: v
            for k, v in od.snapshot(communication, application).items()
            if v != od.default(var := od.variable(*k))
            or (self.keep_node_id_entries and var.relative)
        }
        self.values = {**keep, **changed}
        self._run_area_hooks(communication, application, True)
        self._write(saved=True)
        od.set_stored(self.values)
        self.on_defaults = False
        self.counters["saves"] += 1
        if self.problem is not None and self.node.emcy is not None:
            self.node.emcy.clear_error(self.problem[0], self.problem[1])
        self.problem = None

    def restore(self, sub: int = 1) -> None:
        communication, application = AREAS[sub]
        self.values = {
            k: v for k, v in self.values.items() if not _in_area(k[0], communication, application)
        }
        self._run_area_hooks(communication, application, False)
        self._write(saved=False)
        self.node.od.set_stored(self.values)
        self.on_defaults = True  # the defaults come back at the next power-on (announced then)
        self.counters["restores"] += 1

    def _run_area_hooks(self, communication: bool, application: bool, saving: bool) -> None:
        for hook in self._area_hooks:
            hook(communication, application, saving)

    def section(self, name: str, default: Any = None) -> Any:
        return self.sections.get(name, default)

    def set_section(self, name: str, value: Any) -> None:
        """Change a section in memory (from an area hook); the save / load in progress writes it."""
        self.sections[name] = value

    # -- reporting ------------------------------------------------------------------------------
    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        """At power-on (the first Pre-operational of the process): a store problem as an error,
        running on defaults as an event where the device announces it."""
        if new is not NmtState.PRE_OPERATIONAL or self._reported or self.node.emcy is None:
            return
        self._reported = True
        if self.problem is not None:
            self.node.emcy.raise_error(self.problem[0], 0x81, self.problem[1], now)
        elif self.announce_defaults and self.on_defaults:
            self.counters["defaults_announced"] += 1
            self.node.emcy.signal(OTHER_SET_CODE, 0x81, OTHER_SET_MFR, now, record=False)

    def status(self) -> dict[str, Any]:
        return {
            **self.counters,
            "file": str(self.path) if self.path else None,
            "stored_values": len(self.values),
            "problem": f"{self.problem[0]:04X}" if self.problem else None,
            "on_defaults": self.on_defaults,
            "write_failed": self.write_failed,
        }


def _in_area(index: int, communication: bool, application: bool) -> bool:
    is_comm = 0x1000 <= index <= 0x1FFF
    return (is_comm and communication) or (not is_comm and application)
