"""The I-7241D's DCON host-watchdog attributes of Application object 0x64 (seed-003 §3.6, TV-44..51).

Engine tests (fake clock, fake watchdog back, byte-exact frames) and one gateway run:
DeviceNet master on a virtual CAN bus, DCON back on simulated modules.
"""

from __future__ import annotations

import uuid

import pytest
from dnet_master import Master
from dnet_rig import Rig, image_with

from fieldgate import ChannelSpec, Gateway, Kind, Quality, Source, channel_id, load_registry
from fieldgate.host_watchdog import HostWatchdogs


class FakeDconBack:
    """A running back with host watchdogs (fieldgate.host_watchdog.WatchdogBack), recording requests."""

    def __init__(self, settings: dict[int, tuple[bool, int]]):
        self.settings = dict(settings)
        self.expired: set[int] = set()
        self.requests: list[tuple] = []
        self.host_ok_enabled = True

    def set_host_ok(self, enabled: bool) -> None:
        self.host_ok_enabled = enabled
        self.requests.append(("host ok", enabled))

    def watchdog_settings(self, address: int) -> tuple[bool, int]:
        return self.settings[address]

    def watchdog_status(self, address: int) -> bool:
        self.settings[address]
        return address in self.expired

    def set_watchdog(self, address: int, enabled: bool, timeout_ms: int | None = None):
        old = self.settings[address]
        self.settings[address] = (enabled, old[1] if timeout_ms is None else timeout_ms)
        self.requests.append(("set", address, enabled, timeout_ms))

    def request_clear_watchdog(self, address: int):
        self.settings[address]
        self.expired.discard(address)
        self.requests.append(("clear", address))


def make_rig(
    backs: dict | None = None, configured: dict | None = None, **settings
) -> tuple[Rig, FakeDconBack]:
    """DCON modules io/1..3 (instances 1-3, DO only), a Modbus-like module mb/5 (instance 4)."""
    image = image_with([(1, {Kind.DO: 8}), (2, {Kind.DO: 8}), (3, {Kind.DO: 8})], back="io")
    image.add(ChannelSpec(channel_id("mb", 5, Kind.DO, 0), Kind.DO, Source("mb", 5, 0)))
    back = FakeDconBack({1: (False, 0), 2: (True, 1500), 3: (False, 5000)})
    rig = Rig(image, **settings)
    rig.slave.host_watchdogs = HostWatchdogs(
        {"io": back, "mb": object()} if backs is None else backs, {"io"}, configured
    )
    assert rig.allocate(0x01) == "44B 0A CB 00"
    return rig, back


def test_seed_watchdog_vectors():
    rig, back = make_rig()
    assert rig.explicit("0E 64 03 08") == "0A 8E 00"
    assert rig.explicit("0E 64 03 09") == "0A 8E 32"  # 50 x 0.1 s, the seed's default period
    assert rig.explicit("10 64 03 08 01") == "0A 90"  # TV-44 / TV-45
    assert back.requests == [("set", 3, True, None)]
    assert rig.explicit("0E 64 03 08") == "0A 8E 01"
    back.expired.add(3)
    assert (
        rig.explicit("0E 64 03 0A") == "0A 8E 01"
    )  # TV-48 / TV-49 as intended (the seed prints 64 00 04 / 1E)
    assert rig.explicit("10 64 03 0B") == "0A 90"  # TV-50 / TV-51 as intended: clear, no data
    assert back.requests[-1] == ("clear", 3)
    assert rig.explicit("0E 64 03 0A") == "0A 8E 00"


def test_seed_host_ok_class_attribute():
    rig, back = make_rig()
    assert (
        rig.explicit("0E 64 00 04") == "0A 8E 01"
    )  # the back sends ~** by itself unless told not to
    assert rig.explicit("10 64 00 04 00") == "0A 90"
    assert back.host_ok_enabled is False and rig.explicit("0E 64 00 04") == "0A 8E 00"
    assert rig.explicit("10 64 00 04 01") == "0A 90"  # TV-46 / TV-47
    assert back.requests == [("host ok", False), ("host ok", True)]
    assert rig.explicit("10 64 00 04 02") == "0A 94 09 FF"
    assert rig.explicit("10 64 00 04") == "0A 94 13 FF"
    assert rig.explicit("0E 64 00 03") == "0A 8E 00 00"  # COM timeout: no back with one runs
    assert rig.explicit("10 64 00 03 C8 00") == "0A 94 10 FF"
    assert rig.explicit("0E 64 00 02") == "0A 8E 04 00"
    assert len(back.requests) == 2


def test_period_and_enable_are_independent():
    rig, back = make_rig()
    assert rig.explicit("0E 64 02 08") == "0A 8E 01"
    assert rig.explicit("0E 64 02 09") == "0A 8E 0F"  # 1500 ms
    assert rig.explicit("10 64 02 09 FF") == "0A 90"
    assert back.requests == [("set", 2, True, 25_500)]  # the enable stays on
    assert rig.explicit("10 64 02 08 00") == "0A 90"
    assert back.requests[-1] == ("set", 2, False, None)  # the period stays
    assert rig.explicit("0E 64 02 09") == "0A 8E FF" and rig.explicit("0E 64 02 08") == "0A 8E 00"
    assert rig.explicit("0E 64 01 09") == "0A 8E 00"  # never set: 0, the module keeps its own


