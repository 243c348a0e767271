"""Client writes to the front's writable outputs, acknowledged only once the fieldbus side
applied them.

asyncua answers a Write from ``AttributeService.write`` (async); a node's value setter is
synchronous and cannot wait for anything. :class:`WriteGate` replaces the attribute service
of one server: the values a Write request sets on the front's writable variables go as one
batch through ``set_outputs`` (``GatewayContext.set_outputs``: in a north-facing child, a
round trip to the fieldbus process), and the Write response is sent when it returned, with
each value's own status:

| the value | status |
|---|---|
| applied | Good (the node shows it at once) |
| another Variant type than the variable's, an array, a null | Bad_TypeMismatch |
| outside the channel's data type, its engineering range, text longer than it holds | Bad_OutOfRange |
| an IndexRange on these scalars | Bad_IndexRangeInvalid |
| written with a StatusCode other than Good | Bad_WriteNotSupported |
| refused by the fieldbus side (ValueError) | Bad_NotWritable |
| the fieldbus side unreachable or failing | Bad_CommunicationError |

Timestamps a client writes with the value are ignored: the node shows when the value was
applied. When the batch is refused, each value is tried alone, so one bad value does not
cost the others. Every other write (other nodes, other attributes) is asyncua's, unchanged.
"""

from __future__ import annotations

import datetime
import logging
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any

from asyncua import ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AttributeService

from fieldgate.image import DataType, Value
from fieldgate.plugin import one_line

SetOutputs = Callable[[Mapping[str, Value]], Awaitable[None]]
ADMIN = User(role=UserRole.Admin)  # asyncua's default caller (the server itself)


@dataclass(frozen=True)
class WriteTarget:
    channel_id: str
    variant: ua.VariantType  # the variable's type: a write must carry exactly this
    data_type: DataType  # the channel's, for the range
    check: Callable[[object], Value] | None = None  # the channel's whole check (text length,
    # an engineering range): Bad_OutOfRange before anything goes to the fieldbus side


def _status(code: int) -> ua.StatusCode:
    return ua.StatusCode(ua.UInt32(code))


class WriteGate(AttributeService):
    def __init__(
        self,
        inner: AttributeService,
        aspace: Any,
        targets: Mapping[ua.NodeId, WriteTarget],
        set_outputs: SetOutputs,
        applied: Callable[[ua.NodeId, WriteTarget, Value], Awaitable[None]],
        counters: Any,
        log: logging.Logger,
    ):
        super().__init__(aspace)
        self.inner = inner
        self.targets = targets
        self.set_outputs = set_outputs
        self.applied = applied
        self.counters = counters
        self.log = log

    async def write(self, params: ua.WriteParameters, user: User = ADMIN) -> list[ua.StatusCode]:
        nodes = list(params.NodesToWrite)
        mine = [
            i
            for i, wv in enumerate(nodes)
            if wv.AttributeId == ua.AttributeIds.Value and wv.NodeId in self.targets
        ]
        if not mine:
            return await self.inner.write(params, user)
        results: list[ua.StatusCode | None] = [None] * len(nodes)
        others = [i for i in range(len(nodes)) if i not in set(mine)]
        if others:
            rest = ua.WriteParameters()
            rest.NodesToWrite = [nodes[i] for i in others]
            for i, status in zip(others, await self.inner.write(rest, user), strict=True):
                results[i] = status
        batch: dict[int, tuple[ua.NodeId, WriteTarget, Value]] = {}
        for i in mine:
            target = self.targets[nodes[i].NodeId]
            refused, value = _checked(nodes[i], target)
            if refused is not None:
                results[i] = _status(refused)
                self.counters["write_errors"] += 1
            else:
                batch[i] = (nodes[i].NodeId, target, value)
        if batch:
            for i, status in (await self._apply(batch)).items():
                results[i] = status
        return [r if r is not None else _status(ua.StatusCodes.BadInternalError) for r in results]

    async def _apply(
        self, batch: dict[int, tuple[ua.NodeId, WriteTarget, Value]]
    ) -> dict[int, ua.StatusCode]:
        values = {target.channel_id: value for _, target, value in batch.values()}
        try:
            await self.set_outputs(values)
        except (KeyError, ValueError):
            if len(batch) == 1:
                return await self._apply_one(batch)
            out: dict[int, ua.StatusCode] = {}
            for i, one in batch.items():  # one by one: which of them is refused
                out.update(await self._apply_one({i: one}))
            return out
        except Exception as exc:  # noqa: BLE001  (the fieldbus side unreachable: answer, log)
            self.counters["write_errors"] += len(batch)
            self.log.warning("client write of %s not applied: %s", ", ".join(values), one_line(exc))
            return {i: _status(ua.StatusCodes.BadCommunicationError) for i in batch}
        return await self._done(batch)

    async def _apply_one(
        self, one: dict[int, tuple[ua.NodeId, WriteTarget, Value]]
    ) -> dict[int, ua.StatusCode]:
        ((i, (_, target, value)),) = one.items()
        try:
            await self.set_outputs({target.channel_id: value})
        except KeyError as exc:
            return self._refused(i, target, ua.StatusCodes.BadNodeIdUnknown, exc)
        except ValueError as exc:
            return self._refused(i, target, ua.StatusCodes.BadNotWritable, exc)
        except Exception as exc:  # noqa: BLE001
            return self._refused(i, target, ua.StatusCodes.BadCommunicationError, exc)
        return await self._done(one)

    def _refused(
        self, i: int, target: WriteTarget, code: int, exc: BaseException
    ) -> dict[int, ua.StatusCode]:
        self.counters["write_errors"] += 1
        self.log.warning("client write to %s refused: %s", target.channel_id, one_line(exc))
        return {i: _status(code)}

    async def _done(
        self, batch: dict[int, tuple[ua.NodeId, WriteTarget, Value]]
    ) -> dict[int, ua.StatusCode]:
        for nid, target, value in batch.values():
            self.counters["writes"] += 1
            await self.applied(nid, target, value)
        return {i: _status(ua.StatusCodes.Good) for i in batch}


def _checked(wv: ua.WriteValue, target: WriteTarget) -> tuple[int | None, Value]:
    """(None, the value) when the write may go to the fieldbus, else (the status, None)."""
    dv = wv.Value
    if wv.IndexRange:
        return ua.StatusCodes.BadIndexRangeInvalid, False
    if dv is None or dv.Value is None or dv.Value.Value is None:
        return ua.StatusCodes.BadTypeMismatch, False
    if dv.StatusCode is not None and dv.StatusCode.value != 0:
        return ua.StatusCodes.BadWriteNotSupported, False
    variant = dv.Value
    if variant.VariantType != target.variant or variant.is_array:
        return ua.StatusCodes.BadTypeMismatch, False
    value = variant.Value
    if isinstance(value, bool) != (target.data_type is DataType.BOOL):
        return ua.StatusCodes.BadTypeMismatch, False
    try:
        return None, (target.check or target.data_type.check)(value)
    except ValueError:
        return ua.StatusCodes.BadOutOfRange, False


def data_value(target: WriteTarget, value: Value, status: int) -> ua.DataValue:
    """What the node shows once a write was applied: the value, the channel's status, now."""
    now: Any = datetime.datetime.now(datetime.UTC)  # asyncua types it ua.DateTime (a datetime)
    return ua.DataValue(
        ua.Variant(value, target.variant),
        ua.StatusCode(ua.UInt32(status)),
        SourceTimestamp=now,
        ServerTimestamp=now,
    )
