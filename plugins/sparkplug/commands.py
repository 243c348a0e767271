"""Inbound Sparkplug messages, checked before the session acts on them: their size, the
primary host's STATE (JSON, bounded nesting), NCMD/DCMD payloads and a DCMD's writes.

Anything wrong is counted in ``ignored`` by reason and dropped: a client's message never
raises out of the session."""

from __future__ import annotations

import json
from collections import Counter

from . import payload as codec
from .actions import Write
from .model import NodeModel

MAX_STATE_BYTES = 4096
"""A STATE message is ``{"online": true, "timestamp": ...}``: anything much larger is not one."""

MAX_STATE_DEPTH = 4
"""Deepest JSON nesting a STATE may have (it has 1)."""


def json_depth(data: bytes) -> int:
    """Deepest nesting of ``[``/``{`` in JSON text, outside strings; linear, no recursion."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in data:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


def oversized(parts: list[str], data: bytes, max_command_bytes: int) -> bool:
    """Every inbound payload is bounded, STATE too (it is retained: it comes back)."""
    limit = MAX_STATE_BYTES if parts[1:2] == ["STATE"] else max_command_bytes
    return len(data) > limit


def parse_state(data: bytes, ignored: Counter[str]) -> tuple[bool, int] | None:
    """A STATE payload's ``online`` and ``timestamp``; None (counted) when it is not one."""
    if json_depth(data) > MAX_STATE_DEPTH:  # json.loads would recurse into it
        ignored["bad_state"] += 1
        return None
    try:
        doc = json.loads(data)
        online, ts = doc["online"], doc["timestamp"]
        if not isinstance(online, bool) or not isinstance(ts, int) or isinstance(ts, bool):
            raise ValueError
    except (ValueError, KeyError, TypeError, UnicodeDecodeError, RecursionError):
        ignored["bad_state"] += 1
        return None
    return online, ts


def decode(data: bytes, ignored: Counter[str]) -> list[codec.CommandMetric] | None:
    """An NCMD/DCMD payload's metrics; None (counted) when it does not decode."""
    try:
        return codec.decode_command(data)
    except (codec.PayloadError, RecursionError):  # nesting beyond protobuf's own limit
        ignored["malformed"] += 1
        return None


def device_writes(
    model: NodeModel, dev: str, metrics: list[codec.CommandMetric], ignored: Counter[str]
) -> list[Write]:
    """A DCMD's writes: metrics of this device, writable, with a value of their type (and
    inside the engineering range of a scaled output); the others counted."""
    writes: list[Write] = []
    for cmd in metrics:
        m = None
        if cmd.alias is not None:
            m = model.by_alias.get(cmd.alias)
        elif cmd.name is not None:
            m = model.by_device_name.get((dev, cmd.name))
        if m is None or m.device != dev:
            ignored["unknown_metric"] += 1
            continue
        if not m.writable:
            ignored["not_writable"] += 1
            continue
        try:
            value = codec.command_value(cmd, m.dtype)
            m.dtype.check(value)
            if m.engineering is not None:  # a setpoint outside its range is refused here
                m.engineering.check_output(value)
        except ValueError:
            ignored["bad_value"] += 1
            continue
        writes.append(Write(m.channel_id, value))
    return writes
