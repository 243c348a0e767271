"""Real SocketCAN, end to end. Runs inside User-Mode Linux (`.ci/socketcan/run`), skipped elsewhere.

The SocketCAN stage (.ci/socketcan/run) creates vcan0 and sets FIELDGATE_TEST_CAN=socketcan:vcan0. These tests prove
that python-can's socketcan interface really carries frames between processes, then run
the CANopen integration tests (every tests/canopen module that starts its device through
canopen_dut, which reads FIELDGATE_TEST_CAN) over vcan0, with the gateway started from
the CLI as its own process.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import can
import pytest
from socketcan_guest import in_guest, scaled

CHANNEL = "vcan0"
REPO = Path(__file__).resolve().parents[2]

pytestmark = in_guest(CHANNEL)

ECHO_PEER = textwrap.dedent(
    """
    import can, sys
    bus = can.Bus(interface="socketcan", channel=sys.argv[1])
    print("ready", flush=True)
    while True:
        msg = bus.recv(5.0)
        if msg is None:
            sys.exit(3)
        if msg.arbitration_id == 0x7FF:
            break
        # Answer on id + 1 with the payload reversed, as a second process on the bus.
        bus.send(can.Message(arbitration_id=msg.arbitration_id + 1,
                             data=bytes(reversed(msg.data)), is_extended_id=False))
    bus.shutdown()
    """
)


def _recv_id(bus: can.BusABC, can_id: int, timeout: float = 2.0) -> can.Message:
    timeout = scaled(timeout)
    while True:
        msg = bus.recv(timeout)
        assert msg is not None, f"no frame with id {can_id:#x} within {timeout} s"
        if msg.arbitration_id == can_id:
            return msg


def test_frames_cross_between_two_processes_on_vcan0():
    peer = subprocess.Popen(
        [sys.executable, "-c", ECHO_PEER, CHANNEL], stdout=subprocess.PIPE, text=True
    )
    try:
        assert peer.stdout.readline().strip() == "ready"
        with can.Bus(interface="socketcan", channel=CHANNEL) as bus:
            for n in range(20):
                payload = bytes([n, 0x10, 0x20, 0x30, 0x40, 0x50, 0x60, n ^ 0xFF])
                bus.send(can.Message(arbitration_id=0x600 + n, data=payload, is_extended_id=False))
                echo = _recv_id(bus, 0x601 + n)
                assert bytes(echo.data) == bytes(reversed(payload))
                assert echo.channel == CHANNEL
            bus.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
        assert peer.wait(scaled(10)) == 0
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait()


def test_socketcan_does_not_echo_own_frames_unless_asked():
    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as quiet,
        can.Bus(interface="socketcan", channel=CHANNEL, receive_own_messages=True) as loud,
    ):
        quiet.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        assert _recv_id(loud, 0x123).data == b"\x01"
        assert quiet.recv(0.2) is None
        loud.send(can.Message(arbitration_id=0x124, data=b"\x02", is_extended_id=False))
        assert _recv_id(loud, 0x124).data == b"\x02"
        assert _recv_id(quiet, 0x124).data == b"\x02"


def test_kernel_filters_apply_on_vcan0():
    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
        can.Bus(
            interface="socketcan",
            channel=CHANNEL,
            can_filters=[{"can_id": 0x7E4, "can_mask": 0x7FF, "extended": False}],
        ) as rx,
    ):
        tx.send(can.Message(arbitration_id=0x7E5, data=bytes(8), is_extended_id=False))
        tx.send(
            can.Message(
                arbitration_id=0x7E4, data=bytes([0x5E, 5]) + bytes(6), is_extended_id=False
            )
        )
        msg = rx.recv(scaled(2.0))
        assert msg is not None and msg.arbitration_id == 0x7E4
        assert rx.recv(0.2) is None


async def test_socketcan_is_read_by_the_event_loop_without_a_thread():
    """The CANopen front's receive path on SocketCAN: loop.add_reader on the raw socket."""
    import asyncio
    import threading

    from fieldgate.can.busrx import start_receiver

    got, done = [], asyncio.Event()

    def on_message(msg):
        got.append((msg.arbitration_id, bytes(msg.data), threading.get_ident()))
        if len(got) == 50:
            done.set()

    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as rx,
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
    ):
        threads_before = threading.active_count()
        receiver = start_receiver(rx, asyncio.get_running_loop(), on_message)
        assert receiver.mode == "add-reader"
        assert threading.active_count() == threads_before
        for n in range(50):
            tx.send(can.Message(arbitration_id=0x180 + n, data=bytes([n]), is_extended_id=False))
        await asyncio.wait_for(done.wait(), scaled(5))
        receiver.stop()
    assert [(i, d) for i, d, _ in got] == [(0x180 + n, bytes([n])) for n in range(50)]
    assert {t for _, _, t in got} == {threading.get_ident()}


CANOPEN_TESTS = REPO / "tests" / "canopen"


@pytest.mark.timeout(420)  # a child pytest of every canopen_dut test: minutes on a busy host
def test_canopen_integration_suite_passes_over_vcan0_with_gateway_as_a_process():
    """The same integration tests as in-process, over vcan0, the gateway run from the CLI."""
    # Every test module that starts its device through the shared DUT fixture.
    selected = sorted(
        str(p) for p in CANOPEN_TESTS.rglob("test_*.py") if "canopen_dut" in p.read_text()
    )
    assert len(selected) >= 2, f"the CANopen integration tests in {CANOPEN_TESTS} are missing"
    env = dict(os.environ, FIELDGATE_TEST_CAN=f"socketcan:{CHANNEL}")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-m",
            "not socketcan",
            *selected,
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=scaled(400),
    )
    summary = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-2000:]
    passed = re.search(r"(\d+) passed", summary)
    assert passed and int(passed.group(1)) > 0, summary
