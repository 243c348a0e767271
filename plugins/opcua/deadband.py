"""Data-change filters as OPC UA Part 4 §7.22.2 says, on asyncua's server.

asyncua 2.1 compares a new value with the previous *sampled* one (so a slow drift never
crosses an absolute deadband) and does not implement the percent deadband at all (it logs a
warning and reports everything). This subclass of its monitored-item service compares with
the last value *reported* to that monitored item and implements both:

* absolute: report when ``|new - last reported| > DeadbandValue``;
* percent: report when ``|new - last reported| > DeadbandValue / 100 * (EURange.High - EURange.Low)``;
  an item asking for a percent deadband on a node without an EURange is refused with
  ``Bad_MonitoredItemFilterUnsupported`` (Part 4 §7.22.2).

A status change always reports. Without a filter it behaves as asyncua's own.

Beyond the filters, the items keep to the front's limits (:mod:`.subscriptions` builds one
service per subscription):

* **sampling** at the revised sampling interval, at least ``min_sampling_interval_ms``
  (requested -1: the publishing interval; 0: the minimum): the front is fed by the image's
  change events, so an item samples a change at once when its last sample is at least one
  interval old, else holds the newest value and samples it when the interval is over (a
  change of status is sampled at once, never held);
* **queue size** revised to at most ``max_queue_size`` (at creation and at
  ModifyMonitoredItems, which asyncua leaves unbounded);
* ModifyMonitoredItems of an unknown item answers Bad_MonitoredItemIdInvalid (asyncua 2.1
  raises a TypeError there and answers Bad_InternalError with a traceback);
* asyncua creates a logger per subscription (``...monitored_item_service.<id>``) that the
  logging module keeps forever: a client creating subscriptions in a loop grows memory
  without bound; here every subscription shares one logger.
"""

from __future__ import annotations

import asyncio
import logging
import math
import weakref
from typing import Any

from asyncua import ua
from asyncua.server.monitored_item_service import MonitoredItemData, MonitoredItemService

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


SHARED_LOGGER = logging.getLogger("asyncua.server.monitored_item_service")


def revised_sampling(requested: float, publishing: float, minimum: float) -> float:
    """The sampling interval an item gets (ms): -1 (or any negative) means the publishing
    interval; nothing faster than ``minimum``; NaN and infinities count as 0."""
    if not math.isfinite(requested):
        requested = 0.0
    if requested < 0:
        requested = publishing
    return max(float(requested), minimum)


