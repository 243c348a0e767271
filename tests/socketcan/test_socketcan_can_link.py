"""core/can/link.py and autobaud.py on real CAN controller drivers: two SJA1000s (QEMU's
kvaser_pci, the kernel's kvaser_pci + sja1000 drivers) on one QEMU can-bus.

Run by `.ci/socketcan/run --can-controllers python -m pytest -m can_controller ...`
(scripts/test --socketcan does). `ip -details -json link` (iproute2) is the independent
reader of what the kernel holds. QEMU's can-bus carries frames whatever the controllers'
bit rates (no bit-level emulation) and its SJA1000 never counts errors: these tests show
the kernel drivers take, keep and apply what fieldgate sets; the bit-rate physics is the
sender's part in the auto-baud test, and bus-off is driven through slcan
(test_socketcan_slcan.py). docs/can-link.md.
"""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import threading
import time

import pytest
from socketcan_guest import scaled, with_controllers

from fieldgate.can import link as canlink
from fieldgate.can.autobaud import BitrateProbe, probe_bitrate
from fieldgate.can.link import LinkError, LinkSettings

pytestmark = with_controllers(2)
FRAME = struct.Struct("=IB3x8s")


def ip_details(name: str) -> dict:
    out = subprocess.run(
        ["ip", "-details", "-json", "link", "show", name],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return json.loads(out)[0]


def raw(name: str, timeout: float = 2.0, only_id: int | None = None) -> socket.socket:
    """A raw CAN socket on ``name``; with ``only_id`` it receives that identifier alone.

    The filter matters on a slow guest: a controller's echo of a frame sent earlier on the
    same interface (the kernel's loopback, given on the driver's TX-done interrupt) can
    reach a socket opened after the send, and must not be taken for the frame under test.
    """
    sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    if only_id is not None:
        sock.setsockopt(
            socket.SOL_CAN_RAW, socket.CAN_RAW_FILTER, struct.pack("=II", only_id, 0x7FF)
        )
    sock.bind((name,))
    sock.settimeout(scaled(timeout))
    return sock


def exchange(a: str, b: str, can_id: int) -> bytes:
    """One frame from ``a`` received on ``b``; its data."""
    with raw(a) as tx, raw(b, only_id=can_id) as rx:
        tx.send(FRAME.pack(can_id, 3, b"\x01\x02\x03"))
        word, dlc, data = FRAME.unpack(rx.recv(FRAME.size))
        assert word == can_id
        return data[:dlc]


def test_the_bit_rate_set_through_netlink_is_what_the_kernel_holds_and_traffic_flows(pair):
    a, b = pair
    first = canlink.apply_settings(a, LinkSettings(250000, sample_point=0.875, restart_ms=100))
    canlink.apply_settings(b, LinkSettings(250000))
    assert first.changed and first.link.up
    assert (first.link.bitrate, first.link.sample_point, first.link.restart_ms) == (
        250000,
        0.875,
        100,
    )
    assert first.link.timing_const == "sja1000" and first.link.clock_hz == 8_000_000
    seen = ip_details(a)["linkinfo"]["info_data"]
    assert seen["bittiming"]["bitrate"] == 250000
    assert float(seen["bittiming"]["sample_point"]) == 0.875
    assert seen["restart_ms"] == 100 and seen["state"] == "ERROR-ACTIVE"
    assert exchange(a, b, 0x181) == b"\x01\x02\x03"
    # again with the same settings: nothing to change, the interface is not bounced
    again = canlink.apply_settings(a, LinkSettings(250000, sample_point=0.875, restart_ms=100))
    assert not again.changed and again.link.up
    # a new rate (an LSS or DeviceNet switch): down, set, up on both, traffic at the new rate
    for name in pair:
        moved = canlink.apply_settings(name, LinkSettings(500000))
        assert moved.differences == ["bit rate 250000 -> 500000"]
        assert ip_details(name)["linkinfo"]["info_data"]["bittiming"]["bitrate"] == 500000
    assert exchange(b, a, 0x201) == b"\x01\x02\x03"


def test_controller_state_counters_and_restart(pair):
    a, b = pair
    canlink.apply_settings(a, LinkSettings(125000, restart_ms=0))
    up = canlink.read_link(a)
    assert (up.state, up.tx_errors, up.rx_errors) == ("error-active", 0, 0)
    assert up.counters["bus_off"] == 0 and up.counters["restarts"] == 0
    with pytest.raises(LinkError, match="not restarted: the controller is not bus-off"):
        canlink.restart(a)
    canlink.apply_settings(a, LinkSettings(125000, restart_ms=200))
    with pytest.raises(LinkError, match="restart-ms is 200: the kernel restarts it by itself"):
        canlink.restart(a)
    canlink.set_up(a, False)
    assert canlink.read_link(a).state == "stopped"
    # an interface restart (down, up): the controller serves again
    canlink.set_up(a, True)
    canlink.apply_settings(b, LinkSettings(125000))
    assert exchange(a, b, 0x701) == b"\x01\x02\x03"
    canlink.set_up(b, False)  # (on a running interface the kernel answers EBUSY first)
    with pytest.raises(
        LinkError, match="setting bit rate 10: the controller cannot make it from its clock"
    ):
        canlink.configure(b, bitrate=10)  # beyond the SJA1000's prescaler


def test_a_rate_change_on_a_running_interface_is_refused_by_the_kernel(pair):
    a, _ = pair
    canlink.apply_settings(a, LinkSettings(125000))
    with pytest.raises(LinkError, match="Device or resource busy"):
        canlink.configure(a, bitrate=250000)


def test_listen_only_receives_but_never_sends(pair):
    a, b = pair
    canlink.apply_settings(a, LinkSettings(125000, listen_only=True))
    canlink.apply_settings(b, LinkSettings(125000))
    assert canlink.read_link(a).listen_only is True
    assert ip_details(a)["linkinfo"]["info_data"]["ctrlmode"] == ["LISTEN-ONLY"]
    assert exchange(b, a, 0x123) == b"\x01\x02\x03"
    with raw(a) as tx, raw(b, timeout=0.5, only_id=0x124) as rx:
        try:
            tx.send(FRAME.pack(0x124, 1, b"\x01"))
        except OSError:
            pass  # a driver may refuse at once; either way nothing reaches the bus
        with pytest.raises(TimeoutError):
            rx.recv(FRAME.size)
    assert canlink.apply_settings(a, LinkSettings(125000)).differences == ["listen-only off"]


def test_auto_baud_listens_at_each_rate_until_frames_come_then_takes_normal_mode(pair):
    """The bus runs at 250 kbit/s (``b`` sends a frame every 20 ms). QEMU would carry the
    frames at any rate, so the sender stands for the physics: it sends only while the
    listener's bit rate, read from the kernel, is the bus's. It also records whether the
    listener was in listen-only mode at each frame."""
    a, b = pair
    canlink.apply_settings(b, LinkSettings(250000))
    canlink.set_up(a, False)
    stop = threading.Event()
    modes: list[bool | None] = []

    def bus() -> None:
        with raw(b) as tx:
            while not stop.is_set():
                listener = canlink.read_link(a)
                if listener.up and listener.bitrate == 250000:
                    modes.append(listener.listen_only)
                    tx.send(FRAME.pack(0x185, 2, b"\x00\x01"))
                time.sleep(0.02)

    sender = threading.Thread(target=bus, daemon=True)
    sender.start()
    steps: list[tuple[str, int | None]] = []
    try:
        probe = BitrateProbe(rates=[1_000_000, 500_000, 250_000, 125_000], dwell_s=scaled(1.0))
        found = probe_bitrate(a, probe, on_step=lambda s: steps.append((s.action, s.bitrate)))
    finally:
        stop.set()
        sender.join(scaled(5))
    assert found == 250000
    # fastest first; on a starved host the sender may miss a dwell, then a later round finds it
    assert steps[:3] == [("listen", 1_000_000), ("listen", 500_000), ("listen", 250_000)]
    assert steps[-1] == ("found", 250_000) and [s for s in steps if s[0] == "found"] == steps[-1:]
    assert modes and modes[0] is True  # the first frames came while it only listened
    after = canlink.read_link(a)
    assert (after.bitrate, after.listen_only, after.up) == (250000, False, True)
    assert exchange(a, b, 0x705) == b"\x01\x02\x03"  # normal mode: it sends now
