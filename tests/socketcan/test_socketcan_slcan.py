"""core/can/link.py on the kernel's slcan driver: a serial-line CAN adapter (CANable, USBtin,
Lawicel) whose adapter side is this test, on a pseudo-terminal.

slcan is a real can-dev driver: the bit rate set through netlink becomes the adapter's
``S<n>`` command when the interface comes up, and the adapter's state reports (``sw...``,
``sp...``, ``sb...``) drive the kernel's controller state machine, bus-off included, which
QEMU's emulated controllers never leave (test_socketcan_can_link.py). slcan has no restart
of its own (no ``do_set_mode``): :func:`fieldgate.can.link.restart` takes it down and up,
and restart-ms is refused. docs/can-link.md.
"""

from __future__ import annotations

import fcntl
import os
import pty
import struct
import subprocess
import termios
import threading
import time
import tty
from pathlib import Path

import pytest
from socketcan_guest import in_guest, scaled

from fieldgate.can import link as canlink
from fieldgate.can.link import LinkError, LinkSettings

N_SLCAN = 17
SIOCGIFNAME = 0x8910
pytestmark = [
    *in_guest(),
    pytest.mark.skipif(
        not Path("/sys/module/slcan").exists(), reason="no slcan module in this guest"
    ),
]


class Adapter:
    """The serial side of an slcan adapter: acknowledges each command with CR and keeps
    what the kernel sent; ``report`` writes a line to the kernel."""

    def __init__(self) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        fcntl.ioctl(self.slave, termios.TIOCSETD, struct.pack("i", N_SLCAN))
        name = fcntl.ioctl(self.slave, SIOCGIFNAME, b"\0" * 16)
        self.name = name.split(b"\0")[0].decode()
        self.commands: list[str] = []
        self.lock = threading.Lock()
        self.reader = threading.Thread(target=self._serve, daemon=True)
        self.reader.start()

    def _serve(self) -> None:
        pending = b""
        while True:
            try:
                pending += os.read(self.master, 256)
            except OSError:
                return
            while b"\r" in pending:
                line, pending = pending.split(b"\r", 1)
                with self.lock:
                    self.commands.append(line.decode())
                try:
                    os.write(self.master, b"\r")
                except OSError:  # closed by the test meanwhile
                    return

    def report(self, line: str) -> None:
        os.write(self.master, line.encode() + b"\r")

    def wait_for(self, check, what: str) -> None:
        deadline = time.monotonic() + scaled(5)
        while time.monotonic() < deadline:
            if check():
                return
            time.sleep(0.02)
        raise AssertionError(f"never: {what}")

    def close(self) -> None:
        os.close(self.slave)  # the kernel unregisters the interface
        os.close(self.master)


@pytest.fixture
def adapter():
    adapter = Adapter()
    yield adapter
    adapter.close()


def test_the_bit_rate_reaches_the_adapter_and_rates_it_cannot_do_are_refused(adapter):
    name = adapter.name
    with pytest.raises(LinkError, match=rf"{name} cannot run at 83333 bit/s \(its rates: 10000,"):
        canlink.apply_settings(name, LinkSettings(83333))
    applied = canlink.apply_settings(name, LinkSettings(125000))
    assert applied.differences == ["bit rate unset -> 125000"]
    assert (applied.link.bitrate, applied.link.up) == (125000, True)
    adapter.wait_for(lambda: "O" in adapter.commands, "the adapter opened")
    assert adapter.commands[-3:] == ["C", "S4", "O"]  # S4: 125 kbit/s
    canlink.set_up(name, False)
    with pytest.raises(
        LinkError, match="restart-ms 100: the interface's driver does not support it"
    ):
        canlink.configure(name, restart_ms=100)


def test_bus_off_is_read_back_and_recovered_by_an_explicit_restart(adapter):
    name = adapter.name
    canlink.apply_settings(name, LinkSettings(250000))
    assert canlink.read_link(name).state == "error-active"
    steps = [
        ("sw100010", "error-warning"),
        ("sp130010", "error-passive"),
        ("sb256256", "bus-off"),
    ]
    for line, state in steps:
        adapter.report(line)
        adapter.wait_for(lambda s=state: canlink.read_link(name).state == s, state)
    off = canlink.read_link(name)
    assert off.counters["bus_off"] == 1 and off.counters["error_warning"] == 1
    assert off.counters["error_passive"] == 1
    details = subprocess.run(
        ["ip", "-details", "link", "show", name], capture_output=True, text=True, check=True
    ).stdout
    assert "state BUS-OFF" in details
    opened = len([c for c in adapter.commands if c == "O"])
    assert canlink.restart(name) == "down/up"  # slcan has no restart of its own
    back = canlink.read_link(name)
    assert (back.state, back.up, back.bitrate) == ("error-active", True, 250000)
    adapter.wait_for(
        lambda: len([c for c in adapter.commands if c == "O"]) == opened + 1, "reopened"
    )
    assert "S5" in adapter.commands  # the rate went to the adapter again (250 kbit/s)


async def test_a_gateway_recovers_from_a_real_bus_off_on_slcan(adapter, tmp_path):
    """The CANopen front on slcan: the configured rate reaches the adapter (slcan has no
    restart-ms: left out); the adapter reports bus-off, the kernel's error frame reaches the
    front, which restarts the controller itself (down/up) and the node reports the recovery
    with EMCY 0x8140 (docs/can-link.md, "In the CAN fronts")."""
    import asyncio

    from fieldgate import Gateway, load_registry

    name = adapter.name
    topology = {
        "gateway": {"name": "slcan", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "socketcan",
                "channel": name,
                "node_id": 5,
                "bitrate": 250000,
                "restart_ms": 100,
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }
    gateway = Gateway.load(topology, registry=load_registry())
    await gateway.start()
    try:
        front = gateway.component("can")
        assert canlink.read_link(name).bitrate == 250000 and "S5" in adapter.commands
        assert front.interface.restart_ms_unsupported
        await asyncio.to_thread(
            adapter.wait_for, lambda: "t705100" in adapter.commands, "the boot-up"
        )
        opened = adapter.commands.count("O")
        adapter.report("sb256256")  # the adapter's controller is bus-off
        await asyncio.to_thread(
            adapter.wait_for, lambda: adapter.commands.count("O") > opened, "reopened"
        )
        await asyncio.to_thread(
            adapter.wait_for,
            lambda: any(c.startswith("t0858408111") for c in adapter.commands),
            "EMCY 0x8140 (recovered from bus-off)",
        )
        bus = front.status()["bus"]
        assert (bus["bus_off_events"], bus["bus_off_recoveries"]) == (1, 1)
        assert bus["link"]["restarts_by_fieldgate"] == 1 and bus["link"]["bus_off"] >= 1
        assert canlink.read_link(name).state == "error-active"
    finally:
        await gateway.stop()
