"""The sans-I/O CANopen slave engine: NMT state machine plus pluggable services.

A :class:`Node` owns the object dictionary (:class:`~.od.Dictionary`), the NMT state
and a list of :class:`~.service.Service` objects. It is fed frames and the time and
returns the frames to send::

    node = build_node(settings)            # see .slave: SDO, EMCY, SYNC, error control, store
    out = node.boot(now)                   # [boot-up frame]
    out = node.receive(frame, now)         # answers to one received frame
    out = node.tick(now)                   # timers (heartbeat, life guarding, SDO timeout...)
    out = node.quick_answer(can_id, data, now)  # a read answered from a receive thread, or None
    ids = node.listen_ids()                # the CAN-IDs to receive (acceptance filters), or None
    when = node.next_deadline()            # call tick() again at this time (or None)

Public hooks for other services and the front:

* ``node.add_service(service)`` (see :mod:`.service` for the interface);
* ``node.od`` the object dictionary; ``node.emcy`` the EMCY producer
  (``raise_error(code, register_bits, manufacturer_bytes)`` / ``clear_error(code)``);
* ``node.on_nmt(cb(old, new))``, ``node.on_master(cb(ok, reason))``,
  ``node.on_bit_timing(cb(bitrate, delay_s))`` listeners;
* ``node.set_node_id(new)`` (LSS: becomes active at the next reset communication),
  ``node.reset_communication(now)``, ``node.reset_node(now)``,
  ``node.request_bit_timing(bitrate, delay_s)`` (LSS activate bit timing);
* a node created with ``node_id=None`` (or 0xFF) is *unconfigured*: it stays in
  Initialisation, sends no boot-up and passes frames only to services whose
  ``active_states`` include ``INITIALISING`` (LSS), until LSS sets a node-ID and
  calls ``reset_communication``.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from typing import Any, TypeVar, cast

from fieldgate.can.frame import Frame

from . import nmt
from .nmt import NMT_RESET_NODE, RESETS, STATE_OF, UNCONFIGURED_NODE_ID, NmtState
from .od import Dictionary
from .service import QUIET, EmcyProducer, Service, Taken

log = logging.getLogger("fieldgate.canopen")
S = TypeVar("S", bound=Service)

RESET_EMCY_CODE, RESET_EMCY_REGISTER, RESET_EMCY_MANUFACTURER = (
    0xFF00,
    0x80,
    b"\x0a",
)  # I-7232D/I-7231D


class Node:
    def __init__(self, node_id: int | None, od: Dictionary | None = None, name: str = "canopen"):
        node_id = UNCONFIGURED_NODE_ID if node_id is None else node_id
        if not (1 <= node_id <= 127 or node_id == UNCONFIGURED_NODE_ID):
            raise ValueError(f"node-ID {node_id} is not 1..127 (or unconfigured)")
        self.name = name
        self.node_id = node_id
        self.pending_node_id = node_id
        self.od = (
            od
            if od is not None
            else Dictionary(node_id=node_id if node_id != UNCONFIGURED_NODE_ID else 0)
        )
        self.od.node_id = node_id if node_id != UNCONFIGURED_NODE_ID else 0
        self.state = NmtState.INITIALISING
        self.services: list[Service] = []
        self._timed: list[Service] = []
        self.counters: Counter[str] = Counter()
        self.frames_received = (
            0  # counters["rx"] in status(); a plain integer on the per-frame path
        )
        self.emcy: EmcyProducer | None = (
            None  # the EMCY producer, set when one is added (see .emcy)
        )
        self.now = 0.0  # time of the last boot()/receive()/tick(), for calls from outside
        self._deadline_hint: float | None = None
        self._routes: dict[tuple[int, bool], Service] = {}
        self._routes_generation = -1
        self._listen: frozenset[int] | None = frozenset()
        self._listen_key: tuple[int, int, int] | None = None
        self.reset_emcy = False  # send EMCY 00 FF 80 0A before an NMT reset (ICP DAS gateways do)
        self._outbox: list[Frame] = []
        self._nmt_listeners: list[Callable[[NmtState, NmtState], None]] = []
        self._master_listeners: list[Callable[[bool, str], None]] = []
        self._bit_timing_listeners: list[Callable[[int, float], None]] = []
        self._wake_listeners: tuple[Callable[[], None], ...] = ()

    # -- assembling ------------------------------------------------------------------
    def add_service(self, service: S) -> S:
        self._routes.clear()
        self.services.append(service)
        if type(service).deadline is not Service.deadline:  # services without timers are skipped
            self._timed.append(service)
        service.attach(self)
        if getattr(service, "is_emcy_producer", False):
            self.emcy = cast(EmcyProducer, service)
        return service

    def service(self, name: str) -> Any:  # by name: the caller knows the class it asks for
        for s in self.services:
            if s.name == name:
                return s
        raise KeyError(name)

    def on_nmt(self, callback: Callable[[NmtState, NmtState], None]) -> None:
        self._nmt_listeners.append(callback)

    def on_master(self, callback: Callable[[bool, str], None]) -> None:
        self._master_listeners.append(callback)

    def on_bit_timing(self, callback: Callable[[int, float], None]) -> None:
        self._bit_timing_listeners.append(callback)

    def on_wake(self, callback: Callable[[], None]) -> None:
        """``callback()`` after every :meth:`wake`: whoever drives the node (the CAN front)
        runs it soon (:meth:`tick`, :meth:`flush`)."""
        self._wake_listeners += (callback,)

    @property
    def configured(self) -> bool:
        return self.node_id != UNCONFIGURED_NODE_ID

    # -- I/O (sans-I/O) -----------------------------------------------------------------
    def send(self, frame: Frame) -> None:
        """Queue a frame; the caller of receive()/tick()/boot()/flush() gets it back."""
        self._outbox.append(frame)

    def wake(self) -> None:
        """Work was queued from outside the engine's calls (a process-image event for a
        TPDO, an EMCY): the next call runs the timer pass, and :meth:`quick_answer` leaves
        every frame to the event loop until then, so no answer overtakes that work. The
        wake listeners (:meth:`on_wake`) hear of it."""
        self._deadline_hint = self.now
        for listener in self._wake_listeners:
            listener()

    def flush(self) -> list[Frame]:
        """Frames queued by calls from outside the engine (e.g. ``node.emcy.raise_error``).

        Such a call may also have moved a timer: the deadline hint is brought up to date.
        """
        self._deadline_hint = self.next_deadline()
        return self._drain()

    def _drain(self) -> list[Frame]:
        out, self._outbox = self._outbox, []
        return out

    def boot(self, now: float) -> list[Frame]:
        """Power-on: Initialisation, load everything, boot-up, Pre-operational."""
        self.now = now
        self._reset(now, application=True)
        self._deadline_hint = self.next_deadline()
        return self._drain()

    def receive(self, frame: Frame, now: float) -> list[Frame]:
        self.now = now
        self.frames_received += 1
        if frame.can_id == 0 and not frame.rtr:
            self._nmt_command(frame, now)
            self._run_due(now)
        elif self._dispatch(frame, now) is not QUIET:
            self._run_due(now)
        else:  # a read: timers as they were (None: there are none), unless one is due already
            hint = self._deadline_hint
            if hint is not None and hint <= now:
                self._run_due(now)
        return self._drain()

    def quick_answer(self, can_id: int, data: bytes | bytearray, now: float) -> Frame | None:
        """The answer to a data frame that only reads (an SDO expedited upload), or None.

        For a CAN receive thread (:mod:`fieldgate.can.busrx`), so the answer leaves without
        waiting for the event loop; the adapter calls it with its engine lock held and only
        when every earlier frame has been handled. It answers only what :meth:`receive`
        would answer the same way and changes nothing but counters: the COB-ID must be
        routed to a service already (the route is forgotten on every NMT state change and
        dictionary write, so the service was active and its COB-ID is current), no timer
        may be due, nothing may wait in the outbox or since :meth:`wake`, and the service's
        :meth:`~.service.Service.answer_read` must accept it. None means: give the frame
        to :meth:`receive`.
        """
        if self._routes_generation != self.od.generation or self._outbox:
            return None
        service = self._routes.get((can_id, False))
        if service is None:
            return None
        hint = self._deadline_hint
        if hint is not None and hint <= now:
            return None
        answer = service.answer_read(data)
        if answer is not None:
            self.frames_received += 1
        return answer

    def listen_ids(self) -> frozenset[int] | None:
        """The CAN-IDs the node takes frames on, as configured now; None: every frame.

        NMT (0x000) and what each service lists (:meth:`.service.Service.listen_ids`),
        whatever the NMT state. Recomputed after a dictionary change, reset or node-ID
        change; the same object while nothing changed (the adapter compares identity).
        """
        key = (self.od.generation, self.node_id, len(self.services))
        if key != self._listen_key:
            ids: set[int] = {0x000}
            everything = False  # a service that cannot list its CAN-IDs takes every frame
            for service in self.services:
                try:
                    listed = service.listen_ids()
                except Exception:
                    self._internal_error(service, "listen_ids")
                    listed = None
                if listed is None:
                    everything = True
                    break
                ids.update(listed)
            listen = None if everything else frozenset(ids)
            if listen != self._listen:
                self._listen = listen
            self._listen_key = key
        return self._listen

    def _dispatch(self, frame: Frame, now: float) -> object:
        """Offer the frame to the services in add order until one takes it.

        The service that took a COB-ID last time is asked first. The route is forgotten
        on any dictionary write (COB-IDs live there), NMT state change or added service;
        a service that declines is simply followed by the ordered scan.
        """
        if self._routes_generation != self.od.generation:
            self._routes.clear()
            self._routes_generation = self.od.generation
        key = (frame.can_id, frame.rtr)
        cached = self._routes.get(key)
        if cached is not None:
            try:
                taken = cached.on_frame(frame, now)
            except Exception:
                self._internal_error(cached, "on_frame", frame)
                return True  # consumed (by a bug): not offered to the others
            if taken:
                return taken
        for service in self.services:
            if service is not cached and self.state in service.active_states:
                taken = self._offer(service, frame, now)
                if taken:
                    self._routes[key] = service
                    return taken
        self.counters["ignored"] += 1
        return None

    def _offer(self, service: Service, frame: Frame, now: float) -> Taken:
        """``service.on_frame``'s answer: false (not taken), True or QUIET."""
        try:
            return service.on_frame(frame, now)
        except Exception:
            self._internal_error(service, "on_frame", frame)
            return True  # consumed (by a bug): not offered to the others

    def tick(self, now: float) -> list[Frame]:
        self.now = max(self.now, now)
        self._run_due(now)
        return self._drain()

    @property
    def deadline_after_call(self) -> float | None:
        """``next_deadline()`` as of the end of the last receive()/tick(), without recomputing."""
        return self._deadline_hint

    def next_deadline(self) -> float | None:
        earliest: float | None = None
        for service in self._timed:  # a plain loop: this runs several times per engine call
            try:
                deadline = service.deadline()
            except Exception:
                self._internal_error(service, "deadline")
                continue
            if deadline is not None and (earliest is None or deadline < earliest):
                earliest = deadline
        return earliest

    def _run_due(self, now: float) -> None:
        """Poll the services that are due; note the earliest deadline left (one pass)."""
        earliest, polled = None, False
        for service in self._timed:
            try:
                deadline = service.deadline()
                if deadline is None:
                    continue
                if deadline <= now:
                    polled = True
                    service.poll(now)
                elif earliest is None or deadline < earliest:
                    earliest = deadline
            except Exception:
                self._internal_error(service, "poll")
        # a poll may move any service's deadline (an EMCY queued behind its inhibit time...)
        self._deadline_hint = self.next_deadline() if polled else earliest

    def _internal_error(self, service: Service, where: str, frame: Frame | None = None) -> None:
        self.counters["internal_errors"] += 1
        log.exception(
            "%s: service %s failed in %s%s",
            self.name,
            service.name,
            where,
            f" on {frame}" if frame else "",
        )

    # -- NMT ----------------------------------------------------------------------------
    def _nmt_command(self, frame: Frame, now: float) -> None:
        cs = nmt.command(frame.data, self.node_id if self.configured else None)
        if isinstance(cs, str):  # not a command for this node: counted
            self.counters[cs] += 1
            return
        self.counters["nmt"] += 1
        state = STATE_OF.get(cs)
        if state is not None:
            self.set_state(state, now)
        elif cs in RESETS:
            if self.reset_emcy and self.emcy is not None:
                self.emcy.signal(RESET_EMCY_CODE, RESET_EMCY_REGISTER, RESET_EMCY_MANUFACTURER, now)
            self._reset(now, application=cs == NMT_RESET_NODE)
        else:
            self.counters["nmt_unknown_command"] += 1

    def set_state(self, new: NmtState, now: float) -> None:
        old = self.state
        if old == new:
            return
        self.state = new
        self._routes.clear()
        log.info("%s: NMT %s -> %s", self.name, old.label, new.label)
        self._each("on_nmt_state", old, new, now)
        self._notify(self._nmt_listeners, "NMT", old, new)

    def reset_node(self, now: float) -> None:
        """Reset application: reload the whole dictionary, then reset communication."""
        self._reset(now, application=True)

    def reset_communication(self, now: float) -> None:
        """Reload the communication area, take a pending node-ID, boot-up, Pre-operational."""
        self._reset(now, application=False)

    def _reset(self, now: float, application: bool) -> None:
        self.set_state(NmtState.INITIALISING, now)
        self.node_id = self.pending_node_id
        self.od.node_id = self.node_id if self.configured else 0
        if application:
            self.od.reload(communication=False, application=True)
            self._each("on_reset_application", now)
        self.od.reload(communication=True, application=False)
        self._each("on_reset_communication", now)
        if not self.configured:
            return  # unconfigured: wait for LSS in Initialisation
        self.send(Frame(0x700 + self.node_id, b"\x00"))
        self.set_state(NmtState.PRE_OPERATIONAL, now)

    def _each(self, method: str, *args: Any) -> None:
        for service in self.services:
            try:
                getattr(service, method)(*args)
            except Exception:
                self._internal_error(service, method)

    def _notify(self, listeners: list[Callable[..., None]], what: str, *args: Any) -> None:
        for listener in list(listeners):
            try:
                listener(*args)
            except Exception:
                log.exception("%s: %s listener failed", self.name, what)

    # -- SYNC, master state, LSS hooks -------------------------------------------------
    def sync(self, counter: int | None, now: float) -> None:
        """A SYNC was consumed (or produced): tell every service in add order."""
        for service in self.services:
            if self.state in service.active_states:
                try:
                    service.on_sync(counter, now)
                except Exception:
                    self._internal_error(service, "on_sync")

    def master_state(self, ok: bool, reason: str) -> None:
        """Error control reports the master lost (guarding, heartbeat, bus-off) or back."""
        self._notify(self._master_listeners, "master", ok, reason)

    def set_node_id(self, node_id: int) -> None:
        """LSS configure node-ID: pending until the next reset communication."""
        if not (1 <= node_id <= 127 or node_id == UNCONFIGURED_NODE_ID):
            raise ValueError(f"node-ID {node_id} is not 1..127 or 0xFF")
        self.pending_node_id = node_id

    def request_bit_timing(self, bitrate: int, delay_s: float) -> None:
        """LSS activate bit timing: the adapter re-opens the bus at ``bitrate`` after ``delay_s``."""
        self._notify(self._bit_timing_listeners, "bit-timing", bitrate, delay_s)

    def status(self) -> dict[str, Any]:
        return {
            "node_id": self.node_id if self.configured else None,
            "nmt_state": self.state.label,
            "counters": {"rx": self.frames_received, **self.counters},
            "services": {s.name: s.status() for s in self.services},
        }
