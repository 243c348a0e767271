"""The PDO service of a node (CiA 301 §7.2.2): the PDO engine on the node, like SDO or EMCY.

::

    settings = NodeSettings(node_id=5, pdo=PdoConfig(directory, tpdos, rpdos))
    node = build_node(settings)                 # adds PdoService(settings.pdo) last
    node.service("pdo").object_changed(0x6000, 1, now)   # an application event

What it does on the node:

* adds 0x1400-/0x1600-/0x1800-/0x1A00- (:mod:`.comm`, :mod:`.mapping`) to ``node.od``;
* passes RPDOs and TPDO remote requests to the engine (Operational only), SYNC, NMT
  state changes and timers; resets the PDOs to their defaults at reset communication;
* RPDO too short: EMCY 0x8210 (register 0x11, manufacturer byte 09), cleared by the next
  good RPDO;
* an application event from outside the node's calls (a DI change from a back: the
  profile calls :meth:`PdoService.object_changed`) queues the TPDOs that map it and wakes
  the node (``node.wake()``): whoever drives the node (the CAN adapter, through the
  front's wake-up) runs it in the next loop turn, as for an EMCY raised from outside.

The objects a PDO may map are the application's (``config.directory``: the CiA 401 and
manufacturer objects); :meth:`PdoService.serve` replaces them and the default PDO set
(the NA-9161's data mode, taking effect at a reset node).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from fieldgate.can.frame import Frame

from ..entries import Directory, bind_object
from ..nmt import NmtState
from ..service import NodeHost, Service
from .defaults import PdoDefault
from .engine import PdoEngine

LENGTH_ERROR_CODE, LENGTH_ERROR_REGISTER, LENGTH_ERROR_BYTES = 0x8210, 0x10, b"\x09"


@dataclass
class PdoConfig:
    """What the application gives a node's PDOs: the objects they may map, the default PDO
    set and how the PDOs behave (CiA 401's :class:`..cia401.iodevice.IoDevice` makes one)."""

    directory: Directory
    tpdos: list[PdoDefault]
    rpdos: list[PdoDefault]
    start_policy: Literal["async", "all", "none"] = "async"  # TPDOs sent entering Operational
    rpdo_timing: bool = False  # RPDOs have sub 3/5 (the NA-9161 lists them)
    granularity: int = 8  # 1: 1-bit mapping (CiA 401 bit objects)


class PdoService(Service):
    name = "pdo"
    active_states = frozenset({NmtState.OPERATIONAL})

    def __init__(self, config: PdoConfig):
        super().__init__()
        self.config = config
        self.engine: PdoEngine | None = None

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        self.engine = engine = self._new_engine(config=self.config)
        for obj in engine.objects():
            bind_object(node.od, obj)

    def serve(self, config: PdoConfig) -> None:
        """Other application objects and default PDOs (the parameter objects are built again)."""
        node = self.node
        if self.engine is not None:
            for obj in self.engine.objects():
                node.od.remove(obj.index)
        self.config = config
        self.engine = engine = self._new_engine(config=config)
        for obj in engine.objects():
            bind_object(node.od, obj)

    def _new_engine(self, config: PdoConfig) -> PdoEngine:
        node = self.node
        return PdoEngine(
            config.directory,
            config.tpdos,
            config.rpdos,
            node.node_id if node.configured else 0,
            start_policy=config.start_policy,
            rpdo_timing=config.rpdo_timing,
            clock=lambda: node.now,
            length_error=self._length_error,
            wakeup=node.wake,
            exists=lambda index, sub: (index, sub) in node.od,
            granularity=config.granularity,
        )

    def object_changed(self, index: int, sub: int, now: float) -> None:
        """An application event on a mappable entry: the TPDOs that map it are queued."""
        if self.engine is not None:
            self.engine.object_changed(index, sub, now)

    # -- Service ----------------------------------------------------------------------------
    def listen_ids(self) -> set[int]:
        return self.engine.listen_ids() if self.engine is not None else set()

    def on_frame(self, frame: Frame, now: float) -> bool:
        engine = self.engine
        if engine is None or not engine.listens_to(frame.can_id):
            return False
        self._send(engine.on_frame(frame.can_id, frame.data, now, rtr=frame.rtr))
        return True

    def on_sync(self, counter: int | None, now: float) -> None:
        if self.engine is not None:
            self._send(self.engine.on_sync(now, counter))

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        if self.engine is not None:
            self._send(self.engine.set_operational(new == NmtState.OPERATIONAL, now))

    def on_reset_communication(self, now: float) -> None:
        if self.engine is not None:
            self.engine.reset(self.node.node_id if self.node.configured else 0)

    def deadline(self) -> float | None:
        return self.engine.next_deadline() if self.engine is not None else None

    def poll(self, now: float) -> None:
        if self.engine is not None:
            self._send(self.engine.on_timer(now))

    def status(self) -> dict[str, Any]:
        return {**dict(self.counters), **(self.engine.status() if self.engine else {})}

    # -- glue ---------------------------------------------------------------------------------
    def _send(self, frames: list[tuple[int, bytes]]) -> None:
        for can_id, data in frames:
            self.node.send(Frame(can_id, data))

    def _length_error(self, active: bool) -> None:
        emcy = self.node.emcy
        if emcy is None:
            return
        if active:
            emcy.raise_error(LENGTH_ERROR_CODE, LENGTH_ERROR_REGISTER, LENGTH_ERROR_BYTES)
        else:
            emcy.clear_error(LENGTH_ERROR_CODE)