@pytest.mark.parametrize(
    "body, reply",
    [
        ("10 64 01 08 02", "0A 94 09 FF"),  # enable is 0/1
        ("10 64 01 08 FF", "0A 94 09 FF"),
        ("10 64 01 09 00", "0A 94 09 FF"),  # period 1..255
        ("10 64 01 08", "0A 94 13 FF"),  # no data
        ("10 64 01 09", "0A 94 13 FF"),
        ("10 64 01 0A 00", "0A 94 0E FF"),  # the status is Get only: clear it with 0x0B
        ("10 64 01 0A 01", "0A 94 0E FF"),
        ("0E 64 01 0B", "0A 94 2C FF"),  # clear is Set only (NULL)
        ("0E 64 01 08 00", "0A 94 15 FF"),  # Get with data
        ("0E 64 04 08", "0A 8E 00"),  # the Modbus module has no DCON watchdog: reads off
        ("0E 64 04 0A", "0A 8E 00"),
        ("10 64 04 08 01", "0A 94 0E FF"),  # and cannot be switched on
        ("10 64 04 0B", "0A 94 0E FF"),
        ("10 64 05 08 01", "0A 94 16 FF"),  # no fifth module
    ],
)
def test_bad_requests_get_cip_errors_and_change_nothing(body, reply):
    rig, back = make_rig()
    assert rig.explicit(body) == reply
    assert back.requests == []


def test_trailing_bytes_follow_the_front_setting():
    rig, back = make_rig()  # default: tolerated, as the I-7241D does (seed-003 §9.2)
    assert rig.explicit("10 64 01 08 01 00") == "0A 90"
    assert rig.explicit("10 64 01 0B 00") == "0A 90"
    assert back.requests == [("set", 1, True, None), ("clear", 1)]
    strict, back = make_rig(tolerate_trailing_bytes=False)
    assert strict.explicit("10 64 01 08 01 00") == "0A 94 15 FF"
    assert strict.explicit("10 64 01 09 05 00") == "0A 94 15 FF"
    assert strict.explicit("10 64 01 0B 00") == "0A 94 15 FF"
    assert back.requests == []


def test_back_not_running_answers_configured_values_and_refuses_changes():
    rig, _ = make_rig(backs={}, configured={("io", 1): (True, 800)})
    assert rig.explicit("0E 64 01 08") == "0A 8E 01"
    assert rig.explicit("0E 64 01 09") == "0A 8E 08"
    assert rig.explicit("0E 64 01 0A") == "0A 8E 00"
    assert rig.explicit("0E 64 02 08") == "0A 8E 00"  # not configured: off
    assert rig.explicit("10 64 01 08 00") == "0A 94 10 FF"  # device state conflict
    assert rig.explicit("10 64 01 0B") == "0A 94 10 FF"
    assert rig.explicit("0E 64 00 04") == "0A 8E 01"
    assert rig.explicit("10 64 00 04 00") == "0A 94 10 FF"


def test_module_unknown_to_the_back_is_a_device_state_conflict():
    rig, back = make_rig()
    del back.settings[3]
    assert (
        rig.explicit("0E 64 03 08") == "0A 8E 00"
    )  # unknown to the back: nothing configured either
    assert rig.explicit("0E 64 03 0A") == "0A 8E 00"
    assert rig.explicit("10 64 03 08 01") == "0A 94 10 FF"
    assert rig.explicit("10 64 03 0B") == "0A 94 10 FF"


def test_without_dcon_backs_the_attributes_read_as_off_and_cannot_be_set():
    rig = Rig(image_with([(1, {Kind.DO: 8})]))  # the engine's default: no host watchdogs
    rig.allocate(0x01)
    assert [rig.explicit(f"0E 64 01 {a:02X}") for a in (0x08, 0x09, 0x0A, 0x0B)] == [
        "0A 8E 00",
        "0A 8E 00",
        "0A 8E 00",
        "0A 94 2C FF",  # clear: Set only
    ]
    assert rig.explicit("10 64 01 08 01") == "0A 94 0E FF"
    assert rig.explicit("10 64 01 18") == "0A 94 14 FF"  # no safe-value latch either
    assert rig.explicit("0E 64 00 04") == "0A 8E 01"  # host OK: nothing stops it
    assert rig.explicit("10 64 00 04 01") == "0A 94 10 FF"  # no back to tell
    assert rig.explicit("10 64 00 03 C8 00") == "0A 94 10 FF"


# -- end to end ----------------------------------------------------------------------------------
async def wait_for(predicate, master: Master, timeout: float = 3.0):
    for _ in range(int(timeout / 0.02)):
        if predicate():
            return
        await master.frames(0.02)
    raise AssertionError("condition not reached in time")


