"""``Node.quick_answer``: SDO reads answered from the CAN receive thread.

It must answer exactly what ``receive()`` would answer, change nothing but counters, and
decline (None) everything else so that the frame takes the event loop's path.
"""

from __future__ import annotations

import pytest
from canopen_rig import Rig, frame, seed_node, show

UPLOAD_1000 = "601 40 00 10 00 00 00 00 00"
ANSWER_1000 = "581 43 00 10 00 91 01 0F 00"


def quick(rig: Rig, text: str) -> list[str] | None:
    f = frame(text)
    answer = rig.node.quick_answer(f.can_id, f.data, rig.now)
    return None if answer is None else show([answer])


@pytest.fixture
def rig():
    rig = Rig(seed_node(1, heartbeat_ms=100))
    assert quick(rig, UPLOAD_1000) is None  # the COB-ID is not routed yet: the loop's path first
    assert rig.send(UPLOAD_1000) == [ANSWER_1000]
    return rig


def test_a_routed_read_gets_the_answer_receive_gives(rig):
    assert quick(rig, UPLOAD_1000) == [ANSWER_1000]
    for request in (
        "601 40 00 14 02 00 00 00 00",
        "601 40 17 10 00 00 00 00 00",
        "601 40 18 10 01 00 00 00 00",
    ):
        assert quick(rig, request) == rig.send(request)


def test_it_changes_nothing_but_counters(rig):
    sdo = rig.node.service("sdo")
    deadline, requests, rx = (
        rig.node.next_deadline(),
        sdo.status()["requests"],
        rig.node.status()["counters"]["rx"],
    )
    assert quick(rig, UPLOAD_1000) == [ANSWER_1000]
    assert rig.node.next_deadline() == deadline and rig.node.deadline_after_call == deadline
    assert sdo.status()["phase"] == "idle" and rig.node.flush() == []
    assert sdo.status()["requests"] == requests + 1 and sdo.status()["transfers"] == requests + 1
    assert rig.node.status()["counters"]["rx"] == rx + 1


@pytest.mark.parametrize(
    "request_",
    [
        "601 40 00 20 00 00 00 00 00",  # no such object: the abort is the loop's
        "601 40 00 10 01 00 00 00 00",  # no such sub-index
        "601 40 03 21 00 00 00 00 00",  # write-only
        "601 40 08 10 00 00 00 00 00",  # 0x1008 is 9 bytes: segmented
        "601 2B 17 10 00 C8 00 00 00",  # a write
        "601 A0 00 10 00 7F 00 00 00",  # block upload initiate
        "601 40 00 10 00 00 00 00",  # DLC 7
        "601 E0 00 10 00 00 00 00 00",  # unknown command specifier
        "602 40 00 10 00 00 00 00 00",  # another node's SDO
        "000 01 00",  # NMT
    ],
)
def test_anything_but_a_plain_expedited_read_is_declined(rig, request_):
    sdo = rig.node.service("sdo")
    before = sdo.status()
    assert quick(rig, request_) is None
    assert sdo.status() == before


def test_nothing_is_answered_in_stopped_nor_after_the_state_changes_until_routed_again(rig):
    assert rig.send("000 02 01") == []  # stop
    assert quick(rig, UPLOAD_1000) is None
    assert rig.send(UPLOAD_1000) == []  # no SDO in Stopped (CiA 301)
    assert quick(rig, UPLOAD_1000) is None
    assert rig.send("000 80 01") == []  # pre-operational
    assert quick(rig, UPLOAD_1000) is None  # routes are forgotten on a state change
    assert rig.send(UPLOAD_1000) == [ANSWER_1000]
    assert quick(rig, UPLOAD_1000) == [ANSWER_1000]


def test_declined_while_a_transfer_is_open(rig):
    assert rig.send("601 40 08 10 00 00 00 00 00")[0].startswith("581 41")  # segmented upload open
    assert quick(rig, UPLOAD_1000) is None
    assert rig.node.service("sdo").status()["phase"] == "upload"


def test_declined_when_a_timer_is_due(rig):
    rig.now = 0.15  # the heartbeat (every 100 ms) is due: the loop's path sends it with the answer
    assert quick(rig, UPLOAD_1000) is None
    assert rig.send(UPLOAD_1000) == [ANSWER_1000, "701 7F"]
    assert quick(rig, UPLOAD_1000) == [ANSWER_1000]


def test_declined_after_a_dictionary_write_until_routed_again(rig):
    assert rig.send("601 2B 17 10 00 C8 00 00 00") == ["581 60 17 10 00 00 00 00 00"]
    assert quick(rig, UPLOAD_1000) is None
    assert rig.send("601 40 17 10 00 00 00 00 00") == ["581 4B 17 10 00 C8 00 00 00"]
    assert quick(rig, "601 40 17 10 00 00 00 00 00") == ["581 4B 17 10 00 C8 00 00 00"]


