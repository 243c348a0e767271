"""A lost port (adapter pulled, pty hung up) takes every module of the line offline at once.

The scheduler side, step by step with a fake clock; the backs' real ports are in
tests/faults/test_port_loss.py.
"""

import pytest
from test_core_polling import drain, make_line

from fieldgate import HealthEvent, Quality
from fieldgate.polling import LineLost


class Lost:
    """A module action that fails the way a gone port does."""

    def __init__(self):
        self.calls = 0

    async def __call__(self, *args):
        self.calls += 1
        raise LineLost("/dev/ttyUSB0: read failed: [Errno 5] Input/output error")


async def test_the_first_failed_transaction_takes_every_module_offline(monkeypatch):
    line, modules, image, health, clock, log = make_line(3)
    await drain(line)
    events = []
    for h in health.values():
        h.subscribe(lambda h, e: events.append((h.address, e)))
    assert all(h.online for h in health.values())
    lost = Lost()
    clock.t += 1.0
    monkeypatch.setattr(modules[0], "read_inputs", lost)
    with pytest.raises(LineLost):
        await drain(line)
    assert lost.calls == 1  # one transaction, not fail_threshold + 1 timeouts per module
    assert [h.online for h in health.values()] == [False, False, False]
    assert [e for e in events if e[1] is HealthEvent.OFFLINE] == [
        (1, HealthEvent.OFFLINE),
        (2, HealthEvent.OFFLINE),
        (3, HealthEvent.OFFLINE),
    ]
    assert {image[cid].quality for m in modules for cid in m.inputs + m.outputs} == {
        Quality.COMM_FAULT
    }
    assert line.status()["port_losses"] == 1
    assert all(h.errors["io"] == 1 and h.error_counter == 1 for h in health.values())


async def test_a_write_cut_by_the_loss_is_kept_and_every_module_is_probed_after_the_reopen(
    monkeypatch,
):
    line, modules, image, health, clock, log = make_line(2)
    await drain(line)
    image.write_output(modules[1].outputs[0], True, origin="can")
    with monkeypatch.context() as m:
        m.setattr(modules[1], "send_outputs", Lost())
        with pytest.raises(LineLost):
            await drain(line)
    assert line.pending_writes == 1  # not lost with the port
    clock.t += 0.5  # well before the offline probe period (5 s)
    line.line_reopened()
    log.clear()
    await drain(line)
    assert [h.online for h in health.values()] == [True, True]
    assert ("write", 2, {modules[1].outputs[0]: True}) in log
    assert {image[cid].quality for m in modules for cid in m.inputs} == {Quality.GOOD}
    assert [m.onlines for m in modules] == [2, 2]  # on_online ran again (watchdogs set up again)


async def test_a_job_that_finds_the_port_gone_stops_the_line_too():
    from fieldgate.polling import LineJob

    line, modules, image, health, clock, log = make_line(1)
    await drain(line)
    line.add_job(LineJob("host-ok", 1.0, Lost()))
    with pytest.raises(LineLost):
        await drain(line)
    assert not health[1].online


async def test_the_back_reopens_the_same_path_with_back_off_capped_at_the_probe_period():
    from fieldgate import GatewayContext, ProcessImage, load_registry
    from fieldgate.plugin import PluginStartError
    from fieldgate.polling import LineScheduler, SerialBack
    from fieldgate.topology import load_topology

    registry = load_registry()
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    topology = load_topology(
        {
            "gateway": {"name": "t"},
            "fronts": [{"name": "plc", "type": "memory"}],
            "backs": [
                {
                    "name": "rs485",
                    "type": "dcon",
                    "port": "/dev/ttyUSB0",
                    "offline_probe_ms": 1000,
                    "modules": [{"address": 1, "model": "I-7055"}],
                }
            ],
        },
        registry,
    )

    class Back(SerialBack):
        missing_for = 5  # the adapter is back at the sixth try

        async def open_link(self):
            self.opened = getattr(self, "opened", 0) + 1
            if self.opened <= self.missing_for:
                raise PluginStartError("cannot open serial port /dev/ttyUSB0: no such device")
            return f"link {self.opened}"

        async def close_link(self):
            self.closed = getattr(self, "closed", 0) + 1

        def make_module(self, config, specs):
            raise AssertionError("not used")

    context = GatewayContext.build(topology)
    back = Back(topology.backs[0], context)
    back.scheduler = LineScheduler("rs485", [], ProcessImage(), {})
    waits = []

    async def sleep(seconds):
        waits.append(seconds)

    back.sleep = sleep
    await back._recover_line("read failed: [Errno 5] Input/output error")
    assert waits == [0.1, 0.2, 0.4, 0.8, 1.0, 1.0]  # doubling, capped at offline_probe_ms
    assert back.link == "link 6" and back.closed == 1
    assert {k: v for k, v in back.port.items() if k != "last_outage_s"} == {
        "lost": False,
        "losses": 1,
        "reopen_attempts": 6,
    }
