"""Subscriptions of the OPC UA front: asyncua's, within the front's limits, without its
expired-subscription recursion (issue 29, D1).

**D1, the cause (asyncua 2.1.0, server/internal_subscription.py).** When a subscription's
publishing cycles without a Publish request exceed its lifetime count,
``InternalSubscription.publish_results`` calls ``trigger_statuschange(Bad_Timeout)``,
which enqueues the status change and calls ``_trigger_publish``; with a publishing interval
of 0 there is no publishing task, so ``_trigger_publish`` calls ``publish_results`` at once,
which finds the same cycle count, still over the lifetime, and calls
``trigger_statuschange`` again: the recursion ends only in RecursionError, before the
subscription is deleted. The subscription therefore stays, and every data change of one of
its monitored items starts it again (a traceback of ~1,000 frames each time), for as long as
the session lives (up to its timeout after the client left). Here a subscription expires
once: :class:`GuardedSubscription` marks it expired, keeps the status change queued (no
Publish request can carry it: the lifetime ran out for want of one, which asyncua notes as
a FIXME), deletes it with its monitored items and ignores any later trigger. Besides, the
publishing interval is never below ``min_publishing_interval_ms``, so the immediate mode
(a Publish response per data change) is not offered to clients at all.

**Limits** (:class:`SubscriptionLimits`, from the front's configuration): the publishing
interval revised to at least the minimum (NaN, negative, 0: the minimum); the lifetime
count at least three keep-alive counts (Part 4 §5.13.2); subscriptions per session;
monitored items per subscription and per session (the items over the limit answer
Bad_TooManyMonitoredItems, the others are created); the sampling interval and queue size of
each item (:mod:`.deadband`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from asyncua import ua
from asyncua.common import utils
from asyncua.server.internal_subscription import InternalSubscription
from asyncua.server.subscription_service import SubscriptionService

from .deadband import DeadbandMonitoredItems

log = logging.getLogger("asyncua.server.internal_subscription")


@dataclass(frozen=True)
class SubscriptionLimits:
    min_publishing_interval_ms: float
    min_sampling_interval_ms: float
    max_subscriptions_per_session: int
    max_items_per_subscription: int
    max_items_per_session: int
    max_queue_size: int


def revised_publishing(requested: float, minimum: float) -> float:
    if not math.isfinite(requested) or requested < minimum:
        return minimum
    return float(requested)


class GuardedSubscription(InternalSubscription):
    """asyncua's subscription with the front's monitored items and a single expiry."""

    def __init__(
        self, *args: Any, limits: SubscriptionLimits, on_expired: Callable[[], None], **kwargs: Any
    ):
        super().__init__(*args, **kwargs)
        self.monitored_item_srv = DeadbandMonitoredItems(
            self,
            self.monitored_item_srv.aspace,
            limits.min_sampling_interval_ms,
            limits.max_queue_size,
        )
        self.expired = False
        self.gone = False  # expired or deleted: no item may be added any more
        self._on_expired = on_expired

    @property
    def items(self) -> DeadbandMonitoredItems:
        assert isinstance(self.monitored_item_srv, DeadbandMonitoredItems)
        return self.monitored_item_srv

    async def publish_results(self, requestdata: Any = None) -> bool:
        if self.expired:
            return False
        if self._publish_cycles_count > self.data.RevisedLifetimeCount:
            self._expire()
            return False
        return await super().publish_results(requestdata)

    async def _trigger_publish(self) -> None:
        if not self.expired:
            await super()._trigger_publish()

    async def stop(self) -> None:
        self.gone = True
        await super().stop()

    def _expire(self) -> None:
        self.expired = self.gone = True
        log.warning(
            "subscription %s expired: %d publishing cycles without a Publish request "
            "(lifetime count %d); deleted with its %d monitored items",
            self.data.SubscriptionId,
            self._publish_cycles_count,
            self.data.RevisedLifetimeCount,
            self.items.count,
        )
        self._triggered_statuschanges.append(ua.StatusCode(ua.UInt32(ua.StatusCodes.BadTimeout)))
        if self._task:
            self._closing = True
            self._task = None
        if self.delete_callback:
            self.delete_callback()
        self.monitored_item_srv.delete_all_monitored_items()
        self._on_expired()


class GuardedSubscriptions(SubscriptionService):
    """asyncua's subscription service, one per server, building :class:`GuardedSubscription`."""

    def __init__(
        self,
        aspace: Any,
        iserver: Any,
        limits: SubscriptionLimits,
        count: Callable[[str, int], None],
    ) -> None:
        super().__init__(aspace, iserver)
        self.limits = limits
        self._count = count  # (counter name, how many): the front's counters

    def of_session(self, session_id: ua.NodeId) -> list[GuardedSubscription]:
        return [
            s
            for s in self.subscriptions.values()
            if s.session_id == session_id and isinstance(s, GuardedSubscription)
        ]

    @property
    def monitored_items(self) -> int:
        return sum(
            s.items.count for s in self.subscriptions.values() if isinstance(s, GuardedSubscription)
        )

    async def create_subscription(
        self,
        params: ua.CreateSubscriptionParameters,
        callback: Callable[..., Any],
        session_id: ua.NodeId,
        request_callback: Callable[..., Any] | None = None,
    ) -> ua.CreateSubscriptionResult:
        limits = self.limits
        max_subs = self.iserver.max_subscriptions if self.iserver else 1_000
        if len(self.subscriptions) >= max_subs or (
            request_callback is not None
            and len(self.of_session(session_id)) >= limits.max_subscriptions_per_session
        ):
            self._count("too_many_subscriptions", 1)
            raise utils.ServiceError(ua.StatusCodes.BadTooManySubscriptions)
        result = ua.CreateSubscriptionResult()
        result.RevisedPublishingInterval = revised_publishing(
            params.RequestedPublishingInterval, limits.min_publishing_interval_ms
        )
        result.RevisedMaxKeepAliveCount = self._clamp_keep_alive_count(
            params.RequestedMaxKeepAliveCount
        )
        result.RevisedLifetimeCount = max(
            self._clamp_lifetime_count(params.RequestedLifetimeCount),
            3 * result.RevisedMaxKeepAliveCount,
        )
        self._sub_id_counter += 1
        result.SubscriptionId = self._sub_id_counter
        no_acks_limit = self.iserver.max_unacked_messages_per_subscription if self.iserver else 5000
        max_queue = self.iserver.max_monitored_item_queue_size if self.iserver else 10_000
        sub = GuardedSubscription(
            result,
            self.aspace,
            callback,
            session_id,
            request_callback=request_callback,
            delete_callback=lambda: self.subscriptions.pop(result.SubscriptionId, None),
            no_acks_limit=no_acks_limit,
            max_queue_size=max_queue,
            publishing_enabled=params.PublishingEnabled,
            limits=limits,
            on_expired=lambda: self._count("subscription_expired", 1),
        )
        await sub.start()
        self.subscriptions[result.SubscriptionId] = sub
        return result

    async def create_monitored_items(
        self, params: ua.CreateMonitoredItemsParameters
    ) -> list[ua.MonitoredItemCreateResult]:
        sub = self.subscriptions.get(params.SubscriptionId)
        if not isinstance(sub, GuardedSubscription):
            raise utils.ServiceError(ua.StatusCodes.BadSubscriptionIdInvalid)
        limits = self.limits
        in_session = sum(s.items.count for s in self.of_session(sub.session_id))
        room = max(
            0,
            min(
                limits.max_items_per_subscription - sub.items.count,
                limits.max_items_per_session - in_session,
            ),
        )
        wanted = list(params.ItemsToCreate)
        if len(wanted) <= room:
            return await sub.items.create_monitored_items(params)
        allowed = ua.CreateMonitoredItemsParameters()
        allowed.SubscriptionId = params.SubscriptionId
        allowed.TimestampsToReturn = params.TimestampsToReturn
        allowed.ItemsToCreate = wanted[:room]
        results = await sub.items.create_monitored_items(allowed) if room else []
        refused = len(wanted) - room
        for _ in range(refused):
            result = ua.MonitoredItemCreateResult()
            result.StatusCode = ua.StatusCode(ua.UInt32(ua.StatusCodes.BadTooManyMonitoredItems))
            results.append(result)
        self._count("too_many_monitored_items", refused)
        return results
