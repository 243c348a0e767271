"""What the Sparkplug session (:mod:`.session`) is given and what it asks of its adapter
(:mod:`.front`): the time of every input, its states, and the actions it returns."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from .model import Value


@dataclass(frozen=True)
class Instant:
    mono: float  # monotonic seconds: timers
    wall_ms: int  # milliseconds since the epoch: payload timestamps


class State(StrEnum):
    DISCONNECTED = "disconnected"
    CONNECTING = "connecting"
    WAITING_HOST = "waiting-for-primary-host"
    ONLINE = "online"
    STOPPED = "stopped"


@dataclass(frozen=True)
class Connect:
    broker: int  # index into the configured broker list
    client_id: str
    will_topic: str
    will_payload: bytes
    bdseq: int


@dataclass(frozen=True)
class Subscribe:
    topics: tuple[str, ...]


@dataclass(frozen=True)
class Publish:
    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False
    token: int | None = None  # DATA only: confirmed by on_puback (QoS 1) or a Sync (QoS 0)
    kind: str = ""  # nbirth, dbirth, ddata, ddata_historical, ddeath, ndeath: counters, logs
    seq: int | None = None  # the payload's seq (logs)


@dataclass(frozen=True)
class Sync:
    """Tell :meth:`Session.on_synced` (with this token) once the broker has read every
    message handed to the MQTT client before this action."""

    token: int


@dataclass(frozen=True)
class DiscardQueuedData:
    """Drop every DATA message not yet handed to the MQTT client and report their tokens
    to :meth:`Session.on_discarded` (a Rebirth request: they belong to the old births)."""


@dataclass(frozen=True)
class Disconnect:
    reason: str


@dataclass(frozen=True)
class Write:
    channel_id: str
    value: Value


@dataclass(frozen=True)
class SaveBdSeq:
    bdseq: int


Action = Connect | Subscribe | Publish | Sync | DiscardQueuedData | Disconnect | Write | SaveBdSeq
