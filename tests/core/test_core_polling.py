"""The shared line scheduler, driven step by step with a fake clock and scripted modules."""

from fieldgate import (
    ChannelSpec,
    ErrorKind,
    Kind,
    ModuleHealth,
    ProcessImage,
    Quality,
    Source,
    channel_id,
)
from fieldgate.polling import CommError, LineJob, LineScheduler, PolledModule
from fieldgate.topology import ModuleConfig

TICK = 0.125  # exact in binary, so due times compare exactly


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class ScriptedModule(PolledModule):
    """A module whose answers come from a script: None = answer, an ErrorKind = fail that way."""

    def __init__(self, address, image, n_in=2, n_out=2, poll_ms=None, log=None):
        specs = [
            ChannelSpec(
                channel_id("line", address, Kind.DI, i), Kind.DI, Source("line", address, i)
            )
            for i in range(n_in)
        ]
        specs += [
            ChannelSpec(
                channel_id("line", address, Kind.DO, i), Kind.DO, Source("line", address, i)
            )
            for i in range(n_out)
        ]
        for s in specs:
            image.add(s)
        super().__init__(ModuleConfig(address=address, poll_ms=poll_ms), specs)
        self.failures: list = []
        self.inputs_value = False
        self.log = log if log is not None else []
        self.onlines = 0

    def _maybe_fail(self):
        if self.failures:
            kind = self.failures.pop(0)
            if kind is not None:
                raise CommError(kind, f"scripted {kind}")

    async def read_inputs(self):
        self.log.append(("read", self.address))
        self._maybe_fail()
        return {cid: self.inputs_value for cid in self.inputs}

    async def send_outputs(self, values):
        self.log.append(("write", self.address, dict(values)))
        self._maybe_fail()

    async def on_online(self):
        self.onlines += 1


def make_line(n_modules=2, **kw):
    clock, image, log = Clock(), ProcessImage(), []
    image.clock = clock
    modules = [
        ScriptedModule(a, image, log=log, poll_ms=kw.pop(f"poll_ms_{a}", None))
        for a in range(1, n_modules + 1)
    ]
    health = {m.address: ModuleHealth("line", m.address, fail_threshold=3) for m in modules}
    line = LineScheduler(
        "line",
        modules,
        image,
        health,
        poll_period=TICK,
        offline_probe_period=5.0,
        clock=clock,
        **kw,
    )
    line.attach()
    return line, modules, image, health, clock, log


async def drain(line):
    """Run steps until nothing is due now; returns the next deadline."""
    for _ in range(100):
        deadline = await line.step()
        if deadline is not None:
            return deadline
    raise AssertionError("line never went idle")


async def test_polls_each_module_then_waits_for_the_period():
    line, modules, image, health, clock, log = make_line()
    modules[0].inputs_value = True
    deadline = await drain(line)
    assert log == [("read", 1), ("read", 2)]
    assert deadline == TICK
    assert image.value("line/m1/di0") is True and image["line/m1/di0"].quality is Quality.GOOD
    assert [m.onlines for m in modules] == [1, 1]
    assert line.stats.cycles == 1 and line.stats.requests == 2


async def test_per_module_poll_period():
    line, modules, *_, clock, log = make_line(poll_ms_2=1000)
    await drain(line)
    for step in range(1, 6):
        clock.t = step * TICK
        await drain(line)
    assert log.count(("read", 1)) == 6 and log.count(("read", 2)) == 1


async def test_output_change_is_written_before_any_read():
    line, modules, image, health, clock, log = make_line()
    await drain(line)
    log.clear()
    clock.t = 2 * TICK  # both reads due
    image.write_output("line/m2/do1", True, origin="can")
    await line.step()
    assert log == [("write", 2, {"line/m2/do1": True})]
    await drain(line)
    assert log[1:] == [("read", 1), ("read", 2)]
    assert line.pending_writes == 0


async def test_failed_write_is_retried_later_with_the_latest_value():
    line, modules, image, health, clock, log = make_line()
    await drain(line)
    modules[0].failures = [ErrorKind.TIMEOUT]
    image.write_output("line/m1/do0", True)
    await line.step()
    assert line.pending_writes == 1 and health[1].error_counter == 1
    image.write_output("line/m1/do1", True)
    await line.step()
    assert log[-1] == ("write", 1, {"line/m1/do0": True, "line/m1/do1": True})
    assert line.pending_writes == 0


