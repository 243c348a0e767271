"""Subscriptions of the OPC UA front (plugins/opcua/subscriptions.py, deadband.py) on an
asyncua server in the test's loop: issue 29's D1 (an expired subscription recursed until
RecursionError on every data change, forever) and the limits a client cannot pass."""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from typing import Any

import pytest
import pytest_asyncio
from asyncua import Server, ua
from asyncua.server.subscription_service import SubscriptionService

from fieldgate.plugins.opcua import deadband
from fieldgate.plugins.opcua.subscriptions import (
    GuardedSubscription,
    GuardedSubscriptions,
    SubscriptionLimits,
    revised_publishing,
)

pytestmark = pytest.mark.asyncio(loop_scope="module")  # one asyncua server (seconds to start)

SESSION = ua.NodeId(4242)
_names = iter(range(10**6))


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def server():
    server = Server()
    await server.init()
    yield server


def limits(**changes: Any) -> SubscriptionLimits:
    values = {
        "min_publishing_interval_ms": 100.0,
        "min_sampling_interval_ms": 0.0,
        "max_subscriptions_per_session": 3,
        "max_items_per_subscription": 20,
        "max_items_per_session": 30,
        "max_queue_size": 10,
    } | changes
    return SubscriptionLimits(**values)


async def server_with(
    server: Server, lim: SubscriptionLimits
) -> tuple[Server, GuardedSubscriptions, Counter[str], Any]:
    """A fresh subscription service of the front's on the shared server, a fresh variable."""
    counted: Counter[str] = Counter()
    subs = GuardedSubscriptions(
        server.iserver.aspace, server.iserver, lim, lambda what, n: counted.update({what: n})
    )
    server.iserver.subscription_service = subs
    idx = await server.register_namespace("urn:test")
    name = f"v{next(_names)}"
    var = await server.nodes.objects.add_variable(ua.NodeId(name, idx), name, 0)
    return server, subs, counted, var


async def subscribe(
    subs: SubscriptionService, interval: float, lifetime: int = 600, keepalive: int = 10
) -> ua.CreateSubscriptionResult:
    async def publish(*args: Any) -> None:
        pass

    params = ua.CreateSubscriptionParameters(
        RequestedPublishingInterval=interval,
        RequestedLifetimeCount=lifetime,
        RequestedMaxKeepAliveCount=keepalive,
        PublishingEnabled=True,
    )
    # a client that never sends a Publish request: the request callback finds none
    return await subs.create_subscription(
        params, publish, SESSION, request_callback=lambda sid: None
    )


def items(
    sub_id: int, node: ua.NodeId, n: int, sampling: float = 0.0, queue: int = 1
) -> ua.CreateMonitoredItemsParameters:
    params = ua.CreateMonitoredItemsParameters(SubscriptionId=sub_id)
    for i in range(n):
        params.ItemsToCreate.append(
            ua.MonitoredItemCreateRequest(
                ItemToMonitor=ua.ReadValueId(NodeId=node, AttributeId=ua.AttributeIds.Value),
                MonitoringMode=ua.MonitoringMode.Reporting,
                RequestedParameters=ua.MonitoringParameters(
                    ClientHandle=i, SamplingInterval=sampling, QueueSize=queue
                ),
            )
        )
    return params


async def write(server: Server, var: Any, value: int, status: int = 0) -> None:
    await server.write_attribute_value(
        var.nodeid,
        ua.DataValue(ua.Variant(value, ua.VariantType.Int64), ua.StatusCode(ua.UInt32(status))),
    )


async def test_d1_an_expired_subscription_with_interval_0_expires_once_and_is_deleted(
    server, caplog
):
    """The issue's recipe at its smallest: publishing interval 0 (allowed here by a minimum of
    0 to reach asyncua's immediate mode), lifetime 3, no Publish request, more items than the
    lifetime: each item's first change triggers a publish that finds no request."""
    server, subs, counted, var = await server_with(server, limits(min_publishing_interval_ms=0.0))
    sub = await subscribe(subs, 0.0, lifetime=3, keepalive=1)
    assert sub.RevisedPublishingInterval == 0 and sub.RevisedLifetimeCount == 3
    caplog.set_level(logging.WARNING)
    results = await subs.create_monitored_items(items(sub.SubscriptionId, var.nodeid, 10))
    codes = [r.StatusCode.value for r in results]
    # the 4th item's first change found the lifetime spent: the rest is refused, none left
    assert codes == [0] * 4 + [ua.StatusCodes.BadSubscriptionIdInvalid] * 6
    assert sub.SubscriptionId not in subs.subscriptions
    node = server.iserver.aspace[var.nodeid]
    assert node.attributes[ua.AttributeIds.Value].datachange_callbacks == {}
    assert counted == {"subscription_expired": 1}
    for value in range(1, 200):  # every later change: nothing runs any more
        await write(server, var, value)
    text = caplog.text
    assert "RecursionError" not in text and "Traceback" not in text
    assert text.count("expired") == 1 and "lifetime count 3" in text


async def test_d1_the_cause_is_still_in_asyncua(server, caplog):
    """asyncua's own subscription service, same recipe: RecursionError and the subscription
    left in place. When this fails, asyncua fixed it and GuardedSubscription can go."""
    subs = SubscriptionService(server.iserver.aspace, server.iserver)
    _, _, _, var = await server_with(server, limits())
    sub = await subscribe(subs, 0.0, lifetime=3, keepalive=1)
    with pytest.raises(RecursionError):
        await subs.create_monitored_items(items(sub.SubscriptionId, var.nodeid, 10))
    assert sub.SubscriptionId in subs.subscriptions


