"""Acceptance filters from an engine's listen set: CAN-IDs in, few ``(id, mask)`` pairs out.

An engine states the 11-bit identifiers it takes frames on (its *listen set*); the adapter
(:mod:`.adapter`) hands them to python-can's ``bus.set_filters``, which SocketCAN turns into
``CAN_RAW_FILTER`` (the kernel drops every other frame before the process is woken) and other
interfaces apply in hardware or in python-can's own ``recv`` (the ``virtual`` bus included).

:func:`merge` first joins identifiers that differ in one bit into one masked filter as long
as no identifier outside the set is admitted (0x7EC-0x7EF is one filter; the prime
implicants of Quine-McCluskey, greedily covering the set), then, only while
more than ``limit`` filters remain, joins the pair that admits the fewest extra identifiers.
Frames that pass a widened filter are dropped by the adapter's exact check and counted.
"""

from __future__ import annotations

from collections.abc import Iterable

from can.typechecking import CanFilter

STANDARD_MASK = 0x7FF
MAX_FILTERS = 16  # CAN controllers commonly offer 14-32 filter banks; the kernel takes any number

Filter = tuple[int, int]  # (can_id, can_mask), 11-bit


def _admitted(mask: int) -> int:
    """How many 11-bit identifiers a filter with ``mask`` admits."""
    return 1 << (11 - (mask & STANDARD_MASK).bit_count())


def _join(a: Filter, b: Filter) -> Filter:
    mask = a[1] & b[1] & ~(a[0] ^ b[0]) & STANDARD_MASK
    return a[0] & mask, mask


def _members(f: Filter) -> set[int]:
    """The identifiers ``f`` admits (at most 2048)."""
    can_id, mask = f
    free = [1 << b for b in range(11) if not mask & (1 << b)]
    out = {can_id & mask}
    for bit in free:
        out |= {i | bit for i in out}
    return out


def _exact_joins(filters: set[Filter]) -> set[Filter]:
    """Fewest filters that admit exactly what ``filters`` admit (Quine-McCluskey: the prime
    implicants, then a greedy cover of the identifiers by them)."""
    wanted: set[int] = set()
    for f in filters:
        wanted |= _members(f)
    level = {(i & STANDARD_MASK, STANDARD_MASK) for i in wanted}
    primes: set[Filter] = set()
    while level:
        joined: set[Filter] = set()
        used: set[Filter] = set()
        for can_id, mask in level:
            bit = 1
            while bit <= STANDARD_MASK:
                if mask & bit:
                    partner = (can_id ^ bit, mask)
                    if partner in level:
                        joined.add((can_id & ~bit, mask & ~bit))
                        used.update(((can_id, mask), partner))
                bit <<= 1
        primes |= level - used
        level = joined
    cover: set[Filter] = set()
    left = set(wanted)
    members = {p: _members(p) for p in primes}
    while left:
        best = max(sorted(primes), key=lambda p: len(members[p] & left))
        cover.add(best)
        left -= members[best]
    return cover


def merge(ids: Iterable[int], limit: int = MAX_FILTERS) -> list[Filter]:
    """At most ``limit`` filters that admit every identifier of ``ids`` (11-bit)."""
    if limit < 1:
        raise ValueError("at least one filter")
    filters = _exact_joins({(i & STANDARD_MASK, STANDARD_MASK) for i in ids})
    while len(filters) > limit:  # widen: the pair whose join admits the fewest extra IDs
        ordered = sorted(filters)
        best: tuple[int, Filter, Filter] | None = None
        for n, a in enumerate(ordered):
            for b in ordered[n + 1 :]:
                joined = _join(a, b)
                extra = _admitted(joined[1]) - _admitted(a[1]) - _admitted(b[1])
                if best is None or extra < best[0]:
                    best = (extra, a, b)
        assert best is not None
        _, a, b = best
        filters -= {a, b}
        filters.add(_join(a, b))
    return sorted(filters)


def matches(filters: Iterable[Filter], can_id: int) -> bool:
    """Whether a standard frame with ``can_id`` passes ``filters`` (as SocketCAN decides)."""
    return any((can_id ^ fid) & mask == 0 for fid, mask in filters)


def to_python_can(filters: Iterable[Filter]) -> list[CanFilter]:
    """python-can's ``can_filters`` form; ``extended=False``: 29-bit frames never match.

    No filter at all (an engine that listens to nothing) becomes one that no standard frame
    passes: python-can reads an empty list as "receive everything".
    """
    out: list[CanFilter] = [
        {"can_id": fid, "can_mask": mask, "extended": False} for fid, mask in filters
    ]
    return out or [{"can_id": 0, "can_mask": 0x1FFFFFFF, "extended": True}]


def describe(filters: Iterable[Filter]) -> list[str]:
    """``["080/7FF", "7EC/7FC", ...]`` for the front's status."""
    return [f"{fid:03X}/{mask:03X}" for fid, mask in filters]