async def test_failure_makes_inputs_stale_then_offline_comm_fault_then_slow_probe_and_recovery():
    line, modules, image, health, clock, log = make_line(n_modules=1)
    await drain(line)
    m = modules[0]
    m.failures = [ErrorKind.TIMEOUT] * 4
    clock.t = TICK
    await drain(line)
    assert image["line/m1/di0"].quality is Quality.STALE and health[1].online
    for i in range(2, 5):
        clock.t = i * TICK
        await drain(line)
    assert not health[1].online and health[1].consecutive_failures == 4
    assert image["line/m1/di0"].quality is Quality.COMM_FAULT
    assert image["line/m1/do0"].quality is Quality.COMM_FAULT
    reads = log.count(("read", 1))
    deadline = await drain(line)
    assert deadline == 4 * TICK + 5.0  # re-probe at the slow period, not the poll period
    clock.t = 1.0
    await drain(line)
    assert log.count(("read", 1)) == reads  # nothing polled before the probe is due
    m.inputs_value = True
    clock.t = 4 * TICK + 5.0
    await drain(line)
    assert health[1].online and m.onlines == 2
    assert image["line/m1/di0"].quality is Quality.GOOD and image.value("line/m1/di0") is True
    assert image["line/m1/do0"].quality is Quality.GOOD


async def test_dead_module_does_not_eat_the_poll_budget():
    line, modules, image, health, clock, log = make_line()
    modules[1].failures = [ErrorKind.TIMEOUT] * 1000
    for i in range(50):
        clock.t = i * TICK
        await drain(line)
    assert not health[2].online
    assert log.count(("read", 1)) == 50
    assert log.count(("read", 2)) == 4 + 1  # four to go offline, then one probe at t=5.375


async def test_retries_count_every_attempt():
    line, modules, image, health, clock, log = make_line(n_modules=1, retries=2)
    modules[0].failures = [ErrorKind.CRC, ErrorKind.GARBAGE]
    await drain(line)
    assert log.count(("read", 1)) == 3 and health[1].error_counter == 2
    assert image["line/m1/di0"].quality is Quality.GOOD
    assert line.stats.errors[ErrorKind.CRC] == 1 and line.stats.errors[ErrorKind.GARBAGE] == 1


async def test_unexpected_exception_in_a_codec_is_counted_not_raised():
    line, modules, image, health, clock, log = make_line(n_modules=1)

    async def broken():
        raise ZeroDivisionError("codec bug")

    modules[0].read_inputs = broken
    await drain(line)
    assert health[1].errors[ErrorKind.IO] == 1 and "ZeroDivisionError" in health[1].last_error


async def test_line_jobs_run_periodically_when_enabled():
    line, modules, image, health, clock, log = make_line(n_modules=1)
    enabled = [True]
    calls = []

    async def host_ok():
        calls.append(clock.t)

    line.add_job(LineJob("host-ok", 1.0, host_ok, lambda: enabled[0]))
    for i in range(30):
        clock.t = i * TICK
        await drain(line)
    assert calls == [0.0, 1.0, 2.0, 3.0]
    enabled[0] = False
    for i in range(30, 60):
        clock.t = i * TICK
        await drain(line)
    assert len(calls) == 4


async def test_cyclic_rewrite_of_outputs():
    line, modules, image, health, clock, log = make_line(n_modules=1, write_period=1.0)
    for i in range(25):
        clock.t = i * TICK
        await drain(line)
    writes = [e for e in log if e[0] == "write"]
    assert len(writes) >= 3 and all(set(w[2]) == {"line/m1/do0", "line/m1/do1"} for w in writes)


async def test_outputs_set_while_offline_are_written_on_recovery_and_untouched_ones_never():
    line, modules, image, health, clock, log = make_line(n_modules=1)
    modules[0].failures = [ErrorKind.TIMEOUT] * 4
    for i in range(4):
        clock.t = i * TICK
        await drain(line)
    assert not health[1].online
    image.write_output("line/m1/do1", True, origin="can")
    clock.t = 3 * TICK + 5.0
    await drain(line)
    assert health[1].online
    writes = [e for e in log if e[0] == "write"]
    assert writes[-1] == ("write", 1, {"line/m1/do1": True})
    assert all("line/m1/do0" not in w[2] for w in writes)


