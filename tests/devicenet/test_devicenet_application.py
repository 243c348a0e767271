"""The I-7241D's Application object 0x64 complete (seed-003 §3.6): every attribute of each
module read through a DeviceNet master from the DCON back running on simulated modules, the
class-level COM timeout, and the latch of the current outputs as safe values (§5.3)."""

from __future__ import annotations

import uuid

import pytest
from dnet_master import Master
from test_devicenet_watchdog import wait_for

from fieldgate import Gateway, load_registry


def topology(tmp_path, channel: str, back: dict) -> dict:
    return {
        "gateway": {"name": "i7241d-app", "state_dir": str(tmp_path)},
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
        "backs": [back],
    }


DCON = {
    "name": "rs485",
    "type": "dcon",
    "port": "simulated",
    "baudrate": 19200,
    "checksum": True,
    "timeout_ms": 100,
    "poll_ms": 10,
    "modules": [
        {"address": 1, "model": "I-7055"},  # 8 DI, 8 DO
        {"address": 2, "model": "I-7017", "type_code": 0x09, "data_format": "hex"},  # 8 AI
        {"address": 3, "model": "I-87024"},  # 4 AO
        {"address": 5, "model": "I-7012"},  # 1 DI, 2 DO, 1 AI: the ~AA5PPSS family
    ],
}


@pytest.fixture
def registry():
    registry = load_registry()
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    return registry


async def get(master: Master, instance: int, attribute: int) -> str:
    return (await master.request(bytes([0x0E, 0x64, instance, attribute]))).hex(" ").upper()


async def test_every_attribute_comes_from_what_the_modules_answered(tmp_path, registry):
    channel = f"fg-app-{uuid.uuid4().hex[:8]}"
    gw = Gateway.load(topology(tmp_path, channel, DCON), registry=registry, simulate=True)
    master = Master(channel, slave=9)
    await gw.start()
    try:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        sim.module(2).name = "7018"  # what $AAM answers: the module ID follows the module
        await master.wait_online()
        assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
        await wait_for(lambda: all(m.config_reply for m in back.modules.values()), master, 10)
        assert await get(master, 0, 1) == "8E 02 00"  # revision 2
        assert await get(master, 0, 2) == "8E 04 00"  # 4 modules
        assert await get(master, 0, 3) == "8E 64 00"  # COM timeout 100 ms
        expected = {  # instance -> attribute -> answer
            1: {1: "55 70 00 00", 2: "01", 3: "01", 4: "00 4B 00 00", 5: "40", 6: "00"},
            2: {1: "18 70 00 00", 2: "02", 3: "01", 4: "00 4B 00 00", 5: "09", 6: "02"},
            3: {1: "24 70 08 00", 2: "03", 3: "01", 4: "00 4B 00 00", 5: "33", 6: "02"},
            4: {1: "12 70 00 00", 2: "05", 3: "01", 4: "00 4B 00 00", 5: "08", 6: "02"},
        }
        for instance, attributes in expected.items():
            for attribute, answer in attributes.items():
                assert await get(master, instance, attribute) == f"8E {answer}", (
                    instance,
                    attribute,
                )
        lengths = {1: (1, 0, 1, 0, 8, 0, 8, 0), 2: (0, 0, 0, 16, 0, 0, 0, 8)}
        for instance, values in lengths.items():  # 0x0C-0x13: lengths and channel counts
            answers = [await get(master, instance, 0x0C + n) for n in range(8)]
            assert answers == [f"8E {v:02X}" for v in values]
        assert await get(master, 2, 0x17) != "94 14 FF"  # AI data
        assert await get(master, 1, 0x07) == "8E 00 00 00 00"  # data error counter
        # the COM timeout is Get/Set: the back's reply timeout changes at once
        assert await master.request(bytes.fromhex("10 64 00 03 C8 00")) == bytes.fromhex("90")
        assert back.reply_timeout_ms == 200 and back.dcon.timeout == 0.2
        assert await get(master, 0, 3) == "8E C8 00"
        assert await master.request(bytes.fromhex("10 64 00 03 00 00")) == bytes.fromhex("94 09 FF")
        # the latch: the current outputs become the safe values the watchdog applies
        assert await master.request(bytes.fromhex("10 64 01 14 A5")) == bytes.fromhex("90")
        assert await master.request(bytes.fromhex("10 64 03 15 E8 03 00 00 D0 07 00 00")) == (
            bytes.fromhex("90")
        )
        assert await master.request(bytes.fromhex("10 64 04 14 02")) == bytes.fromhex("90")
        await wait_for(
            lambda: (
                sim.module(1).do_bits == 0xA5
                and sim.module(3).ao_raw[2] == 2000
                and sim.module(5).do_bits == 0x02
            ),
            master,
            10,
        )
        for instance in (1, 3, 4):
            assert await master.request(bytes([0x10, 0x64, instance, 0x18])) == b"\x90"
        await wait_for(
            lambda: sum(m.safe_values_latched for m in back.modules.values()) == 3, master, 10
        )
        assert sim.module(1).safe_do == 0xA5
        assert sim.module(3).safe_ao == [1000, 0, 2000, 0]
        assert sim.module(5).safe_do == 0x02
        assert await master.request(bytes.fromhex("10 64 02 18")) == bytes.fromhex(
            "94 14 FF"
        )  # an input module has no latch
        assert await master.request(bytes.fromhex("0E 64 01 18")) == bytes.fromhex("94 2C FF")
        status = gw.status()["backs"]["rs485"]
        assert status["reply_timeout_ms"] == 200
        assert [m["safe_values_latched"] for m in status["dcon_modules"]] == [1, 0, 1, 1]
    finally:
        master.close()
        await gw.stop()


async def test_modbus_modules_read_0_for_dcon_identity_and_a_stopped_back_answers_the_topology(
    tmp_path, registry
):
    from fieldgate.module_info import ModuleIdentity, ModuleInfo

    assert ModuleIdentity("M-7055D").module_id == 0x7055
    assert ModuleIdentity("I-87024", reported="87024").module_id == 0x87024
    assert ModuleIdentity("special").module_id == 0
    modbus = {
        "name": "mb",
        "type": "modbus",
        "port": "simulated",
        "modules": [{"address": 1, "model": "M-7055D"}],
    }
    from fieldgate.plugin import GatewayContext
    from fieldgate.topology import load_topology

    for back, answers in ((modbus, None), (DCON, {1: "55 70 00 00", 4: "00 4B 00 00", 5: "40"})):
        topo = load_topology(topology(tmp_path, "x", back), registry)
        context = GatewayContext.build(topo)
        front = registry.lookup("front", "devicenet").factory(topo.fronts[0], context)
        slave = front.build()
        assert isinstance(slave.module_info, ModuleInfo)
        app = slave.objects[0x64]
        for attribute in (1, 3, 4, 5, 6):
            read = app.attribute(1, attribute).read().hex(" ").upper()
            if answers is None:  # the manual's 0 where the back has no such notion
                assert read in ("00", "00 00 00 00")
            elif attribute in answers:
                assert read == answers[attribute]
        if answers is not None:
            assert app.attribute(0, 3).read() == bytes.fromhex("64 00")  # configured 100 ms
