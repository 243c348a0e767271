"""CAN controller health over real SocketCAN (vcan0 inside the guest of .ci/socketcan/run).

* Controller error frames (``CAN_ERR_CRTL``: warning, passive, back to active; controller
  overflow) sent on vcan0 reach the gateway the way a CAN driver delivers them, through the
  raw socket's error-frame subscription: the I-7232D's EMCYs and their error reset.
* A software Rx overrun for real: the gateway's event loop is blocked while another process
  floods vcan0 with frames the node listens to (SYNC with a wrong length: counted, harmless),
  so the kernel drops what its socket buffer cannot hold; the kernel's drop counter
  (``SO_RXQ_OVFL``) makes the gateway send EMCY ``10 81 11 04`` once it reads again.
"""

from __future__ import annotations

import asyncio
import socket
import sys
import time
from pathlib import Path

import can
import pytest
from socketcan_guest import in_guest, scaled
from test_socketcan_can_load import CHANNEL, flood_result, start_flood

from fieldgate import Gateway, load_registry
from fieldgate.can import socketcan_raw

REPO = Path(__file__).resolve().parents[2]
NODE = 5
EMCY = 0x80 + NODE
CAN_ERR_CRTL = 0x04

pytestmark = in_guest(CHANNEL)


def topology(state_dir: Path) -> dict:
    return {
        "gateway": {"name": "can-health", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "socketcan",
                "channel": CHANNEL,
                "node_id": NODE,
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }


async def emcys(bus: can.BusABC, seconds: float) -> list[bytes]:
    loop = asyncio.get_running_loop()
    end, got = loop.time() + scaled(seconds), []
    while loop.time() < end:
        msg = await asyncio.to_thread(bus.recv, 0.05)
        if msg is not None and msg.arbitration_id == EMCY and not msg.is_error_frame:
            got.append(bytes(msg.data))
    return got


@pytest.fixture
async def gateway(tmp_path):
    gw = Gateway.load(topology(tmp_path), registry=load_registry())
    await gw.start()
    peer = can.Bus(interface="socketcan", channel=CHANNEL)
    peer.set_filters([{"can_id": EMCY, "can_mask": 0x7FF, "extended": False}])
    await asyncio.sleep(scaled(0.2))
    yield gw, peer
    peer.shutdown()
    await gw.stop()


def error_frame(bus: can.BusABC, crtl: int) -> None:
    bus.send(
        can.Message(
            arbitration_id=CAN_ERR_CRTL,
            is_error_frame=True,
            is_extended_id=False,
            data=bytes([0, crtl, 0, 0, 0, 0, 0, 0]),
        )
    )


async def test_controller_states_and_overflow_from_error_frames(gateway):
    gw, peer = gateway
    adapter = gw.component("can").adapter
    error_frame(peer, 0x04)  # RX warning
    assert await emcys(peer, 0.5) == [bytes.fromhex("0010810100000000")]
    assert adapter.status()["controller"] == "warning"
    error_frame(peer, 0x40)  # back to error-active
    assert await emcys(peer, 0.5) == [bytes(8)]
    error_frame(peer, 0x01)  # the controller lost frames
    got = await emcys(peer, 1.8)  # the overrun error, then its reset after a quiet second
    assert got == [bytes.fromhex("1081110600000000"), bytes(8)], got
    assert adapter.status()["overruns"]["controller"] == 1


async def test_a_blocked_loop_under_a_flood_is_an_rx_overrun(gateway):
    gw, peer = gateway
    adapter = gw.component("can").adapter
    # a small socket buffer (a small gateway's default), so a second's flood overflows it
    sock = socketcan_raw.raw_socket(adapter.bus)
    assert sock is not None, "the raw SocketCAN path"
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16384)
    proc = start_flood(1.0, ids="0x80")  # SYNC with 8 bytes: the node's, of the wrong length
    time.sleep(scaled(1.2))  # the gateway's loop is blocked: the socket buffer overflows
    flood_result(proc)
    # traffic goes on: a frame queued after the drops carries the kernel's count (SO_RXQ_OVFL)
    await asyncio.sleep(scaled(0.2))
    for _ in range(3):
        peer.send(can.Message(arbitration_id=0x80, data=bytes(8), is_extended_id=False))
        await asyncio.sleep(0.05)
    got = await emcys(peer, 2.5)  # the state poll (1 s) sees the drops
    assert bytes.fromhex("1081110400000000") in got, (got, adapter.status())
    assert adapter.status()["rx_dropped"] > 0 and adapter.status()["overruns"]["rx"] >= 1
    node = gw.component("can").node
    assert node.service("sync").counters["bad_length"] > 0  # what was read was counted
    print(f"dropped by the kernel: {adapter.status()['rx_dropped']}", file=sys.stderr)