async def test_a_poll_with_nothing_due_is_neither_a_success_nor_a_request():
    from fieldgate.polling import NOTHING_DUE

    line, modules, image, health, clock, log = make_line(n_modules=1)
    await drain(line)
    assert health[1].requests == 1 and line.stats.requests == 1

    async def idle():
        return NOTHING_DUE

    modules[0].read_inputs = idle
    modules[0].failures = []
    health[1].consecutive_failures = 2
    clock.t = TICK
    await drain(line)
    assert health[1].requests == 1 and line.stats.requests == 1
    assert health[1].consecutive_failures == 2  # not reset by a poll that asked nothing


async def test_run_yields_to_the_loop_even_when_polls_do_no_io():
    import asyncio

    clock_line = make_line(n_modules=1)
    line = clock_line[0]
    line._states[
        0
    ].period = 0.0  # poll_ms 0: as fast as the line allows, and the module never awaits I/O
    ticks = []

    async def other_task():
        for _ in range(5):
            ticks.append(1)
            await asyncio.sleep(0)

    task = asyncio.create_task(line.run())
    await asyncio.wait_for(other_task(), 2)
    task.cancel()
    assert len(ticks) == 5


class SwallowingModule(ScriptedModule):
    """Its read swallows a cancellation, as Python 3.11's asyncio.wait_for inside pymodbus can
    when the reply arrives together with the cancellation."""

    def __init__(self, *args, **kw):
        import asyncio

        super().__init__(*args, **kw)
        self.swallowed = 0
        self.waiting = asyncio.Event()  # set while the read waits for its "reply"

    async def read_inputs(self):
        import asyncio

        self.waiting.set()
        try:
            await asyncio.sleep(0.05)
        except asyncio.CancelledError:
            self.swallowed += 1
        self.waiting.clear()
        return await super().read_inputs()


async def test_a_cancellation_swallowed_inside_a_transaction_still_stops_the_line():
    import asyncio

    clock, image = Clock(), ProcessImage()
    module = SwallowingModule(1, image)
    line = LineScheduler(
        "line",
        [module],
        image,
        {1: ModuleHealth("line", 1)},
        poll_period=0.0,
        offline_probe_period=5.0,
        clock=clock,
    )
    task = asyncio.create_task(line.run())
    await asyncio.wait_for(module.waiting.wait(), 2.0)
    task.cancel()
    done, _ = await asyncio.wait({task}, timeout=2.0)
    assert done and task.cancelled()  # without the check the line would poll on
    assert module.swallowed == 1


async def test_a_reply_is_one_image_batch_stamped_when_it_arrived():
    """Every input of one reply is one update_inputs batch: one call per subscriber, each
    channel its own value, the module-reported quality of one kept, the reply's time."""
    line, modules, image, health, clock, log = make_line(n_modules=1)
    module = modules[0]
    batches = []
    image.subscribe_batch(batches.append, kinds=[Kind.DI])

    async def reply():
        clock.t += 0.01  # the reply arrives 10 ms after the request
        return {"line/m1/di0": True, "line/m1/di1": (True, Quality.OVER_RANGE)}

    module.read_inputs = reply
    clock.t = 1.0
    await line.step()
    assert len(batches) == 1
    assert [(c.id, c.value, c.quality, c.timestamp) for c in batches[0]] == [
        ("line/m1/di0", True, Quality.GOOD, 1.01),
        ("line/m1/di1", True, Quality.OVER_RANGE, None),  # never good: no timestamp
    ]
    clock.t = 2.0
    await line.step()  # the same reply again: nothing changed, no call; the time refreshed
    assert len(batches) == 1 and image["line/m1/di0"].timestamp == 2.01


async def test_an_output_batch_marks_the_changed_outputs_dirty_once():
    line, modules, image, health, clock, log = make_line()
    await drain(line)
    log.clear()
    image.write_outputs({"line/m1/do0": True, "line/m1/do1": False, "line/m2/do0": True})
    assert line.pending_writes == 2  # m1/do1 kept its value: not rewritten
    await drain(line)
    assert sorted(e for e in log if e[0] == "write") == [
        ("write", 1, {"line/m1/do0": True}),
        ("write", 2, {"line/m2/do0": True}),
    ]