class DeadbandMonitoredItems(MonitoredItemService):
    def __init__(
        self, isub: Any, aspace: Any, min_sampling_ms: float = 0.0, max_queue_size: int = 0
    ) -> None:
        super().__init__(isub, aspace)
        logging.Logger.manager.loggerDict.pop(self.logger.name, None)  # see the module's text
        self.logger = SHARED_LOGGER
        self.min_sampling_ms = min_sampling_ms
        self.max_queue_size = max_queue_size  # 0: asyncua's own cap
        self._reported: dict[int, ua.DataValue] = {}  # monitored item id -> last reported
        self._sampling: dict[int, float] = {}  # monitored item id -> interval (s)
        self._sampled: dict[int, tuple[float, ua.DataValue]] = {}  # id -> (when, last sample)
        self._held: dict[int, tuple[ua.DataValue, asyncio.TimerHandle]] = {}  # newest, timer

    @property
    def count(self) -> int:
        return len(self._monitored_items)

    def _revise_queue_size(self, requested: int) -> int:
        size = super()._revise_queue_size(requested)
        return min(size, self.max_queue_size) if self.max_queue_size > 0 else size

    def _make_monitored_item_common(
        self, params: ua.MonitoredItemCreateRequest
    ) -> tuple[ua.MonitoredItemCreateResult, MonitoredItemData]:
        result, mdata = super()._make_monitored_item_common(params)
        result.RevisedSamplingInterval = revised_sampling(
            params.RequestedParameters.SamplingInterval,
            self.isub.data.RevisedPublishingInterval,
            self.min_sampling_ms,
        )
        self._sampling[result.MonitoredItemId] = result.RevisedSamplingInterval / 1000.0
        return result, mdata

    def _modify_monitored_item(
        self, params: ua.MonitoredItemModifyRequest
    ) -> ua.MonitoredItemModifyResult:
        result = ua.MonitoredItemModifyResult()
        mdata = self._monitored_items.get(params.MonitoredItemId)
        if mdata is None:
            result.StatusCode = ua.StatusCode(ua.UInt32(ua.StatusCodes.BadMonitoredItemIdInvalid))
            return result
        requested = params.RequestedParameters
        result.RevisedSamplingInterval = revised_sampling(
            requested.SamplingInterval,
            self.isub.data.RevisedPublishingInterval,
            self.min_sampling_ms,
        )
        self._sampling[params.MonitoredItemId] = result.RevisedSamplingInterval / 1000.0
        result.RevisedQueueSize = self._revise_queue_size(requested.QueueSize)
        if requested.Filter is not None:
            mdata.filter = requested.Filter
        mdata.queue_size = result.RevisedQueueSize
        return result

    def _range(self, node_id: ua.NodeId) -> tuple[float, float] | None:
        return _RANGES.get(self.aspace, {}).get(node_id)

    async def create_monitored_items(
        self, params: ua.CreateMonitoredItemsParameters
    ) -> list[ua.MonitoredItemCreateResult]:
        results: list[ua.MonitoredItemCreateResult] = []
        for n, item in enumerate(params.ItemsToCreate):
            if n and n % 64 == 0:
                await asyncio.sleep(0)  # thousands of items in one request: let others run
            if getattr(self.isub, "gone", False):  # deleted or expired meanwhile: none added
                gone = ua.MonitoredItemCreateResult()
                gone.StatusCode = ua.StatusCode(ua.UInt32(ua.StatusCodes.BadSubscriptionIdInvalid))
                results.append(gone)
                continue
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
            created = await super().create_monitored_items(one)
            for result in created:
                if getattr(self.isub, "gone", False):  # its first sample expired it: gone too
                    result.StatusCode = ua.StatusCode(
                        ua.UInt32(ua.StatusCodes.BadSubscriptionIdInvalid)
                    )
                if not result.StatusCode.is_good():
                    self._forget(result.MonitoredItemId)
            results.extend(created)
        return results

    def delete_monitored_items(self, ids: list[int]) -> list[ua.StatusCode]:
        for mid in ids:
            self._forget(mid)
        return super().delete_monitored_items(ids)

    def _forget(self, mid: int) -> None:
        self._reported.pop(mid, None)
        self._sampling.pop(mid, None)
        self._sampled.pop(mid, None)
        held = self._held.pop(mid, None)
        if held is not None:
            held[1].cancel()

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
        mid = self._monitored_datachange.get(handle)
        mdata = self._monitored_items.get(mid) if mid is not None else None
        if mid is None or mdata is None or mdata.mode == ua.MonitoringMode.Disabled:
            return
        interval = self._sampling.get(mid, 0.0)
        last = self._sampled.get(mid)
        now = asyncio.get_running_loop().time()
        if (
            interval <= 0
            or last is None
            or now - last[0] >= interval
            or last[1].StatusCode != value.StatusCode
        ):
            held = self._held.pop(mid, None)
            if held is not None:
                held[1].cancel()
            await self._sample(mid, mdata, value, now)
            return
        held = self._held.get(mid)
        if held is not None:
            self._held[mid] = (value, held[1])  # the timer samples the newest value
            return
        timer = asyncio.get_running_loop().call_at(last[0] + interval, self._sample_held, mid)
        self._held[mid] = (value, timer)

    def _sample_held(self, mid: int) -> None:
        held = self._held.pop(mid, None)
        mdata = self._monitored_items.get(mid)
        if held is None or mdata is None:
            return
        now = asyncio.get_running_loop().time()
        task = asyncio.get_running_loop().create_task(self._sample(mid, mdata, held[0], now))
        task.add_done_callback(_quiet)

    async def _sample(self, mid: int, mdata: Any, value: ua.DataValue, now: float) -> None:
        self._sampled[mid] = (now, value)
        if not self._passes(mid, mdata, value):
            return
        self._reported[mid] = value
        event = ua.MonitoredItemNotification()
        event.ClientHandle = mdata.client_handle
        event.Value = value
        await self.isub.enqueue_datachange_event(mid, event, mdata.queue_size)


def _quiet(task: asyncio.Task[None]) -> None:
    if not task.cancelled() and task.exception() is not None:
        SHARED_LOGGER.warning("sampling a held value failed: %s", task.exception())