async def test_the_publishing_interval_and_lifetime_are_revised(server):
    _, subs, _, _ = await server_with(server, limits(max_subscriptions_per_session=10))
    for requested in (0.0, -5.0, float("nan"), float("inf"), 50.0):
        sub = await subscribe(subs, requested)
        assert sub.RevisedPublishingInterval == 100.0, requested
    sub = await subscribe(subs, 250.0, lifetime=1, keepalive=7)
    assert sub.RevisedPublishingInterval == 250.0
    assert sub.RevisedLifetimeCount == 21  # at least 3 keep-alive counts (Part 4 §5.13.2)
    assert revised_publishing(1e9, 100) == 1e9


async def test_subscriptions_per_session_are_limited(server):
    _, subs, counted, _ = await server_with(server, limits())
    for _ in range(3):
        await subscribe(subs, 1000)
    with pytest.raises(ua.UaError) as refused:
        await subscribe(subs, 1000)
    assert refused.value.code == ua.StatusCodes.BadTooManySubscriptions  # type: ignore[attr-defined]
    assert counted["too_many_subscriptions"] == 1


async def test_monitored_items_per_subscription_and_per_session_are_limited(server):
    _, subs, counted, var = await server_with(server, limits())
    first = await subscribe(subs, 1000)
    results = await subs.create_monitored_items(items(first.SubscriptionId, var.nodeid, 25))
    codes = [r.StatusCode.value for r in results]
    assert codes == [0] * 20 + [ua.StatusCodes.BadTooManyMonitoredItems] * 5
    second = await subscribe(subs, 1000)
    results = await subs.create_monitored_items(items(second.SubscriptionId, var.nodeid, 15))
    assert sum(r.StatusCode.is_good() for r in results) == 10  # 30 per session
    assert counted["too_many_monitored_items"] == 10
    assert subs.monitored_items == 30


async def test_sampling_and_queue_size_are_revised_and_modify_keeps_them(server):
    _, subs, _, var = await server_with(server, limits(min_sampling_interval_ms=200.0))
    sub = await subscribe(subs, 500)
    (fast, slow, default) = [
        (await subs.create_monitored_items(items(sub.SubscriptionId, var.nodeid, 1, s, 10**6)))[0]
        for s in (0.0, 1000.0, -1.0)
    ]
    assert fast.RevisedSamplingInterval == 200.0 and fast.RevisedQueueSize == 10
    assert slow.RevisedSamplingInterval == 1000.0
    assert default.RevisedSamplingInterval == 500.0  # -1: the publishing interval
    modify = ua.ModifyMonitoredItemsParameters(SubscriptionId=sub.SubscriptionId)
    for mid in (fast.MonitoredItemId, 999_999):
        modify.ItemsToModify.append(
            ua.MonitoredItemModifyRequest(
                MonitoredItemId=mid,
                RequestedParameters=ua.MonitoringParameters(SamplingInterval=1.0, QueueSize=10**9),
            )
        )
    revised, unknown = subs.modify_monitored_items(modify)
    assert revised.RevisedSamplingInterval == 200.0 and revised.RevisedQueueSize == 10
    assert unknown.StatusCode.value == ua.StatusCodes.BadMonitoredItemIdInvalid


async def test_a_burst_of_changes_is_sampled_once_per_interval_a_status_change_at_once(server):
    server, subs, _, var = await server_with(server, limits(min_sampling_interval_ms=200.0))
    created = await subscribe(subs, 5000)
    sub = subs.subscriptions[created.SubscriptionId]
    assert isinstance(sub, GuardedSubscription)
    (item,) = await subs.create_monitored_items(
        items(created.SubscriptionId, var.nodeid, 1, 0.0, 10)
    )

    def queued() -> list[tuple[int, int]]:
        notes = sub._triggered_datachanges.get(item.MonitoredItemId, [])
        return [(n.Value.Value.Value, n.Value.StatusCode.value) for n in notes]

    assert queued() == [(0, 0)]  # the first sample, at creation
    for value in range(1, 6):  # within the interval: held, the newest replaces the older
        await write(server, var, value)
    assert queued() == [(0, 0)]
    await asyncio.sleep(0.35)
    assert queued() == [(0, 0), (5, 0)]
    await write(server, var, 6, status=0x8031_0000)  # a status change is sampled at once
    assert queued() == [(0, 0), (5, 0), (None, 0x8031_0000)]  # (a Bad value is null)


async def test_subscriptions_do_not_leave_a_logger_each_behind(server):
    """asyncua makes a logger per subscription, kept by the logging module for good."""
    _, subs, _, var = await server_with(server, limits(max_subscriptions_per_session=1000))
    before = len(logging.Logger.manager.loggerDict)
    for _ in range(200):
        sub = await subscribe(subs, 1000)
        await subs.create_monitored_items(items(sub.SubscriptionId, var.nodeid, 1))
        await subs.delete_subscriptions([sub.SubscriptionId])
    assert len(logging.Logger.manager.loggerDict) - before < 5
    assert deadband.SHARED_LOGGER.name == "asyncua.server.monitored_item_service"
