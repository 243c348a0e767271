"""The receive-thread path with canopen's master, on the loop ``fieldgate run`` uses (uvloop).

Reads of plain entries are answered on the receive thread; reads of the process image
(0x6000, 0x6401) always take the loop's path, and still see what the back wrote.
"""

from __future__ import annotations

import os
import uuid

import canopen
import pytest
from canopen_dut import FRONT, InProcessDut, topology

NODE = 5
uvloop = pytest.importorskip("uvloop")
pytestmark = pytest.mark.skipif(
    bool(os.environ.get("FIELDGATE_TEST_CAN")),
    reason="about the virtual bus's receive thread; on SocketCAN the loop reads the socket",
)


@pytest.fixture
def dut_and_master(tmp_path):
    channel = f"quick-{uuid.uuid4().hex[:8]}"
    dut = InProcessDut(
        topology(tmp_path, NODE), "virtual", channel, loop_factory=uvloop.new_event_loop
    )
    dut.start()
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = network.add_node(canopen.RemoteNode(NODE, canopen.ObjectDictionary()))
    yield dut, node
    network.disconnect()
    dut.stop()


def quick_answers(dut) -> int:
    return dut.call(lambda: dut.gateway.status()["fronts"][FRONT]["bus"]["quick_answers"])


def test_plain_reads_on_the_receive_thread_image_reads_on_the_loop(dut_and_master):
    dut, node = dut_and_master
    assert dut.call(
        lambda: type(dut.gateway.component(FRONT).adapter.loop).__module__.startswith("uvloop")
    )
    node.sdo.upload(0x1000, 0)  # routes the SDO COB-ID (on the loop)
    before = quick_answers(dut)
    for _ in range(50):
        assert len(node.sdo.upload(0x1000, 0)) == 4
    assert (
        quick_answers(dut) - before >= 48
    )  # a heartbeat falling due may send one or two to the loop

    node.sdo.download(0x6200, 1, bytes([0x5A]))  # DO 0-7 of module 3, looped back to its DI
    node.sdo.download(0x6411, 1, (1234).to_bytes(2, "little"))  # AO 0 -> AI 0
    before = quick_answers(dut)
    for _ in range(10):
        assert node.sdo.upload(0x6000, 1) == bytes([0x5A])
        assert node.sdo.upload(0x6401, 1) == (1234).to_bytes(2, "little")
    assert quick_answers(dut) == before  # none of the image reads left the loop's path
