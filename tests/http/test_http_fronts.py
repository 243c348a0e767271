"""What the fronts add to the status API: NMT and EMCY events, master output writes,
DeviceNet state and assembly locations, bus-off and fault events."""

from __future__ import annotations

import can
from httpkit import load_gateway, start, wait_for
from prometheus_client.parser import text_string_to_metric_families

from fieldgate.events import BUS_OFF, BUS_ON, FAULT, NMT_STATE


async def samples(running, family: str) -> list:
    text = (await running.get("/metrics")).text
    return [s for f in text_string_to_metric_families(text) if f.name == family for s in f.samples]


async def test_canopen_nmt_start_and_rpdo_show_up_as_event_metrics_and_written_by(running):
    gw = running.gateway
    bus = can.Bus(interface="virtual", channel=running.channel)
    try:
        # the example's node 2
        bus.send(can.Message(arbitration_id=0x000, data=[0x01, 0x02], is_extended_id=False))
        await wait_for(lambda: any(e.kind == NMT_STATE for e in running.events))
        event = next(e for e in running.events if e.kind == NMT_STATE)
        assert (event.source, event.data) == (
            "can",
            {"old": "PRE-OPERATIONAL", "new": "OPERATIONAL"},
        )
        nmt = {
            s.labels["state"]: s.value
            for s in await samples(running, "fieldgate_canopen_nmt_state")
        }
        assert nmt["OPERATIONAL"] == 1.0 and nmt["PRE-OPERATIONAL"] == 0.0
        bus.send(
            can.Message(arbitration_id=0x202, data=[0x05], is_extended_id=False)
        )  # RPDO1: DO bits 0, 2
        await wait_for(lambda: gw.image.value("rs485/m3/do2") is True)
    finally:
        bus.shutdown()
    point = (await running.get("/api/v1/points/rs485/m3/do2")).json()
    assert point["value"] is True and point["written_by"].startswith("can")
    (writes,) = await samples(running, "fieldgate_master_output_writes")
    assert writes.value == 1.0 and writes.labels == {"component": "can"}
    status = (await running.get("/api/v1/status")).json()
    assert status["fronts"]["can"]["nmt_state"] == "OPERATIONAL"


async def test_canopen_bus_off_and_recovery_are_events(running):
    front = running.gateway.component("can")
    front.on_bus_state(True, 0.0)
    front.on_bus_state(False, 1.0)
    kinds = [(e.kind, e.source) for e in running.events]
    assert (BUS_OFF, "can") in kinds and (BUS_ON, "can") in kinds
    status = (await running.get("/api/v1/status")).json()
    assert [e["level"] for e in status["events"] if e["kind"] == BUS_OFF] == ["warning"]


async def test_devicenet_front_state_locations_and_fault_events(tmp_path):
    gw = load_gateway(tmp_path, "i7241d-style.yaml")
    running = await start(gw)
    try:
        front = gw.component("dnet")
        await wait_for(lambda: front.slave.state == "online")  # after the duplicate MAC ID check
        state = {
            s.labels["state"]: s.value for s in await samples(running, "fieldgate_devicenet_state")
        }
        assert state == {"offline": 0.0, "dup-mac-check": 0.0, "online": 1.0, "comm-fault": 0.0}
        connections = await samples(running, "fieldgate_devicenet_connection_established")
        assert {s.labels["connection"] for s in connections} == {
            "explicit",
            "poll",
            "bit-strobe",
            "cos-cyclic",
            "cos-cyclic-data",
        }
        point = (await running.get("/api/v1/points/rs485/m1/di3")).json()
        assert point["served_by"] == [
            {
                "component": "dnet",
                "at": "assembly 102 byte 0 bit 3 (poll response byte 0, bit-strobe response byte 0, "
                "COS message byte 0)",
            }
        ]
        assert point["source"]["at"] == ["@01 reply bit 3"]
        front._fault("duplicate MAC ID 1 on the network")
        front.on_bus_state(True, 0.0)
        events = [(e.kind, e.source, e.level) for e in running.events]
        assert (FAULT, "dnet", "warning") in events and (BUS_OFF, "dnet", "warning") in events
    finally:
        await gw.stop()
