"""The ``canopen-device`` front as a whole on python-can's virtual bus: a hook that really
sleeps (1 s, on a hook thread) delays no other object's SDO answer or TPDO; the topology's
bindings carry entries to and from the process image (a loopback back: DO n -> DI n).

No timed asserts: what is checked is the order in which frames arrive."""

from __future__ import annotations

import uuid
from pathlib import Path

import can
import pytest

REPO = Path(__file__).resolve().parents[3]
BATTERY = REPO / "examples" / "canopen-device" / "battery.eds"
SLOW_HOOKS = """
import time


def setup(device):
    @device.on_write(0x2100)
    def slow(index, sub, value):
        time.sleep(1.0)

    @device.on_read(0x2102)
    def crash(index, sub):
        raise RuntimeError("broken sensor")
"""


@pytest.fixture
def pack(tmp_path, fieldgate_thread):
    channel = f"dev-{uuid.uuid4().hex[:8]}"
    hooks = tmp_path / "slow_hooks.py"
    hooks.write_text(SLOW_HOOKS)
    eds = tmp_path / "pack.eds"
    eds.write_text(BATTERY.read_text())
    topology = {
        "gateway": {"name": "slow-pack", "state_dir": str(tmp_path / "state")},
        "fronts": [
            {
                "name": "pack",
                "type": "canopen-device",
                "interface": "virtual",
                "channel": channel,
                "node_id": 5,
                "eds": str(eds),
                "hooks": str(hooks),
                "hook_timeout_ms": 3000,
                "bind": {"0x2103": "io/m1/di0", "0x2104": "io/m1/do0"},
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }
    fieldgate_thread(topology, simulate=False)
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield bus
    bus.shutdown()


def send(bus: can.BusABC, can_id: int, data: str) -> None:
    bus.send(can.Message(arbitration_id=can_id, data=bytes.fromhex(data), is_extended_id=False))


def frames_until(bus: can.BusABC, can_id: int, timeout: float = 5.0) -> list[can.Message]:
    """Every frame up to and including the first one with ``can_id``."""
    seen = []
    while True:
        msg = bus.recv(timeout)
        assert msg is not None, [f"{m.arbitration_id:03X}" for m in seen]
        seen.append(msg)
        if msg.arbitration_id == can_id:
            return seen


def sdo(bus: can.BusABC, request: str) -> bytes:
    send(bus, 0x605, request)
    return bytes(frames_until(bus, 0x585)[-1].data)


def test_a_sleeping_hook_delays_no_other_sdo_or_tpdo(pack):
    send(pack, 0x000, "01 05")
    send(pack, 0x605, "2F 00 21 00 3C 00 00 00")  # to the hook that sleeps 1 s
    send(pack, 0x080, "")  # SYNC: TPDO1
    tpdo = frames_until(pack, 0x185)
    assert [m.arbitration_id for m in tpdo if m.arbitration_id == 0x585] == []
    # the same client gives up waiting and reads another object: answered at once
    assert sdo(pack, "40 18 10 01 00 00 00 00") == bytes.fromhex("43 18 10 01 CE 0A 00 00")
    assert sdo(pack, "40 00 21 00 00 00 00 00") == bytes.fromhex("4F 00 21 00 5A 00 00 00")
    # a write that waits for the slow hook to the end: answered once it returned
    send(pack, 0x605, "2F 00 21 00 3D 00 00 00")
    send(pack, 0x080, "")
    order = [m.arbitration_id for m in frames_until(pack, 0x585)]
    assert order.index(0x185) < order.index(0x585)  # the TPDO came first
    assert sdo(pack, "40 00 21 00 00 00 00 00") == bytes.fromhex("4F 00 21 00 3D 00 00 00")


def test_a_crashing_hook_is_an_abort_and_bindings_reach_the_image(pack):
    assert sdo(pack, "40 02 21 00 00 00 00 00") == bytes.fromhex("80 02 21 00 20 00 00 08")
    assert sdo(pack, "2F 04 21 00 01 00 00 00") == bytes.fromhex("60 04 21 00 00 00 00 00")
    # the fan relay (DO0) loops back to the door switch (DI0): 0x2103 follows
    for _ in range(50):
        if sdo(pack, "40 03 21 00 00 00 00 00")[4] == 1:
            break
    else:
        pytest.fail("0x2103 never followed the loopback input")
