"""core/can/interface.py and the auto-baud front step (core/can/autobaud.py's AutoBaud), on the
host with a fake kernel (tests/fake_can_link.py): what is applied, what a failure says, a
driver without restart-ms, bus-off restarts, a front whose bit rate is found by listening
first. The real kernel: tests/socketcan/test_socketcan_can_link.py and
test_socketcan_can_gateway.py in the QEMU guest."""

from __future__ import annotations

import asyncio
import logging
import threading
import uuid
from functools import partial

import pytest
from fake_can_link import FakeKernel

from fieldgate import Gateway, load_registry
from fieldgate.can import front as canfront
from fieldgate.can.autobaud import AutoBaud, BitrateProbe, Step
from fieldgate.can.interface import InterfaceControl, controls
from fieldgate.can.link import LinkError


def test_only_socketcan_with_a_channel_is_controlled():
    assert controls("socketcan", "can0")
    assert not controls("virtual", "demo")
    assert not controls("pcan", "PCAN_USBBUS1")  # the adapter's driver sets its rate
    assert not controls("socketcan", None)


async def test_an_unmanaged_interface_is_only_read_and_a_different_rate_said():
    kernel = FakeKernel(bitrate=125_000, restart_ms=0)
    control = InterfaceControl("can0", ops=kernel.ops, managed=False)  # systemd-networkd's
    assert await control.apply(125_000) is None
    problem = await control.apply(250_000)
    assert problem is not None and "runs at 125000" in problem and "configure_interface" in problem
    assert kernel.calls == [] and kernel.bitrate == 125_000
    assert "configure_interface is false" in (await control.restart() or "")


async def test_apply_reports_what_differed_and_says_why_it_could_not():
    kernel = FakeKernel(bitrate=None, restart_ms=0)  # a controller nobody configured
    control = InterfaceControl("can0", 0.875, 100, ops=kernel.ops)
    assert await control.apply(250_000) is None
    assert (kernel.bitrate, kernel.restart_ms) == (250_000, 100)
    assert control.status()["applied"] == 1 and control.status()["bitrate"] == 250_000
    assert await control.apply(250_000) is None and control.status()["applied"] == 1  # no change
    kernel.refuse = True
    problem = await control.apply(500_000)
    assert problem is not None and "CAP_NET_ADMIN" in problem and "250000 -> 500000" in problem
    assert control.status()["error"] == problem and kernel.bitrate == 250_000
    kernel.refuse = False
    assert await control.apply(500_000) is None and control.status()["error"] is None


async def test_a_driver_without_restart_ms_gets_the_rate_and_the_front_restarts_it(caplog):
    kernel = FakeKernel(bitrate=125_000, restart_ms=0)
    kernel.restart_ms_unsupported = True  # slcan: EOPNOTSUPP
    control = InterfaceControl("slcan0", None, 100, ops=kernel.ops)
    caplog.set_level(logging.INFO, "fieldgate.can.interface")
    assert await control.apply(250_000) is None
    assert kernel.bitrate == 250_000 and control.restart_ms_unsupported
    assert not control.kernel_restarts and "has no restart-ms" in caplog.text


async def test_a_restart_that_is_refused_says_why():
    kernel = FakeKernel()
    control = InterfaceControl("can0", ops=kernel.ops)
    assert "not bus-off" in (await control.restart() or "")
    kernel.go_bus_off()
    assert await control.restart() is None
    assert control.status()["restarts_by_fieldgate"] == 1 and control.link.state == "error-active"


def test_a_vcan_interface_is_left_alone_with_a_note():
    kernel = FakeKernel(kind="vcan")
    control = InterfaceControl("vcan0", ops=kernel.ops)
    assert asyncio.run(control.apply(125_000)) is None
    assert "no bit timing" in control.status()["note"]


# -- auto-baud ------------------------------------------------------------------------------------
def fake_probing(found: int | None, steps: list[Step], started: threading.Event | None = None):
    def probing(name, probe, on_step):
        for step in steps:
            if started is not None:
                started.set()
            on_step(step)
        return found

    return probing


async def test_autobaud_reports_progress_and_the_rate_found():
    probe = BitrateProbe(dwell_s=0.01)
    steps = [Step("listen", 1_000_000), Step("listen", 500_000), Step("found", 250_000)]
    auto = AutoBaud("can0", object(), probe, fake_probing(250_000, steps))
    assert await auto.run(logging.getLogger("t")) == 250_000
    assert auto.status()["state"] == "found" and auto.status()["found"] == 250_000


async def test_autobaud_on_an_interface_it_does_not_control_opens_the_bus_as_it_is(caplog):
    auto = AutoBaud("demo", None)
    assert await auto.run(logging.getLogger("t")) is None
    assert auto.status()["state"] == "not-probed" and "does not control" in caplog.text


async def test_autobaud_refused_by_the_kernel_says_why():
    def refusing(name, probe, on_step):
        raise LinkError("can0: the controller has no listen-only mode")

    auto = AutoBaud("can0", object(), probing=refusing)
    assert await auto.run(logging.getLogger("t")) is None
    assert "listen-only" in auto.status()["why"]


async def test_a_canopen_front_with_bitrate_auto_boots_at_the_rate_found(tmp_path, monkeypatch):
    """The node boots only once the rate is found; meanwhile the gateway runs and the status shows
    the probe's progress."""
    kernel = FakeKernel(bitrate=125_000)
    release = threading.Event()
    listening = threading.Event()

    def probing(name, probe, on_step):
        probe.start(0.0)
        on_step(Step("listen", 1_000_000))
        listening.set()
        release.wait(5)
        on_step(Step("found", 500_000))
        return 500_000

    monkeypatch.setattr(canfront, "controls", lambda interface, channel: True)
    monkeypatch.setattr(canfront, "InterfaceControl", partial(InterfaceControl, ops=kernel.ops))
    monkeypatch.setattr(canfront, "AutoBaud", partial(AutoBaud, probing=probing))
    channel = f"auto-{uuid.uuid4().hex[:8]}"
    topology = {
        "gateway": {"name": "auto", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "style": "na9161",
                "interface": "virtual",
                "channel": channel,
                "node_id": 5,
                "bitrate": "auto",
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }
    import can

    peer = can.Bus(interface="virtual", channel=channel)
    gateway = Gateway.load(topology, registry=load_registry())
    await gateway.start()
    try:
        await asyncio.to_thread(listening.wait, 5)
        front = gateway.component("can")
        status = front.status()
        assert status["autobaud"]["state"] == "probing"
        assert status["autobaud"]["listening_at"] == 1_000_000 and status["bus"] is None
        assert await asyncio.to_thread(peer.recv, 0.2) is None  # no boot-up while probing
        release.set()
        boot = await asyncio.to_thread(peer.recv, 2.0)
        assert boot is not None and (boot.arbitration_id, bytes(boot.data)) == (0x705, b"\x00")
        assert kernel.bitrate == 500_000  # normal mode at the rate found
        status = front.status()
        assert (
            status["autobaud"]["state"] == "found"
            and status["services"]["lss"]["bitrate"] == 500_000
        )
    finally:
        await gateway.stop()
        peer.shutdown()


@pytest.mark.parametrize("value", [125_000, "auto", None])
def test_canopen_bitrate_takes_a_cia_rate_auto_or_null(value):
    from fieldgate.plugins.canopen.config import CanopenFrontConfig

    cfg = CanopenFrontConfig(name="can", node_id=5, bitrate=value)
    assert cfg.bitrate == value
