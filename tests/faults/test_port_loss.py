"""Serial port faults on a running gateway, both backs (scripts/faults/port_faults.py, one cycle each).

The back's port is a symlink to a pty that is pulled (link removed, pty hung up) and
plugged back under the same path, then garbage, then an RS-485 echo. Behaviour only; the
timings are the script's figures (docs/reliability.md).
"""

from __future__ import annotations

import random

import port_faults  # scripts/faults (see conftest)
import pytest

from fieldgate import load_registry


@pytest.fixture(scope="module")
def registry():
    return load_registry()


@pytest.mark.parametrize("back", ["modbus", "dcon"])
async def test_port_loss_garbage_and_echo_are_survived_without_a_restart(back, registry, tmp_path):
    rig = await port_faults.start_rig(back, tmp_path, registry)
    rng = random.Random(5)
    try:
        unplug = await port_faults.cycle(rig, "unplug", rng)
        garbage = await port_faults.cycle(rig, "garbage", rng)
        echo = await port_faults.cycle(rig, "echo", rng)
        status = rig.gateway.status()["backs"]["rs485"]
    finally:
        await port_faults.stop_rig(rig)
    # the port is gone: every module offline after ONE failed transaction, not fail_threshold + 1
    assert unplug.failures_counted == {a: 1 for a in rig.addresses}
    assert unplug.port_losses == 1
    assert unplug.emcy_modules == rig.addresses  # the CANopen front's EMCY 00 FF 81 0B <address>
    assert unplug.devicenet_fault_seen and unplug.devicenet_fault_cleared
    # garbage is not a lost port: each module goes offline by its own failure count
    assert garbage.port_losses == 0 and garbage.detect_s is not None
    assert garbage.emcy_modules == rig.addresses
    assert all(n > 1 for n in garbage.failures_counted.values())
    # an adapter that starts echoing: echo: auto drops the echo on every exchange, so no
    # module goes offline (before, every DCON module did); the exchange under way when the
    # echo starts may fail once
    assert echo.port_losses == 0 and echo.detect_s is None
    assert all(n <= 1 for n in echo.failures_counted.values()), echo.failures_counted
    # recovered every time (cycle() waits for it), in the same run of the back
    assert status["restarts"] == 0
    assert status["port"] == {
        "lost": False,
        "losses": 1,
        "reopen_attempts": status["port"]["reopen_attempts"],
        "last_outage_s": status["port"]["last_outage_s"],
    }
    assert status["port"]["reopen_attempts"] >= 2  # the path was missing at the first try(s)
