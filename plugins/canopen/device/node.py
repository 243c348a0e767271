"""The node of an EDS/DCF device: the CiA 301 engine configured from the file, the file's
objects laid over the engine's own, hooks and PDOs wired in. No I/O: the front
(:mod:`.front`) runs it on a bus, tests drive it with a fake clock.

How the file's dictionary becomes the node's (docs/canopen-device.md):

* the services the file calls for are built from its values (:mod:`.odfile`);
* every entry of the file replaces the engine's description of that entry (name, access,
  limits, default, PDO mapping) where both have it with the same data type; the engine
  keeps serving it (a write to 0x1017 still restarts the heartbeat). A file that makes an
  entry writable which the engine serves read-only keeps the engine's access;
* entries the engine does not have are served as plain values (stored by 0x1010 unless
  ``StorageLocation=RAM``); objects the engine keeps for its services but the file does
  not list are hidden (0602 0000, not in the EDS);
* mappable entries of the file (``PDOMapping=1``) are what the PDOs may map; the mapping
  objects are writable (dynamic mapping) unless the file says ``ro``/``const``.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, cast

from canopen import objectdictionary as cod

from ..cia301.builder import NodeSettings, build_node
from ..cia301.entries import _FORMATS, Directory, Entry, ObjectDef
from ..cia301.od_file import FileDictionary
from ..cia301.pdo.engine import PdoEngine
from ..cia301.pdo.service import PdoConfig, PdoService
from ..cia301.sdo import SdoServer
from ..cia301.service import NodeHost, Service
from ..cia301.store import StoreService
from ..cia305.lss import LssService, LssStore
from .hooks import DeviceApi, HookTable, Runner
from .odfile import (
    PDO_AREA,
    DeviceFile,
    file_entries,
    identity,
    pdo_defaults,
    rpdo_timing,
    sdo_server_count,
)

log = logging.getLogger("fieldgate.canopen.device")

_PERMISSIVE = {"const": 0, "ro": 1, "wo": 1, "rww": 2, "rwr": 2, "rw": 2}


class PdoStore(Service):
    """The PDO parameters in the store's ``pdo`` section (0x1010:1/2 save them, 0x1011:1/2
    forget them), loaded again at each reset communication."""

    name = "device_pdo_store"

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        self.store: StoreService = node.service("store")
        self.store.add_area_hook(self._area)

    def _engine(self) -> PdoEngine | None:
        engine: PdoEngine | None = self.node.service("pdo").engine
        return engine

    def _area(self, communication: bool, application: bool, saving: bool) -> None:
        if not communication:
            return
        engine = self._engine()
        self.store.set_section(
            "pdo", engine.parameters() if saving and engine is not None else None
        )

    def on_reset_communication(self, now: float) -> None:
        records = self.store.section("pdo")
        engine = self._engine()
        if isinstance(records, list) and engine is not None:
            engine.load_parameters(records)


class DeviceNode:
    """One device: ``node`` (the engine), ``table`` (hooks), ``api`` (what hooks get)."""

    def __init__(
        self,
        device: DeviceFile,
        node_id: int | None,
        *,
        name: str = "device",
        store_path: Path | None = None,
        lss_store_path: Path | None = None,
        lss: bool | None = None,
        bitrate: int | None = None,
        sdo_timeout_s: float = 1.0,
        serial: int | None = None,
        hook_timeout_s: float = 0.5,
        runner: Runner | None = None,
        setup: Callable[[DeviceApi], None] | None = None,
        run: Callable[[Callable[[], None]], None] | None = None,
        clock: Callable[[], float] | None = None,
    ):
        self.device = device
        self.table = HookTable(hook_timeout_s)
        if runner is not None:
            self.table.runner = runner
        self.notes: list[str] = list(device.notes)
        self.directory = Directory(self._mappable_objects())
        settings = self._settings(node_id, store_path, sdo_timeout_s, serial)
        self.od = FileDictionary()
        self.node = node = build_node(settings, name=name, od=self.od)
        self.clock = clock or (lambda: node.now)
        if lss if lss is not None else device.lss:
            node.add_service(
                LssService(
                    bitrate=bitrate, store=LssStore(lss_store_path) if lss_store_path else None
                )
            )
        serial_var = device.var(0x1018, 4)
        if serial is not None and serial_var is not None:  # this unit's: served, in its EDS
            serial_var.default = serial
            serial_var.default_raw = f"0x{serial:08X}"  # type: ignore[attr-defined]  # (undeclared)
        node.add_service(PdoStore())
        self._lay_over()
        self.api = DeviceApi(
            self.table, lambda: node.node_id, run or (lambda action: action()), self
        )
        if setup is not None:
            setup(self.api)
        self._install_hooks()
        self.table.finished = self._finished

    # -- building -------------------------------------------------------------------------
    def _settings(
        self, node_id: int | None, store_path: Path | None, sdo_timeout_s: float, serial: int | None
    ) -> NodeSettings:
        f = self.device
        consumers = [f.integer(0x1016, s) for s in f.subs(0x1016)]
        history = len(f.subs(0x1003))
        return NodeSettings(
            node_id=node_id,
            identity=identity(f, serial),
            heartbeat_ms=f.integer(0x1017) if f.has(0x1017) else None,
            guard_time_ms=f.integer(0x100C),
            life_time_factor=f.integer(0x100D),
            heartbeat_consumers=len(consumers),
            consumer_heartbeats=tuple(consumers),
            error_behaviour=f.integer(0x1029, 1, 0) if f.has(0x1029, 1) else 0,
            emcy_history=min(max(history, 1), 254),
            sdo_timeout_s=sdo_timeout_s,
            sdo_servers=sdo_server_count(f),
            sync_cob_id=(f.integer(0x1005, 0, 0x80) & 0x7FF) or 0x80,
            store_path=store_path,
            fingerprint=hashlib.sha256(f.path.read_bytes()).hexdigest()[:16],
            pdo=PdoConfig(
                self.directory,
                pdo_defaults(f, transmit=True),
                pdo_defaults(f, transmit=False),
                start_policy="none",
                rpdo_timing=rpdo_timing(f),
            ),
        )

    def _mappable_objects(self) -> list[ObjectDef]:
        """The file's entries a PDO may map, read and written through the dictionary."""
        by_index: dict[int, list[Entry]] = {}
        names: dict[int, tuple[str, str]] = {}
        for var in file_entries(self.device):
            if var.index in PDO_AREA or not var.pdo_mappable or var.data_type not in _FORMATS:
                continue
            access = "rw" if var.access_type in ("rww", "rwr") else var.access_type
            writable = access in ("rw", "wo")
            by_index.setdefault(var.index, []).append(
                Entry(
                    var.subindex,
                    var.name,
                    var.data_type,
                    access,
                    partial(self.get, var.index, var.subindex),
                    partial(self._pdo_write, var.index, var.subindex) if writable else None,
                    mappable=True,
                    low=var.min,
                    high=var.max,
                )
            )
            parent = var.parent
            kind = "var" if isinstance(parent, cod.ObjectDictionary) else "record"
            names[var.index] = (
                getattr(parent, "name", var.name) if kind == "record" else var.name,
                kind,
            )
        return [ObjectDef(i, names[i][0], names[i][1], entries) for i, entries in by_index.items()]

    def _lay_over(self) -> None:
        od, model = self.od, self.od.model
        for index, obj in list(self.device.model.indices.items()):
            if index not in model.indices:
                od.add_object(obj)
                continue
            ours = model.indices[index]
            if isinstance(obj, cod.ODVariable) != isinstance(ours, cod.ODVariable):
                self.notes.append(
                    f"0x{index:04X}: the file's object type differs; the engine's is served"
                )
                continue
            for var in [obj] if isinstance(obj, cod.ODVariable) else list(obj.subindices.values()):
                self._adopt(var)
            if not isinstance(obj, cod.ODVariable):
                ours.name = obj.name
                if index in PDO_AREA and not isinstance(ours, cod.ODVariable):
                    for sub in set(ours.subindices) - set(obj.subindices):
                        od.drop_entry(index, sub)  # e.g. RPDO inhibit time the file lacks
        for var in file_entries(self.device):
            if (var.storage_location or "").upper() == "RAM":
                od.volatile.add((var.index, var.subindex))
        for index in list(model.indices):
            if index not in self.device.model.indices:
                od.hide(index)

    def _adopt(self, var: cod.ODVariable) -> None:
        od = self.od
        key = (var.index, var.subindex)
        if key in od:
            ours = od.variable(*key)
            if ours.data_type != var.data_type:
                self.notes.append(
                    f"0x{key[0]:04X}:{key[1]}: the file's data type differs; the engine's is served"
                )
                return
            if _PERMISSIVE.get(var.access_type, 0) > _PERMISSIVE.get(ours.access_type, 0):
                self.notes.append(
                    f"0x{key[0]:04X}:{key[1]}: {var.access_type} in the file, served {ours.access_type}"
                )
                var.access_type = ours.access_type
        od.adopt(var)

    def _install_hooks(self) -> None:
        od = self.node.od
        hooked_writes: set[int] = set()
        for var in file_entries(self.device):
            key = (var.index, var.subindex)
            if var.subindex == 0 and not isinstance(var.parent, cod.ObjectDictionary):
                continue  # a record's "highest sub-index supported" is the structure's, not a hook's
            if self.table.reader(var.index) is not None and var.readable and key in od:
                od.add_reader(*key, partial(self._sdo_read, *key))
                od.defers = True
            if self.table.writer(var.index) is not None and var.index not in hooked_writes:
                hooked_writes.add(var.index)
                od.add_validator(var.index, partial(self._sdo_write, var.index))
                od.defers = True

    # -- hooks at work ----------------------------------------------------------------------
    def _sdo_read(self, index: int, sub: int) -> Any:
        value = self.table.read(index, sub)
        self.node.od.set(index, sub, value, notify=False)  # (TypeError: answered 0606 0000)
        return value

    def _sdo_write(self, index: int, sub: int, value: Any) -> None:
        self.table.write(index, sub, value)

    def _finished(self, ticket: int) -> None:
        now = self.clock()
        for service in self.node.services:
            if isinstance(service, SdoServer) and service.resolve(ticket, now):
                return

    def _pdo_write(self, index: int, sub: int, value: Any) -> None:
        self.node.od.set(index, sub, value)
        self.table.pdo_written(index, sub, value)

    # -- DeviceActions (run on the loop) ---------------------------------------------------
    def get(self, index: int, sub: int) -> Any:
        return self.node.od.get(index, sub)

    def set(self, index: int, sub: int, value: Any) -> None:
        self.node.od.set(index, sub, value)
        self.trigger(index, sub)

    def trigger(self, index: int, sub: int) -> None:
        pdo = cast(PdoService, self.node.service("pdo"))
        pdo.object_changed(index, sub, self.clock())

    def raise_emcy(self, code: int, register: int, data: bytes) -> None:
        if self.node.emcy is not None:
            self.node.emcy.raise_error(code, register, data)

    def clear_emcy(self, code: int, data: bytes | None) -> None:
        if self.node.emcy is not None:
            self.node.emcy.clear_error(code, data)
