"""fieldgate.host_watchdog: which backs offer host watchdogs, configured values, errors fronts map."""

import pytest

from fieldgate import ErrorKind, GatewayContext
from fieldgate.host_watchdog import (
    ClearSteps,
    HostWatchdogs,
    NoHostWatchdog,
    WatchdogUnavailable,
    clear_timeout,
)
from fieldgate.polling import CommError
from fieldgate.topology import load_topology


def test_capable_backs_and_configured_settings_come_from_the_back_configs(registry, topology_dict):
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    data = topology_dict()
    data["backs"].append(
        {
            "name": "rs485",
            "type": "dcon",
            "port": "simulated",
            "modules": [
                {"address": 4, "model": "I-7060", "watchdog": {"timeout_ms": 700}},
                {"address": 6, "model": "I-7052"},
            ],
        }
    )
    context = GatewayContext.build(load_topology(data, registry))
    wd = HostWatchdogs.from_context(context)
    assert wd.capable == {"rs485"}  # the loopback back has no host watchdog protocol
    assert wd.has("rs485", 6) and not wd.has("io", 3)
    assert wd.any([("io", 1), ("rs485", 4)]) and not wd.any([("io", 1), ("io", 3)])
    assert wd.settings("rs485", 4) == (True, 700) and wd.timeout_tenths("rs485", 4) == 7
    assert wd.settings("rs485", 6) == (False, 0) and not wd.expired("rs485", 4)
    with pytest.raises(NoHostWatchdog, match="back rs485 is not running"):
        wd.recover("rs485", 4)  # not started: context.backs is empty
    with pytest.raises(NoHostWatchdog, match="module 3 has no host watchdog"):
        wd.set_enabled("io", 3, 1)
    context.backs["rs485"] = object()  # a back object without the protocol's methods
    with pytest.raises(WatchdogUnavailable):
        wd.set_enabled("rs485", 4, 0)
    assert wd.settings("rs485", 4) == (True, 700)


def test_values_are_checked_before_the_back_is_asked():
    class Back:
        calls = []

        def set_watchdog(self, address, enabled, timeout_ms=None):
            self.calls.append((address, enabled, timeout_ms))

        def watchdog_settings(self, address):
            return (True, 30_000)  # longer than 0.1 s x 255: reported as 255

    wd = HostWatchdogs({"b": Back()}, {"b"})
    for bad in (2, -1):
        with pytest.raises(ValueError):
            wd.set_enabled("b", 1, bad)
    for bad in (0, 256):
        with pytest.raises(ValueError):
            wd.set_timeout_tenths("b", 1, bad)
    assert Back.calls == [] and wd.timeout_tenths("b", 1) == 255
    wd.set_timeout_tenths("b", 1, 1)
    assert Back.calls == [(1, True, 100)]


def test_host_ok_switch_goes_to_every_running_capable_back():
    class Back:
        def __init__(self):
            self.host_ok_enabled = True

        def set_host_ok(self, enabled):
            self.host_ok_enabled = enabled

    a, b = Back(), Back()
    wd = HostWatchdogs({"a": a, "b": b, "other": Back()}, {"a", "b", "c"})
    assert wd.host_ok() is True
    wd.set_host_ok(0)
    assert (a.host_ok_enabled, b.host_ok_enabled, wd.backs["other"].host_ok_enabled) == (
        False,
        False,
        True,
    )
    assert wd.host_ok() is False
    b.host_ok_enabled = True
    assert wd.host_ok() is False  # only when every back may send it
    with pytest.raises(ValueError):
        wd.set_host_ok(2)
    with pytest.raises(NoHostWatchdog):
        HostWatchdogs({}, {"a"}).set_host_ok(1)
    assert HostWatchdogs({}, {"a"}).host_ok() is True


class Line:
    """The steps of a clear, recorded in order, against a module model: its watchdog keeps
    running while host OK is paused, and ~AA1 clears the flag without restarting it."""

    def __init__(self, expired_after_clear: bool = False):
        self.sent: list[str] = []
        self.expired_after_clear = expired_after_clear

    async def host_ok(self):
        self.sent.append("~**")

    async def clear(self):
        self.sent.append("~AA1")

    async def expired(self):
        self.sent.append("~AA0")
        return self.expired_after_clear

    def steps(self, host_ok: bool, why: str = "") -> ClearSteps:
        return ClearSteps(
            clear=self.clear,
            expired=self.expired,
            rewrite_outputs=lambda: self.sent.append("outputs"),
            host_ok=self.host_ok if host_ok else None,
            without_host_ok=why,
        )


async def test_clear_sends_host_ok_first_then_clears_confirms_and_rewrites_outputs():
    line = Line()
    assert await clear_timeout(line.steps(host_ok=True)) == "cleared"
    assert line.sent == ["~**", "~AA1", "~AA0", "outputs"]


async def test_clear_without_host_ok_says_so():
    line = Line()
    outcome = await clear_timeout(line.steps(False, "switched off by the master"))
    assert line.sent == ["~AA1", "~AA0", "outputs"]
    assert outcome == (
        "cleared without host OK (switched off by the master): "
        "the module times out again after its watchdog timeout"
    )


async def test_a_flag_still_set_after_the_clear_is_a_watchdog_error_and_no_output_is_written():
    line = Line(expired_after_clear=True)
    with pytest.raises(CommError) as info:
        await clear_timeout(line.steps(False, "a front's master is lost"))
    assert info.value.kind is ErrorKind.WATCHDOG and "a front's master is lost" in str(info.value)
    assert "outputs" not in line.sent