def test_a_failing_getter_is_declined_and_the_loop_path_aborts(rig):
    def broken():
        raise RuntimeError("back end bug")

    rig.node.od.bind(0x1017, 0, getter=broken)
    rig.send(UPLOAD_1000)  # route again after the binding
    assert quick(rig, "601 40 17 10 00 00 00 00 00") is None
    assert rig.send("601 40 17 10 00 00 00 00 00") == [
        "581 80 17 10 00 00 00 06 06"
    ]  # hardware error


def test_extra_sdo_channels_answer_quickly_too():
    rig = Rig(seed_node(1, sdo_servers=2))
    for sub, value in ((1, 0x690), (2, 0x6A0)):
        request = f"601 23 01 12 {sub:02X} " + value.to_bytes(4, "little").hex(" ").upper()
        assert rig.send(request) == [f"581 60 01 12 {sub:02X} 00 00 00 00"]
    assert rig.send("690 40 00 10 00 00 00 00 00") == ["6A0 43 00 10 00 91 01 0F 00"]
    assert quick(rig, "690 40 00 10 00 00 00 00 00") == ["6A0 43 00 10 00 91 01 0F 00"]


# -- what may be read on the receive thread -------------------------------------------------
# Process-image getters are the event loop's (the image has no locks): a read of 8 DI
# channels packed in 0x6000 could mix two updates, and 0x6422 clears what it reads.


def io_quick(b, index: int, sub: int) -> str | None:
    answer = b.node.quick_answer(
        0x601, bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]), b.clock.t
    )
    return None if answer is None else answer.data.hex(" ").upper()


@pytest.fixture
def io():
    from io_bench import demo_7232d

    b = demo_7232d()
    b.start()
    for index, sub in (
        (0x1000, 0),
        (0x6000, 1),
        (0x6401, 1),
        (0x6422, 1),
        (0x1001, 0),
        (0x1003, 0),
        (0x1010, 1),
    ):
        b.read(index, sub)  # routes the SDO server and fills the read cache
    return b


@pytest.mark.parametrize("index, sub", [(0x6000, 1), (0x6401, 1), (0x6422, 1), (0x6200, 1)])
def test_process_image_entries_are_left_to_the_loop(io, index, sub):
    assert io_quick(io, index, sub) is None
    assert io.read(index, sub).startswith(("4F", "4B", "43"))  # the loop's path answers them


def test_a_read_and_clear_entry_is_never_read_on_the_receive_thread(io):
    profile = io.io.profile.analog
    calls = []
    original = profile.read_source

    def counting(*args):
        calls.append(args)
        return original(*args)

    profile.read_source = counting
    io.node.od.generation += 1  # the read cache holds the getter it looked up
    io.read(0x6000, 1)  # route again
    assert io_quick(io, 0x6422, 1) is None
    assert calls == []


def test_plain_values_and_thread_safe_getters_are_read_on_the_receive_thread(io):
    assert io_quick(io, 0x1000, 0) == io.read(0x1000, 0)
    assert io_quick(io, 0x1010, 1) == "43 10 10 01 01 00 00 00"
    assert io_quick(io, 0x1001, 0) == "4F 01 10 00 00 00 00 00"
    io.node.emcy.raise_error(0x8130, 0x10)
    io.flush()
    io.read(0x1000, 0)  # route again (raising an error changed no dictionary value: still routed)
    assert io_quick(io, 0x1001, 0) == "4F 01 10 00 11 00 00 00"  # communication + generic
    assert io_quick(io, 0x1003, 0) == "4F 03 10 00 01 00 00 00"
    assert io_quick(io, 0x1003, 1) == io.read(0x1003, 1)


def test_an_input_change_outside_a_call_is_never_overtaken_by_a_quick_answer(io):
    """A DI change queues a TPDO (sent when the loop runs the engine): an SDO read that
    arrives after it must not be answered first."""
    assert io_quick(io, 0x1000, 0) is not None
    io.image.update_input("bus/m1/di0", True)  # a back's poll result, on the loop
    assert io_quick(io, 0x1000, 0) is None
    assert io.flush() == ["181 [1] 01"]  # what the loop's wake-up does: the TPDO goes first
    assert io_quick(io, 0x1000, 0) == io.read(0x1000, 0)


def test_a_frame_waiting_in_the_outbox_is_never_overtaken(io):
    io.node.emcy.raise_error(0x5000)  # from outside a call: waits in the outbox
    assert io_quick(io, 0x1000, 0) is None
    assert [f.split(" ")[0] for f in io.flush()] == ["081"]
    assert io_quick(io, 0x1000, 0) is not None
