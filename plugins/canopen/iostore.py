"""Store / restore (0x1010 / 0x1011) of the I/O device's parameters.

The node's store service saves plain dictionary values; the PDO parameters and the
CiA 401 settings live in the PDO engine and the process image, so they are saved as
the store's ``io401`` section when 0x1010 is written ("save": sub 1 all, 2
communication = PDO parameters, 3 application = CiA 401 settings) and forgotten when
0x1011 is written ("load"). They come back at the next reset: PDO parameters at reset
communication, CiA 401 settings (0x6002, 0x6206/0x6207, 0x6208, 0x6421-0x6426,
0x6443/0x6444) at reset node.

The section carries a fingerprint of the layout (channels and styles): after the
module set changes, the saved parameters are ignored and the defaults used (the
NA-9161 discards its stored settings when modules are added or removed).
"""

from __future__ import annotations

import hashlib
import logging

from .abort import SdoAbort
from .store import AREAS, LOAD, SAVE

log = logging.getLogger("fieldgate.canopen.iostore")

SECTION = "io401"
STORED_APPLICATION = (0x6002, 0x6206, 0x6207, 0x6208, 0x6421, 0x6423, 0x6424, 0x6425, 0x6426, 0x6443, 0x6444)


class IoStore:
    def __init__(self, io) -> None:
        self.io = io
        self.node = None
        lay = io.layout
        text = "|".join([io.settings.style, str(io.settings.count), str(io.settings.compressed), str(io.settings.mapping_closed)] + [
            ",".join(c.id if c is not None else "-" for c in b) for b in lay.di_bytes + lay.do_bytes] + [c.id for c in lay.ai + lay.ao])
        self.fingerprint = hashlib.sha256(text.encode()).hexdigest()[:16]

    def attach(self, node) -> None:
        self.node = node
        # listeners also see reloads of the defaults: act on the signatures only
        node.od.on_write(0x1010, lambda index, sub, value: self._save(sub) if value == SAVE else None)
        node.od.on_write(0x1011, lambda index, sub, value: self._forget(sub) if value == LOAD else None)

    def _store(self):
        try:
            return self.node.service("store")
        except KeyError:
            return None

    def _section(self) -> dict:
        store = self._store()
        doc = store.section(SECTION) if store is not None else None
        return doc if isinstance(doc, dict) and doc.get("fingerprint") == self.fingerprint else {"fingerprint": self.fingerprint}

    def _save(self, sub: int) -> None:
        communication, application = AREAS.get(sub, (False, False))
        doc = self._section()
        if communication:
            doc["pdo"] = self.io.engine.parameters()
        if application:
            doc["application"] = {f"{obj.index:04X}.{e.sub:02X}": e.get() for obj in self.io.directory if obj.index in STORED_APPLICATION for e in obj.entries if e.writable}
        self._store().put_section(SECTION, doc)

    def _forget(self, sub: int) -> None:
        communication, application = AREAS.get(sub, (False, False))
        doc = self._section()
        if communication:
            doc.pop("pdo", None)
        if application:
            doc.pop("application", None)
        self._store().put_section(SECTION, doc)

    # -- at reset -------------------------------------------------------------------------
    def load_communication(self) -> None:
        store = self._store()
        doc = store.section(SECTION) if store is not None else None
        if not isinstance(doc, dict):
            return
        if doc.get("fingerprint") != self.fingerprint:
            log.warning("stored I/O parameters belong to another module set; defaults used")
            return
        self.io.engine.load_parameters(doc.get("pdo", []))

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
        doc = self._section()
        for key, value in doc.get("application", {}).items():
            try:
                index, sub = (int(part, 16) for part in key.split("."))
                self.io.directory.entry(index, sub).write(int(value))
            except (SdoAbort, ValueError, TypeError):
                log.warning("stored value %s = %r does not fit; default kept", key, value)
