"""Who wants which channel of the process image, and how one batch's changes reach them.

:class:`fieldgate.image.ProcessImage` writes a batch, then hands its changes to
:meth:`Subscribers.notify`: usually every change goes to the same subscribers (one route
tuple shared by every channel they want, looked up once per change), else each
subscriber gets its own changes in write order; subscribers are served in subscription
order, a batch subscriber with one list, a per-change one with one call per change. A
subscriber that raises is logged and the others are still served.

This module knows channels and changes only by what it reads of them (:class:`Routed`,
:class:`Delivered`), so the image, which defines them, builds on it.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

log = logging.getLogger("fieldgate.image")


class Routed(Protocol):
    """What routing reads of a channel (:class:`fieldgate.image.Channel`)."""

    @property
    def id(self) -> str: ...
    @property
    def kind(self) -> str: ...  # a Kind (a StrEnum)


class Delivered(Protocol):
    """What delivery reads of a change (:class:`fieldgate.image.Change`)."""

    @property
    def id(self) -> str: ...
    @property
    def channel(self) -> Routed: ...


class Subscription:
    """Handle returned by :meth:`ProcessImage.subscribe` / :meth:`ProcessImage.subscribe_batch`;
    call :meth:`cancel` to stop."""

    def __init__(
        self,
        owner: Subscribers,
        callback: Callable[[Any], None],
        kinds: frozenset[str] | None,
        ids: frozenset[str] | None,
        batch: bool = False,
    ):
        self._owner = owner
        self.callback = callback
        self.kinds = kinds
        self.ids = ids
        self.batch = batch
        self.active = True
        self.seq = next(owner.seq)

    def wants(self, channel: Routed) -> bool:
        if self.kinds is not None and channel.kind not in self.kinds:
            return False
        return self.ids is None or channel.id in self.ids

    def cancel(self) -> None:
        self.active = False
        self._owner.remove(self)


def _by_seq(item: tuple[Subscription, Sequence[Delivered]]) -> int:
    return item[0].seq


class Subscribers:
    """The image's subscriptions and their routes (channel id -> who wants it)."""

    def __init__(self) -> None:
        self.subscriptions: list[Subscription] = []  # the image tests it: kept in place
        self._routes: dict[str, tuple[Subscription, ...]] = {}
        self._route_of: dict[tuple[Subscription, ...], tuple[Subscription, ...]] = {}
        self.seq = itertools.count()

    def add(
        self,
        callback: Callable[[Any], None],
        kinds: Iterable[str] | None,
        ids: Iterable[str] | None,
        batch: bool,
    ) -> Subscription:
        """A subscription to changes of channels of these kinds and ids (None: any)."""
        sub = Subscription(
            self,
            callback,
            frozenset(kinds) if kinds is not None else None,
            frozenset(ids) if ids is not None else None,
            batch,
        )
        self.subscriptions.append(sub)
        self.forget_routes()
        return sub

    def remove(self, sub: Subscription) -> None:
        self.subscriptions[:] = [s for s in self.subscriptions if s is not sub]
        self.forget_routes()

    def forget_routes(self) -> None:
        """Channels or subscriptions changed: routes are worked out again as needed."""
        self._routes.clear()
        self._route_of.clear()

    def notify(self, changes: Sequence[Delivered]) -> None:
        """Deliver one batch's changes (the image calls it only with subscribers)."""
        routes = self._routes
        route: tuple[Subscription, ...] | None = None
        for change in changes:  # usually every change goes to the same subscribers
            subs = routes.get(change.id)
            if subs is None:
                subs = self._route(change.channel)
            if route is None:
                route = subs
            elif subs is not route:
                self._deliver(self._grouped(changes))
                return
        if route:
            self._deliver([(sub, changes) for sub in route])

    def _grouped(
        self, changes: Sequence[Delivered]
    ) -> list[tuple[Subscription, Sequence[Delivered]]]:
        """Each subscriber's changes, in write order; subscribers in subscription order."""
        groups: dict[Subscription, list[Delivered]] = {}
        routes = self._routes
        for change in changes:
            subs = routes.get(change.id)
            if subs is None:
                subs = self._route(change.channel)
            for sub in subs:
                group = groups.get(sub)
                if group is None:
                    groups[sub] = [change]
                else:
                    group.append(change)
        return sorted(groups.items(), key=_by_seq)

    def _deliver(self, deliveries: list[tuple[Subscription, Sequence[Delivered]]]) -> None:
        for sub, group in deliveries:
            if not sub.active:  # cancelled by a subscriber served before it
                continue
            if sub.batch:
                try:
                    sub.callback(group[:])  # a list of its own
                except Exception:  # a bad subscriber must never stop a writer
                    log.exception(
                        "subscriber %r failed on %s", sub.callback, ", ".join(c.id for c in group)
                    )
                continue
            for change in group:
                try:
                    sub.callback(change)
                except Exception:  # a bad subscriber must never stop a writer
                    log.exception("subscriber %r failed on %s", sub.callback, change.id)

    def _route(self, channel: Routed) -> tuple[Subscription, ...]:
        """Who wants this channel; channels wanted by the same subscribers share one tuple."""
        subs = tuple(s for s in self.subscriptions if s.wants(channel))
        subs = self._route_of.setdefault(subs, subs)
        self._routes[channel.id] = subs
        return subs
