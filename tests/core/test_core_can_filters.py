"""Acceptance filters from a listen set (fieldgate.can.filters) and how the adapter applies
them: merged into few (id, mask) pairs, re-applied before the frames of the engine call that
changed them are sent, and frames outside the set counted and kept from the engine."""

from __future__ import annotations

import asyncio
import uuid

import can
import pytest

from fieldgate.can.adapter import CanAdapter
from fieldgate.can.filters import describe, matches, merge, to_python_can
from fieldgate.can.frame import Frame


def admitted(filters) -> set[int]:
    return {i for i in range(0x800) if matches(filters, i)}


@pytest.mark.parametrize(
    "ids",
    [
        {0x000},
        {0x7EC, 0x7ED, 0x7EE, 0x7EF},
        {0x428 + i for i in range(8)} | {0x408} | {0x7EC, 0x7ED, 0x7EE, 0x7EF},
        {0x000, 0x080, 0x100, 0x183, 0x203, 0x283, 0x303, 0x383, 0x403, 0x483, 0x503, 0x603},
        set(range(0x701, 0x780)),
    ],
)
def test_merging_within_the_limit_admits_exactly_the_set(ids):
    filters = merge(ids)
    assert admitted(filters) == ids
    assert len(filters) <= len(ids)


def test_aligned_blocks_become_one_filter():
    assert merge({0x7EC, 0x7ED, 0x7EE, 0x7EF}) == [(0x7EC, 0x7FC)]
    assert merge({0x428 + i for i in range(8)}) == [(0x428, 0x7F8)]
    assert len(merge(set(range(0x701, 0x780)))) <= 7  # 127 heartbeats


def test_over_the_limit_filters_widen_where_it_admits_least():
    ids = {0x000, 0x080, 0x100, 0x205, 0x305, 0x405, 0x505, 0x605, 0x705, 0x7E5, 0x701}
    filters = merge(ids, limit=3)
    assert len(filters) <= 3
    assert ids <= admitted(filters)  # never loses an identifier
    assert len(admitted(filters)) < 0x800  # and still filters


def test_python_can_form_is_standard_frames_only_and_never_empty():
    assert to_python_can([(0x605, 0x7FF)]) == [
        {"can_id": 0x605, "can_mask": 0x7FF, "extended": False}
    ]
    nothing = to_python_can([])
    assert nothing and nothing[0]["extended"] is True  # an empty list would mean "everything"
    assert describe([(0x7EC, 0x7FC)]) == ["7EC/7FC"]


class Engine:
    """A sans-I/O engine whose listen set a frame on 0x100 changes to {0x100, data[0] << 4}."""

    deadline_after_call = None

    def __init__(self, bus_log: list):
        self.ids = frozenset({0x100})
        self.got: list[int] = []
        self.bus_log = bus_log

    def listen_ids(self):
        return self.ids

    def boot(self, now):
        return []

    def receive(self, frame, now):
        self.got.append(frame.can_id)
        if frame.can_id == 0x100:
            self.ids = frozenset({0x100, frame.data[0] << 4})
            return [Frame(0x101, frame.data)]
        return []

    def tick(self, now):
        return []

    def flush(self):
        return []

    def next_deadline(self):
        return None

    def on_bit_timing(self, callback):
        pass


