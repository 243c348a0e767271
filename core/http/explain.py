"""What the status API shows, explained: the gateway's status, each point with its cause, readiness.

Everything here reads what the gateway already keeps (``status()`` dicts, the process
image, module health): building a view never touches a bus.

Components may explain where a point lives: a front or back MAY have a method
``point_locations(self) -> dict[str, list[str]]`` mapping a channel id to readable places
(``"0x6000:1 bit 0"``, ``"TPDO1 (0x181) byte 0 bit 0"``, ``"input register 0"``). It is
called when a point is asked for, so it may reflect a mapping the master changed.
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING, Any, assert_never

from ..health import ModuleHealth
from ..image import Channel, Quality
from ..version import __version__

if TYPE_CHECKING:
    from ..plugin import Component
    from .view import GatewayView

log = logging.getLogger("fieldgate.http")

_failed_locators: set[str] = set()


def json_safe(value: Any) -> Any:
    """``value`` with keys as strings, tuples as lists, non-finite floats as None, others as str."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [json_safe(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)


def readiness(gateway: GatewayView) -> tuple[bool, list[str]]:
    """(ready, reasons): ready when the gateway runs and every front and back is started."""
    reasons: list[str] = []
    if not gateway.running:
        reasons.append("gateway not running (starting or stopping)")
    components = {c.name: c for c in gateway.backs + gateway.fronts}
    for role, configs in (("back", gateway.topology.backs), ("front", gateway.topology.fronts)):
        for cfg in configs:
            comp = components.get(cfg.name)
            cause = gateway.down.get(cfg.name)
            if cause is not None:
                reasons.append(f"{role} {cfg.name} down: {cause}")
            elif comp is None or not getattr(comp, "started", False):
                reasons.append(f"{role} {cfg.name} not started")
    return not reasons, reasons


def status(gateway: GatewayView, started_at: float) -> dict[str, Any]:
    ready, reasons = readiness(gateway)
    body = gateway.status()
    body.update(
        version=__version__,
        ready=ready,
        not_ready=reasons,
        uptime_s=round(time.monotonic() - started_at, 3),
        description=gateway.topology.gateway.description,
        down=dict(gateway.down),
        points=quality_counts(gateway),
        events=[e.as_dict() for e in gateway.context.events.recent(50)],
    )
    return json_safe(body)  # type: ignore[no-any-return]


def quality_counts(gateway: GatewayView) -> dict[str, int]:
    counts = {q.value: 0 for q in Quality}
    for ch in gateway.image:
        counts[ch.quality.value] += 1
    return counts


def _module_health(gateway: GatewayView, channel: Channel) -> ModuleHealth | None:
    try:
        return gateway.health.get(channel.source.back, channel.source.module)
    except KeyError:
        return None


def cause(gateway: GatewayView, channel: Channel) -> str:
    """Why a point is not good, in one line ("" when it is good)."""
    quality = channel.quality
    if quality is Quality.GOOD:
        return ""
    health = _module_health(gateway, channel)
    last_error = health.last_error if health is not None else ""
    down = gateway.down.get(channel.source.back)
    if quality is Quality.COMM_FAULT:
        if down is not None:
            return f"back {channel.source.back} not running: {down}"
        if health is not None and not health.online:
            return f"module offline after {health.consecutive_failures} failed transactions: {last_error}"
        if any(comp.name == channel.source.back for comp in gateway.backs) and not gateway.running:
            return f"back {channel.source.back} not running"
        return "no communication with the module"
    if quality is Quality.STALE:
        return f"last read failed ({last_error}); the value is the last good one"
    if quality is Quality.NOT_READ:
        return "not read since the gateway started"
    if quality is Quality.OVER_RANGE:
        return "the module reports the input over its range"
    if quality is Quality.UNDER_RANGE:
        return "the module reports the input under its range"
    if quality is Quality.WATCHDOG:
        return "the module sits in its host-watchdog safe state and ignores outputs"
    if quality is Quality.CONFIG_ERROR:
        return "the module does not match its declaration" + (
            f": {last_error}" if last_error else ""
        )
    assert_never(quality)  # every quality has its sentence (mypy checks this)


def locations(components: list[Component]) -> dict[str, list[dict[str, str]]]:
    """Every component's ``point_locations()``, merged: channel id -> [{component, at}]."""
    out: dict[str, list[dict[str, str]]] = {}
    for comp in components:
        method = getattr(comp, "point_locations", None)
        if method is None or not getattr(comp, "started", False):
            continue
        try:
            places = method()
        except Exception:
            if comp.name not in _failed_locators:
                _failed_locators.add(comp.name)
                log.exception("%s %s: point_locations() failed", comp.kind, comp.name)
            continue
        for cid, texts in places.items():
            for text in texts:
                out.setdefault(cid, []).append({"component": comp.name, "at": str(text)})
    return out


def point(
    gateway: GatewayView,
    channel: Channel,
    places: dict[str, list[dict[str, str]]] | None = None,
    now: float | None = None,
) -> dict[str, Any]:
    """One point explained: value, engineering value, quality and cause, age, source, where served."""
    now = gateway.image.clock() if now is None else now
    spec = channel.spec
    health = _module_health(gateway, channel)
    source: dict[str, Any] = {
        "back": spec.source.back,
        "module": spec.source.module,
        "model": health.model if health is not None else "",
        "index": spec.source.index,
    }
    served: list[dict[str, str]] = []
    for entry in (places or {}).get(channel.id, []):
        if entry["component"] == spec.source.back:
            source.setdefault("at", []).append(entry["at"])
        else:
            served.append(entry)
    body: dict[str, Any] = {
        "id": channel.id,
        "kind": channel.kind.value,
        "type": spec.data_type.value,
        "value": channel.value,
        "quality": channel.quality.value,
        "cause": cause(gateway, channel),
        "age_s": None if channel.timestamp is None else round(now - channel.timestamp, 3),
        "last_good": channel.last_good,
        "source": source,
        "served_by": served,
    }
    if spec.scaling is not None and not isinstance(channel.value, bool | str):
        body["engineering"] = {
            "value": round(spec.scaling.to_engineering(channel.value), 6),
            "unit": spec.scaling.unit,
        }
    elif spec.engineering is not None:  # the value is in engineering units already
        eng = spec.engineering
        body["engineering"] = {
            "value": channel.value,
            "unit": eng.unit,
            "range": [eng.low, eng.high],
        }
    if spec.label:
        body["label"] = spec.label
    if channel.kind.is_output:
        body["written_by"] = channel.written_by
        body["error_mode"] = channel.error_mode.describe()
    return json_safe(body)  # type: ignore[no-any-return]


def compact(channel: Channel, now: float) -> dict[str, Any]:
    """The few fields an event stream sends for a changed point."""
    body: dict[str, Any] = {
        "id": channel.id,
        "value": channel.value,
        "quality": channel.quality.value,
    }
    scaling = channel.spec.scaling
    if scaling is not None and not isinstance(channel.value, bool | str):
        body["eng"] = round(scaling.to_engineering(channel.value), 6)
    return json_safe(body)  # type: ignore[no-any-return]
