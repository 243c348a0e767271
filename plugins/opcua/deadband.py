"""Data-change filters as OPC UA Part 4 §7.22.2 says, on asyncua's server.

asyncua 2.1 compares a new value with the previous *sampled* one (so a slow drift never
crosses an absolute deadband) and does not implement the percent deadband at all (it logs a
warning and reports everything). This subclass of its monitored-item service compares with
the last value *reported* to that monitored item and implements both:

* absolute: report when ``|new - last reported| > DeadbandValue``;
* percent: report when ``|new - last reported| > DeadbandValue / 100 * (EURange.High - EURange.Low)``;
  an item asking for a percent deadband on a node without an EURange is refused with
  ``Bad_MonitoredItemFilterUnsupported`` (Part 4 §7.22.2).

A status change always reports. The front installs it once per process with :func:`install`
(asyncua builds one service per subscription from a module-level name); without a filter it
behaves exactly as asyncua's own.
"""

from __future__ import annotations

import weakref
from typing import Any

from asyncua import ua
from asyncua.server import internal_subscription
from asyncua.server.monitored_item_service import MonitoredItemService

# per address space: node id -> (EURange.Low, EURange.High), set by the front that built it
_RANGES: weakref.WeakKeyDictionary[Any, dict[ua.NodeId, tuple[float, float]]] = (
    weakref.WeakKeyDictionary()
)


def set_ranges(aspace: Any, ranges: dict[ua.NodeId, tuple[float, float]]) -> None:
    _RANGES[aspace] = ranges


def _number(dv: ua.DataValue | None) -> float | None:
    if dv is None or dv.Value is None:
        return None
    value = dv.Value.Value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def _data_change_filter(flt: Any) -> Any:
    """The filter when it is a DataChangeFilter (decoded from the wire its class is not always
    ``ua.DataChangeFilter`` itself, so it is recognised by its fields), else None."""
    if flt is None or not all(
        hasattr(flt, f) for f in ("Trigger", "DeadbandType", "DeadbandValue")
    ):
        return None
    return flt


class DeadbandMonitoredItems(MonitoredItemService):
    def __init__(self, isub: Any, aspace: Any) -> None:
        super().__init__(isub, aspace)
        self._reported: dict[int, ua.DataValue] = {}  # monitored item id -> last reported

    def _range(self, node_id: ua.NodeId) -> tuple[float, float] | None:
        return _RANGES.get(self.aspace, {}).get(node_id)

    async def create_monitored_items(
        self, params: ua.CreateMonitoredItemsParameters
    ) -> list[ua.MonitoredItemCreateResult]:
        results: list[ua.MonitoredItemCreateResult] = []
        for item in params.ItemsToCreate:
            flt = item.RequestedParameters.Filter
            if (
                (flt := _data_change_filter(flt)) is not None
                and flt.DeadbandType == ua.DeadbandType.Percent
                and self._range(item.ItemToMonitor.NodeId) is None
            ):
                refused = ua.MonitoredItemCreateResult()
                refused.StatusCode = ua.StatusCode(
                    ua.UInt32(ua.StatusCodes.BadMonitoredItemFilterUnsupported)
                )
                results.append(refused)
                continue
            one = ua.CreateMonitoredItemsParameters()
            one.SubscriptionId = params.SubscriptionId
            one.TimestampsToReturn = params.TimestampsToReturn
            one.ItemsToCreate = [item]
            results.extend(await super().create_monitored_items(one))
        return results

    def delete_monitored_items(self, ids: list[int]) -> list[ua.StatusCode]:
        for mid in ids:
            self._reported.pop(mid, None)
        return super().delete_monitored_items(ids)

    def _passes(self, mid: int, mdata: Any, value: ua.DataValue) -> bool:
        last = self._reported.get(mid)
        if last is None:
            return True
        flt = _data_change_filter(mdata.filter)
        trigger = flt.Trigger if flt is not None else ua.DataChangeTrigger.StatusValue
        if last.StatusCode != value.StatusCode:
            return True
        if trigger == ua.DataChangeTrigger.Status:
            return False
        old, new = _number(last), _number(value)
        band = 0.0
        if flt is not None and old is not None and new is not None:
            if flt.DeadbandType == ua.DeadbandType.Absolute:
                band = flt.DeadbandValue
            elif flt.DeadbandType == ua.DeadbandType.Percent:
                low, high = self._range(mdata.read_value_id.NodeId) or (0.0, 0.0)
                band = flt.DeadbandValue / 100.0 * abs(high - low)
        if band > 0 and old is not None and new is not None:
            changed = abs(new - old) > band
        else:
            changed = last.Value != value.Value
        if changed:
            return True
        return trigger == ua.DataChangeTrigger.StatusValueTimestamp and (
            last.SourceTimestamp != value.SourceTimestamp
        )

    async def datachange_callback(
        self, handle: int, value: ua.DataValue, error: ua.StatusCode | None = None
    ) -> None:
        if error:
            await super().datachange_callback(handle, value, error)
            return
        mid = self._monitored_datachange[handle]
        mdata = self._monitored_items[mid]
        if mdata.mode == ua.MonitoringMode.Disabled:
            return
        mdata.mvalue.set_current_datavalue(value)
        if not self._passes(mid, mdata, value):
            return
        self._reported[mid] = value
        event = ua.MonitoredItemNotification()
        event.ClientHandle = mdata.client_handle
        event.Value = value
        await self.isub.enqueue_datachange_event(mid, event, mdata.queue_size)


def install() -> None:
    """Every subscription asyncua creates from now on uses these filters (idempotent)."""
    setattr(internal_subscription, "MonitoredItemService", DeadbandMonitoredItems)  # noqa: B010