class LoggingBus(can.BusABC):
    """Records set_filters and send in order; frames are injected with feed()."""

    def __init__(self, log: list):
        self.log = log
        self.queue: list[can.Message] = []
        super().__init__(channel="log")
        log.clear()  # BusABC.__init__ applies "no filters"

    def feed(self, can_id: int, data: bytes = b"\x00") -> None:
        self.queue.append(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def _recv_internal(self, timeout):
        return (self.queue.pop(0) if self.queue else None), False

    def _apply_filters(self, filters):
        self.log.append(("filters", describe((f["can_id"], f["can_mask"]) for f in filters or [])))

    def send(self, msg, timeout=None):
        self.log.append(("send", msg.arbitration_id))

    def recv(self, timeout=None):  # no receive thread in this test: frames go in by hand
        return None


async def test_new_filters_are_on_the_bus_before_the_answer_that_confirms_them():
    log: list = []
    bus = LoggingBus(log)
    engine = Engine(log)
    adapter = CanAdapter(engine, bus, asyncio.get_running_loop())
    adapter.start()
    try:
        assert log == [("filters", ["100/7FF"])]
        adapter.receiving.message(
            can.Message(arbitration_id=0x100, data=b"\x32", is_extended_id=False)
        )
        assert log[1:] == [("filters", ["100/7FF", "320/7FF"]), ("send", 0x101)]
        assert adapter.listen == {0x100, 0x320}
        status = adapter.status()
        assert status["filters"] == ["100/7FF", "320/7FF"] and status["filter_updates"] == 2
    finally:
        adapter.close()


async def test_a_frame_outside_the_listen_set_is_counted_and_never_reaches_the_engine():
    log: list = []
    engine = Engine(log)
    adapter = CanAdapter(engine, LoggingBus(log), asyncio.get_running_loop())
    adapter.start()
    try:
        for can_id in (0x181, 0x7E5, 0x320):  # a widened filter or a frame queued before a change
            adapter.receiving.message(
                can.Message(arbitration_id=can_id, data=b"\x00", is_extended_id=False)
            )
        assert engine.got == []
        assert adapter.status()["rx"] == 3 and adapter.status()["rx_ignored"] == 3
        adapter.receiving.message(
            can.Message(arbitration_id=0x100, data=b"\x32", is_extended_id=False)
        )
        adapter.receiving.message(
            can.Message(arbitration_id=0x320, data=b"\x00", is_extended_id=False)
        )
        assert engine.got == [0x100, 0x320]
    finally:
        adapter.close()


async def test_an_engine_without_a_listen_set_gets_every_frame_and_no_filters():
    log: list = []
    engine = Engine(log)
    engine.listen_ids = lambda: None  # type: ignore[method-assign]
    adapter = CanAdapter(engine, LoggingBus(log), asyncio.get_running_loop())
    adapter.start()
    try:
        adapter.receiving.message(
            can.Message(arbitration_id=0x181, data=b"\x00", is_extended_id=False)
        )
        assert engine.got == [0x181] and log == []
        assert adapter.status()["filters"] is None
    finally:
        adapter.close()


async def test_python_can_software_filtering_on_the_virtual_bus_keeps_foreign_frames_out():
    ch = f"filters-{uuid.uuid4().hex[:8]}"
    peer = can.Bus(interface="virtual", channel=ch)
    log: list = []
    engine = Engine(log)
    adapter = CanAdapter(
        engine, can.Bus(interface="virtual", channel=ch), asyncio.get_running_loop()
    )
    adapter.start()
    try:
        for can_id in (0x181, 0x1FF, 0x320, 0x100):
            peer.send(can.Message(arbitration_id=can_id, data=b"\x32", is_extended_id=False))
        answer = await asyncio.to_thread(peer.recv, 2.0)
        assert answer is not None and answer.arbitration_id == 0x101
        peer.send(can.Message(arbitration_id=0x320, data=b"\x00", is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x100, data=b"\x00", is_extended_id=False))
        assert (await asyncio.to_thread(peer.recv, 2.0)).arbitration_id == 0x101
        assert engine.got == [0x100, 0x320, 0x100]  # 0x320 only after it was listened to
        assert adapter.rx_ignored == 0 and adapter.rx_frames == 3
    finally:
        adapter.close()
        peer.shutdown()


def test_the_raw_socketcan_path_is_only_taken_for_python_cans_classic_socketcan_bus():
    import socket

    from fieldgate.can import socketcan_raw

    virtual = can.Bus(interface="virtual", channel=f"raw-{uuid.uuid4().hex[:8]}")
    try:
        assert socketcan_raw.raw_socket(virtual) is None  # no socket at all
    finally:
        virtual.shutdown()

    class UdpBus(LoggingBus):  # a bus with a socket that is not AF_CAN
        def __init__(self):
            super().__init__([])
            self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    bus = UdpBus()
    try:
        assert socketcan_raw.raw_socket(bus) is None
    finally:
        bus.socket.close()


def test_raw_error_and_extended_frames_become_python_can_messages():
    from fieldgate.can import socketcan_raw as raw

    error = raw.to_message(raw.CAN_ERR_FLAG | 0x40, 8, bytes(8))
    assert error.is_error_frame and error.arbitration_id == 0x40
    extended = raw.to_message(raw.CAN_EFF_FLAG | 0x18FF0001, 2, b"\x01\x02" + bytes(6))
    assert extended.is_extended_id and extended.arbitration_id == 0x18FF0001
    assert bytes(extended.data) == b"\x01\x02"
    assert raw.FRAME.size == 16  # struct can_frame