async def test_watchdog_through_devicenet_drives_simulated_dcon_modules(tmp_path):
    registry = load_registry()
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    channel = f"fg-dnwd-{uuid.uuid4().hex[:8]}"
    topology = {
        "gateway": {"name": "i7241d-wd", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "dnet",
                "type": "devicenet",
                "interface": "virtual",
                "channel": channel,
                "mac_id": 9,
                "dup_mac_timeout_ms": 50,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": "simulated",
                "timeout_ms": 100,
                "poll_ms": 10,
                "offline_probe_ms": 100,
                "modules": [{"address": 1, "model": "I-7060"}, {"address": 2, "model": "I-7052"}],
            }
        ],
    }
    gw = Gateway.load(topology, registry=registry, simulate=True)
    master = Master(channel, slave=9)
    await gw.start()
    try:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await master.wait_online()
        assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
        assert await master.request(bytes.fromhex("0E 64 01 08")) == bytes.fromhex("8E 00")
        await wait_for(lambda: gw.health.get("rs485", 1).requests > 2, master)
        assert back.host_ok_sent == 0
        quiet_since = sim.module(2).last_host_ok  # only ~** (a broadcast) moves it for module 2
        # enable with a 0.3 s period: ~AA3EVV reaches the module, ~** starts
        assert await master.request(bytes.fromhex("10 64 01 09 03")) == bytes.fromhex("90")
        assert await master.request(bytes.fromhex("10 64 01 08 01")) == bytes.fromhex("90")
        await wait_for(
            lambda: sim.module(1).watchdog_enabled and sim.module(1).watchdog_tenths == 3, master
        )
        await wait_for(
            lambda: back.host_ok_sent >= 3 and sim.module(2).last_host_ok > quiet_since, master
        )
        assert not sim.module(2).watchdog_enabled
        assert await master.request(bytes.fromhex("0E 64 01 09")) == bytes.fromhex("8E 03")
        # the module times out (as if ~** were lost): a DO write through 0x14 is answered '!'
        sim.module(1).tick(sim.module(1).last_host_ok + 10)
        assert await master.request(bytes.fromhex("10 64 01 14 06")) == bytes.fromhex("90")
        await wait_for(lambda: gw.image["rs485/m1/do1"].quality is Quality.WATCHDOG, master)
        assert await master.request(bytes.fromhex("0E 64 01 0A")) == bytes.fromhex("8E 01")
        assert await master.request(bytes.fromhex("0E 64 02 0A")) == bytes.fromhex("8E 00")
        assert sim.module(1).do_bits == 0
        # recovery: Set 0x0B sends ~AA1, then the outputs are written again
        assert await master.request(bytes.fromhex("10 64 01 0B")) == bytes.fromhex("90")
        await wait_for(
            lambda: not sim.module(1).timed_out and sim.module(1).do_bits == 0x06, master
        )
        await wait_for(lambda: gw.image["rs485/m1/do1"].quality is Quality.GOOD, master)
        assert await master.request(bytes.fromhex("0E 64 01 0A")) == bytes.fromhex("8E 00")
        # Host OK off (class attribute 4, TV-46 with 0): no more ~**, the module times out by itself
        # after 0.3 s and the back sees it through ~AA0
        assert await master.request(bytes.fromhex("10 64 00 04 00")) == bytes.fromhex("90")
        stopped_at = back.host_ok_sent
        await wait_for(lambda: sim.module(1).timed_out, master)
        await wait_for(lambda: back.watchdog_status(1), master)
        assert await master.request(bytes.fromhex("0E 64 01 0A")) == bytes.fromhex("8E 01")
        assert (
            back.host_ok_sent == stopped_at and sim.module(1).do_bits == 0
        )  # the module's safe value
        assert gw.status()["backs"]["rs485"]["host_ok"]["enabled"] is False
        # a clear while the master keeps host OK off goes out without ~**; the module's
        # watchdog has run out, so the flag is back at once, and the status says why
        assert await master.request(bytes.fromhex("10 64 01 0B")) == bytes.fromhex("90")
        await wait_for(lambda: "switched off by the master" in back.module(1).last_clear, master)
        assert await master.request(bytes.fromhex("0E 64 01 0A")) == bytes.fromhex("8E 01")
        assert back.host_ok_sent == stopped_at
        assert await master.request(bytes.fromhex("10 64 00 04 01")) == bytes.fromhex("90")
        assert await master.request(bytes.fromhex("10 64 01 0B")) == bytes.fromhex("90")
        await wait_for(
            lambda: (
                not sim.module(1).timed_out
                and sim.module(1).do_bits == 0x06
                and back.host_ok_sent > stopped_at
            ),
            master,
        )
        assert await master.request(bytes.fromhex("0E 64 01 0A")) == bytes.fromhex("8E 00")
        assert back.module(1).last_clear == "cleared"
        await master.frames(0.7)  # more than two watchdog timeouts: the clear holds
        assert await master.request(bytes.fromhex("0E 64 01 0A")) == bytes.fromhex("8E 00")
    finally:
        master.close()
        await gw.stop()
