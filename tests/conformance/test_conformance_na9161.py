"""The na9161 profile and the mapping-granularity cases against fieldgate's NA-9161-style front
(in-process, virtual bus, loopback back with a special module), and the same cases failing
for the reason they check when the front is broken on purpose."""

from __future__ import annotations

import uuid

import can
import pytest
from conformance_gateway import (
    NODE_ID,
    GatewayThread,
    front_unavailable,
    patch_out,
    topology,
    write_eds,
)

from fieldgate.conformance import Options, SuiteConfig, Timing, Verdict, run_suite
from fieldgate.conformance.report import text_report
from fieldgate.plugins.canopen.cia301.abort import SdoAbort

CASES = [
    "na9161.*",
    "sync-pdo.dummy_mapping",
    "sync-pdo.dummy_undeclared",
    "sync-pdo.bit_mapping",
    "sync-pdo.granularity_whole_bytes",
]


def run(work, *, bit_mapping: bool = True, patterns=CASES):
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    channel = f"na-{uuid.uuid4().hex[:8]}"
    topo = topology(work / "state", channel)
    topo["fronts"][0].update(style="na9161", bit_mapping=bit_mapping)
    topo["backs"][0]["modules"] = [
        {"address": 1, "digital": 4},
        {"address": 2, "digital": 12},
        {"address": 3, "analog": 2},
        {"address": 4, "special": 6},
    ]
    eds = write_eds(topo, work)
    timing = Timing(response=0.3, silence=0.1, heartbeat_ms=50, bootup=1.0, sdo_server_timeout=1.0)
    with GatewayThread(topo):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            return run_suite(
                SuiteConfig(
                    NODE_ID,
                    str(eds),
                    timing=timing,
                    options=Options(loopback=True),
                    profiles=["all", "seed", "icpdas", "na9161"],
                    patterns=patterns,
                ),
                bus=bus,
            )
        finally:
            bus.shutdown()


def test_the_power_on_emcy_with_a_power_cycle(tmp_path):
    """na9161.hw_config_emcy with --power-cycle (here: the gateway stopped and started again on
    its state directory): after 0x1011 "load" the head powers on on its defaults and says so."""
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    channel = f"na-{uuid.uuid4().hex[:8]}"
    topo = topology(tmp_path / "state", channel)
    topo["fronts"][0].update(style="na9161")
    eds = write_eds(topo, tmp_path)
    running = [GatewayThread(topo).__enter__()]
    cycles = []

    def power_cycle() -> None:
        running[0].__exit__(None, None, None)
        running[0] = GatewayThread(topo).__enter__()
        cycles.append(1)

    timing = Timing(response=0.5, silence=0.1, heartbeat_ms=50, bootup=3.0, sdo_server_timeout=1.0)
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        results = run_suite(
            SuiteConfig(
                NODE_ID,
                str(eds),
                timing=timing,
                options=Options(power_cycle=power_cycle),
                profiles=["na9161"],
                patterns=["na9161.hw_config_emcy"],
            ),
            bus=bus,
        )
    finally:
        bus.shutdown()
        running[0].__exit__(None, None, None)
    assert verdicts(results) == {"na9161.hw_config_emcy": Verdict.PASS}, text_report(results)
    assert cycles == [1]


def refuse(self, value):
    raise SdoAbort(0x06090030, "broken on purpose")


def verdicts(results) -> dict[str, Verdict]:
    return {r.case.id: r.verdict for r in results}


def test_the_na9161_front_passes_the_na9161_and_granularity_cases(tmp_path):
    results = run(tmp_path)
    seen = verdicts(results)
    assert {cid for cid, v in seen.items() if v is not Verdict.PASS} == {
        "sync-pdo.granularity_whole_bytes",  # SKIP: this front maps single bits
        "sync-pdo.dummy_undeclared",  # SKIP: with bit mapping every dummy entry is declared
        "na9161.hw_config_emcy",  # SKIP: needs --power-cycle (test_..._power_cycle below)
    }, text_report(results)
    assert len(seen) == 21


def test_with_byte_granularity_the_bit_case_skips_and_the_byte_case_runs(tmp_path):
    results = run(
        tmp_path,
        bit_mapping=False,
        patterns=["sync-pdo.*mapping*", "sync-pdo.*dumm*", "sync-pdo.granularity*"],
    )
    seen = verdicts(results)
    assert seen["sync-pdo.bit_mapping"] is Verdict.SKIP
    assert seen["sync-pdo.granularity_whole_bytes"] is Verdict.PASS
    assert seen["sync-pdo.dummy_undeclared"] is Verdict.PASS  # Dummy0001 is not declared
    assert seen["sync-pdo.dummy_mapping"] is Verdict.PASS, text_report(results)


@pytest.mark.parametrize(
    "target, attribute, broken, case_id",
    [
        (
            "fieldgate.plugins.canopen.na9161.fnbus.FnBusRegister",
            "write_mode",
            refuse,
            "na9161.fnbus_register",  # TV-08: writing the mode back is refused
        ),
        (
            "fieldgate.plugins.canopen.na9161.fnbus.FnBusRegister",
            "apply",
            lambda self: None,  # the written mode never takes effect
            "na9161.data_mode_layout",
        ),
        (
            "fieldgate.plugins.canopen.cia301.pdo.rpdo.RpdoService",
            "_apply",
            lambda self, pdo, payload: None,  # RPDO data dropped
            "sync-pdo.dummy_mapping",
        ),
        (
            "fieldgate.plugins.canopen.cia401.analog.AnalogInterrupts",
            "fires",
            lambda self, change: False,  # analog changes are no events
            "na9161.analog_change_tpdo",
        ),
        (
            "fieldgate.image.ProcessImage",
            "apply_error_modes",
            lambda self, *args, **kwargs: [],  # outputs keep their values on an error event
            "na9161.heartbeat_loss_outputs",
        ),
        (
            "fieldgate.plugins.canopen.cia301.sync.SyncService",
            "_error_event",
            lambda self, lost, now: None,  # SYNC loss only an EMCY (the CiA 301 way)
            "na9161.sync_loss_outputs",
        ),
        (
            "fieldgate.plugins.canopen.canhealth.CanHealth",
            "_emcy_queue_overflow",
            lambda self, now: None,  # the overflow counted, not reported
            "na9161.emcy_queue_overflow",
        ),
        (
            "fieldgate.plugins.canopen.na9161.slots.SlotObjects",
            "read_memory",
            lambda self, slot: b"\x00",  # one byte whatever 0x4501 says
            "na9161.slot_objects",
        ),
        (
            "fieldgate.plugins.canopen.cia301.sdo.SdoServer",
            "_zero_extended",
            lambda self, data: data,  # CiA 301-strict: short writes aborted
            "na9161.short_expedited_write",
        ),
    ],
)
def test_a_broken_front_fails_the_case_that_checks_it(
    tmp_path, monkeypatch, target, attribute, broken, case_id
):
    patch_out(monkeypatch, target, attribute, broken)
    results = run(tmp_path, patterns=[case_id])
    assert verdicts(results) == {case_id: Verdict.FAIL}, text_report(results)
