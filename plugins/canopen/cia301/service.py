"""The interface every CANopen service implements to plug into a :class:`Node`.

How a service plugs in (PDO engine, CiA 401 objects, LSS, ... are written this way)::

    class MyService(Service):
        name = "pdo"

        def attach(self, node):                  # called once by node.add_service(self)
            super().attach(node)
            node.od.add_record(0x1400, ...)      # add your objects
            node.od.add_validator(0x1400, ...)   # veto bad writes with SdoAbort
            node.od.on_write(0x1400, ...)        # react to accepted writes (resets reload without calling it)

        def on_frame(self, frame: Frame, now: float) -> bool:  # every received frame, in add order,
            if frame.can_id != self.cob_id:      # until one service returns a true value
                return False
            self.node.send(Frame(...))           # answers go to the node's outbox
            return True                          # (or QUIET: see below)

        def listen_ids(self):                    # the CAN-IDs on_frame takes, as configured now
            return (self.cob_id,)

        def on_nmt_state(self, old, new, now): ...   # NMT state changed
        def on_sync(self, counter, now): ...         # a SYNC was consumed (counter or None)
        def on_reset_communication(self, now): ...   # communication area reloaded, node-ID may be new
        def on_reset_application(self, now): ...     # application area reloaded (reset node)
        def deadline(self): return self._next        # next time poll() must run, or None
        def poll(self, now): ...                     # called when now >= deadline()

    node.add_service(MyService())

Rules:
* Everything is sans-I/O and runs on one thread (the event loop): no sleeping, no
  blocking calls; use ``now`` (seconds, monotonic) and :meth:`deadline`.
* A service never raises out of ``on_frame``/``poll``: the node counts and logs any
  exception as an internal error and carries on, but a well-behaved service answers
  bad input with its protocol error (SDO abort, EMCY) or counts a drop in
  :attr:`counters` (shown in the front's ``status()``).
* Timers: override ``deadline``/``poll`` in the class; the node asks only services
  whose class overrides ``deadline``. The node also remembers which service took a
  COB-ID and offers it that frame first; that memory is dropped on every dictionary
  change, NMT state change and added service, so keep COB-IDs in the dictionary.
* ``QUIET``: ``on_frame`` may return it instead of True for a frame that moved no
  timer, changed no dictionary value and no NMT state (the SDO server's expedited
  upload: a read). The node then skips its timer pass after that frame unless a timer
  is already due. Returning True is always correct; QUIET is only an optimisation.
* ``answer_read``: a service may answer a request that only reads (the SDO server's
  expedited upload) without the event loop: :meth:`Node.quick_answer` calls it from the
  CAN receive thread, with the adapter's engine lock held, for a COB-ID the service took
  before. It returns the answer or None (then the frame goes the normal way); it changes
  nothing but its own counters, never raises, and reads the dictionary only with
  ``od.read_quick`` (plain values and getters bound ``thread_safe``).
* ``listen_ids``: the CAN-IDs (data or remote) ``on_frame`` may take, from the current
  configuration and independent of the NMT state (a frame may follow the NMT command at
  once). The node joins them into its listen set, which the adapter turns into the bus's
  acceptance filters; frames on other IDs never reach the node. The set is asked for again
  after any dictionary change, reset or node-ID change, so keep what it depends on in the
  dictionary. The default: none for a service without ``on_frame``, every frame (None, no
  filtering) for one that has ``on_frame`` but does not say.
* ``active_states``: the NMT states in which the node passes frames to ``on_frame``.
  The default is pre-operational and operational (SDO, SYNC, EMCY per CiA 301); a PDO
  service sets ``{NmtState.OPERATIONAL}``, error control and LSS set all states.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Collection, Iterable
from typing import Any, ClassVar, Protocol, TypeVar

from fieldgate.can.frame import Frame

from .nmt import NmtState
from .od import Dictionary

ALL_STATES = frozenset(NmtState)


class _Quiet:
    """``on_frame``'s "taken, and nothing a timer depends on changed" (true, like True)."""

    __slots__ = ()

    def __bool__(self) -> bool:
        return True

    def __repr__(self) -> str:
        return "QUIET"


QUIET = _Quiet()
COMMUNICATING = frozenset({NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL})


class EmcyProducer(Protocol):
    """What services use of the node's EMCY producer (:class:`.emcy.Emcy`)."""

    on_sent: Callable[[Frame], None] | None  # the front publishes an event per EMCY sent
    on_overflow: Callable[[float], None] | None  # the queue dropped an EMCY (CAN health reports it)

    def raise_error(
        self,
        code: int,
        register_bits: int = ...,
        manufacturer: bytes = b"",
        now: float | None = None,
        *,
        urgent: bool = False,
    ) -> bool: ...

    def clear_error(
        self, code: int, manufacturer: bytes | None = None, now: float | None = None
    ) -> bool: ...

    def clear_errors(
        self, errors: Iterable[tuple[int, bytes]], now: float | None = None
    ) -> int: ...

    def signal(
        self,
        code: int,
        register: int,
        manufacturer: bytes = b"",
        now: float | None = None,
        *,
        record: bool = True,
    ) -> None: ...


S = TypeVar("S", bound="Service")


class NodeHost(Protocol):
    """What a service may use of the node it is attached to (:class:`.node.Node` is one).

    A service depends on this interface, not on the node module, so ``node.py`` imports
    ``service.py`` and nothing imports back.
    """

    name: str
    node_id: int
    pending_node_id: int
    od: Dictionary
    state: NmtState
    now: float
    emcy: EmcyProducer | None
    services: list[Service]

    @property
    def configured(self) -> bool: ...

    def add_service(self, service: S) -> S: ...

    def service(self, name: str) -> Any: ...  # by name: the caller knows the class it asks for

    def send(self, frame: Frame) -> None: ...

    def wake(self) -> None: ...

    def on_nmt(self, callback: Callable[[NmtState, NmtState], None]) -> None: ...

    def on_master(self, callback: Callable[[bool, str], None]) -> None: ...

    def set_state(self, new: NmtState, now: float) -> None: ...

    def reset_communication(self, now: float) -> None: ...

    def sync(self, counter: int | None, now: float) -> None: ...

    def master_state(self, ok: bool, reason: str) -> None: ...

    def set_node_id(self, node_id: int) -> None: ...

    def request_bit_timing(self, bitrate: int, delay_s: float) -> None: ...


Taken = bool | _Quiet  # on_frame's answer: False (not taken), True or QUIET


class Service:
    name: str = "service"  # a class constant, or per instance (one SDO server channel each)
    active_states: ClassVar[frozenset[NmtState]] = COMMUNICATING

    node: NodeHost  # the node this service is attached to: set by attach (node.add_service)

    def __init__(self) -> None:
        self.counters: Counter[str] = Counter()

    def attach(self, node: NodeHost) -> None:
        self.node = node

    def on_frame(self, frame: Frame, now: float) -> Taken:
        return False

    def answer_read(self, data: bytes | bytearray) -> Frame | None:
        return None

    def listen_ids(self) -> Collection[int] | None:
        return () if type(self).on_frame is Service.on_frame else None

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        pass

    def on_sync(self, counter: int | None, now: float) -> None:
        pass

    def on_reset_communication(self, now: float) -> None:
        pass

    def on_reset_application(self, now: float) -> None:
        pass

    def deadline(self) -> float | None:
        return None

    def poll(self, now: float) -> None:
        pass

    def status(self) -> dict[str, Any]:
        return dict(self.counters)
