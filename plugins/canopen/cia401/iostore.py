"""Store / restore (0x1010 / 0x1011) of the I/O device's parameters.

The node's store service saves plain dictionary values; the PDO parameters and the
CiA 401 settings live in the PDO engine and the process image, so they are kept as the
store's ``io401`` section, updated inside each 0x1010 "save" (sub 1 all, 2
communication = PDO parameters, 3 application = CiA 401 settings) and 0x1011 "load"
through the store's area hook: one file, one atomic write per command. They come back
at the next reset: PDO parameters at reset communication, CiA 401 settings (0x6002,
0x6206/0x6207, 0x6208, 0x6421-0x6426, 0x6443/0x6444) at reset node.

The ``na9161`` FnBus settings (0x4500:2 data mode, :3 slot flags) are the ``fnbus`` part
of the application area: saved with sub 1 or 3, read back once at power-on.

The layout settings (style, PDO count, packing as configured) are added to the store's fingerprint:
after the module set or the layout changes, the store drops everything it holds and the
defaults are used (the NA-9161 discards its stored settings when modules are added or
removed).
"""

from __future__ import annotations

import logging
from typing import Any, Protocol

from ..cia301.abort import SdoAbort
from ..cia301.entries import Directory
from ..cia301.pdo.engine import PdoEngine
from ..cia301.service import NodeHost
from ..cia301.store import StoreService
from ..na9161.fnbus import FnBusRegister
from .layouts import IoLayout

log = logging.getLogger("fieldgate.canopen.iostore")

SECTION = "io401"
STORED_APPLICATION = (
    0x6002,
    0x6206,
    0x6207,
    0x6208,
    0x6421,
    0x6423,
    0x6424,
    0x6425,
    0x6426,
    0x6443,
    0x6444,
)


class _IoSettings(Protocol):
    @property
    def style(self) -> str: ...
    @property
    def count(self) -> int: ...
    @property
    def compressed(self) -> bool: ...
    @property
    def mapping_closed(self) -> bool: ...


class StoredIo(Protocol):
    """What the store hook reads of the CiA 401 device (:class:`.iodevice.IoDevice` is one)."""

    @property
    def settings(self) -> _IoSettings: ...
    @property
    def layout(self) -> IoLayout: ...
    @property
    def engine(self) -> PdoEngine | None: ...
    @property
    def directory(self) -> Directory: ...
    @property
    def fnbus(self) -> FnBusRegister | None: ...


class IoStore:
    def __init__(self, io: StoredIo) -> None:
        self.io = io
        self.store: StoreService | None = None  # the node's store service, if it has one
        settings, lay = io.settings, io.layout
        self.fingerprint_part = "|".join(
            [
                settings.style,
                str(settings.count),
                str(settings.compressed),
                str(settings.mapping_closed),
            ]
            + [
                ",".join(c.id if c is not None else "-" for c in b)
                for b in lay.di_bytes + lay.do_bytes
            ]
            + [c.id for c in lay.ai + lay.ao]
        )

    def attach(self, node: NodeHost) -> None:
        try:
            self.store = node.service("store")
        except KeyError:
            return
        if self.store is not None:
            self.store.add_fingerprint(self.fingerprint_part)
            self.store.add_area_hook(self._area_command)

    def _section(self) -> dict[str, Any]:
        doc = self.store.section(SECTION) if self.store is not None else None
        return doc if isinstance(doc, dict) else {}

    def _area_command(self, communication: bool, application: bool, saving: bool) -> None:
        """Inside a store "save" (``saving``) or "load" of the given areas."""
        doc = self._section()
        if communication:
            doc.pop("pdo", None)
            if saving and self.io.engine is not None:
                keep = self.store is not None and self.store.keep_node_id_entries
                doc["pdo"] = self.io.engine.parameters(keep_node_id=keep)
        if application:
            doc.pop("application", None)
            doc.pop("fnbus", None)
            if saving and self.io.fnbus is not None:
                doc["fnbus"] = self.io.fnbus.settings()
            if saving:
                doc["application"] = {
                    f"{obj.index:04X}.{e.sub:02X}": e.get()
                    for obj in self.io.directory
                    if obj.index in STORED_APPLICATION
                    for e in obj.entries
                    if e.writable
                }
        if self.store is not None:  # (the hook is only added when there is a store)
            self.store.set_section(SECTION, doc)

    # -- at reset -------------------------------------------------------------------------
    def fnbus_settings(self) -> object:
        return self._section().get("fnbus")

    def load_communication(self) -> None:
        records = self._section().get("pdo")
        if isinstance(records, list) and self.io.engine is not None:
            self.io.engine.load_parameters(records)

    def load_application(self) -> None:
        """Reset node: every stored CiA 401 setting back to its default, then the stored values."""
        for obj in self.io.directory:
            if obj.index in STORED_APPLICATION:
                for e in obj.entries:
                    if e.writable and e.default is not None:
                        try:
                            e.write(int(e.default))
                        except SdoAbort:
                            pass
        stored = self._section().get("application")
        for key, value in stored.items() if isinstance(stored, dict) else ():
            try:
                index, sub = (int(part, 16) for part in key.split("."))
                self.io.directory.entry(index, sub).write(int(value))
            except (SdoAbort, ValueError, TypeError):
                log.warning("stored value %s = %r does not fit; default kept", key, value)
