"""The opcua front without a client: quality table, address space, listener rules, one writer."""

from __future__ import annotations

import pytest

from fieldgate import load_registry
from fieldgate.image import ChannelSpec, DataType, Kind, ProcessImage, Quality, Scaling, Source
from fieldgate.plugins.opcua import model
from fieldgate.plugins.opcua.quality import STATUS_OF, status_code, status_name
from fieldgate.topology import TopologyError, load_topology

REGISTRY = load_registry()


def topology(**opcua: object) -> dict[str, object]:
    return {
        "gateway": {"name": "cell"},
        "fronts": [{"name": "ua", "type": "opcua", **opcua}],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "modules": [
                    {"address": 1, "model": "M-7052D"},
                    {"address": 4, "model": "M-7024", "counts": {"ao": 2}},
                ],
            }
        ],
    }


def errors(data: dict[str, object]) -> list[str]:
    with pytest.raises(TopologyError) as info:
        load_topology(data, REGISTRY)
    return [f"{i.path}: {i.message}" for i in info.value.issues]


# -- quality -> StatusCode -------------------------------------------------------------------
def test_every_quality_has_the_status_code_the_issue_names():
    assert set(STATUS_OF) == set(Quality)
    assert status_code(Quality.GOOD) == 0
    assert status_name(status_code(Quality.STALE)) == "Uncertain_LastUsableValue"
    assert (
        status_name(status_code(Quality.COMM_FAULT)) == "Bad_NoCommunication"
    )  # DA's "Comm Failure"
    assert (
        status_name(status_code(Quality.OVER_RANGE)) == "Uncertain_EngineeringUnitsExceeded (High)"
    )
    assert (
        status_name(status_code(Quality.UNDER_RANGE)) == "Uncertain_EngineeringUnitsExceeded (Low)"
    )
    assert status_name(status_code(Quality.NOT_READ)) == "Bad_WaitingForInitialData"
    assert status_name(status_code(Quality.CONFIG_ERROR)) == "Bad_ConfigurationError"
    assert status_name(status_code(Quality.WATCHDOG)) == "Uncertain_SubstituteValue"
    # severity bits: good 00, uncertain 01, bad 10 (Part 4 §7.39.1)
    severity = {q: status_code(q) >> 30 for q in Quality}
    assert severity[Quality.GOOD] == 0
    assert {severity[q] for q in (Quality.STALE, Quality.OVER_RANGE, Quality.WATCHDOG)} == {1}
    assert {severity[q] for q in (Quality.COMM_FAULT, Quality.NOT_READ, Quality.CONFIG_ERROR)} == {
        2
    }


def test_the_quality_table_in_the_docs_is_the_code():
    from pathlib import Path

    doc = (Path(__file__).parents[2] / "docs" / "opcua.md").read_text()
    for quality in Quality:
        name = status_name(status_code(quality)).split(" (")[0]
        assert f"| `{quality.value}` | {name}" in doc, quality


LIMITS = (
    "max_connections",
    "max_connections_per_peer",
    "max_sessions",
    "max_sessions_per_peer",
    "hello_timeout_s",
    "activation_timeout_s",
    "max_session_timeout_ms",
    "max_chunk_size",
    "max_message_size",
    "max_chunk_count",
    "min_publishing_interval_ms",
    "min_sampling_interval_ms",
    "max_subscriptions_per_session",
    "max_monitored_items_per_subscription",
    "max_monitored_items_per_session",
    "max_queue_size",
    "max_retransmission_queue",
)


def test_every_limit_is_in_the_docs_table_with_its_default():
    """docs/opcua.md "Limits": one row per key, its default as the code has it (issue 29)."""
    from pathlib import Path

    from fieldgate.plugins.opcua.config import OpcUaFrontConfig

    doc = (Path(__file__).parents[2] / "docs" / "opcua.md").read_text()
    fields = OpcUaFrontConfig.model_fields
    documented = {line.split("`")[1] for line in doc.splitlines() if line.startswith("| `max_")}
    documented |= {line.split("`")[1] for line in doc.splitlines() if line.startswith("| `min_")}
    documented |= {
        line.split("`")[1]
        for line in doc.splitlines()
        if line.startswith("| `") and "_s` |" in line
    }
    assert documented == set(LIMITS)
    for key in LIMITS:
        default = fields[key].default
        text = (
            f"{default:g}"
            if isinstance(default, float) and default != int(default)
            else str(int(default))
        )
        assert f"| `{key}` | {text}" in doc or f"| `{key}` | {float(default)}" in doc, key


def test_limits_bound_what_validate_accepts():
    with pytest.raises(TopologyError, match="max_connections_per_peer"):
        load_topology(topology(max_connections=4, max_connections_per_peer=8), REGISTRY)
    with pytest.raises(TopologyError, match="min_publishing_interval_ms"):
        load_topology(topology(min_publishing_interval_ms=0), REGISTRY)
    with pytest.raises(TopologyError, match="max_chunk_size"):
        load_topology(topology(max_chunk_size=1024), REGISTRY)  # below Part 6's 8,192
    load_topology(topology(min_sampling_interval_ms=0, max_sessions=100), REGISTRY)


# -- address space -----------------------------------------------------------------------------
def channels() -> list:
    image = ProcessImage(clock=lambda: 0.0)
    image.add(ChannelSpec("rs485/m1/di0", Kind.DI, Source("rs485", 1, 0)))
    image.add(
        ChannelSpec(
            "rs485/m2/ai0",
            Kind.AI,
            Source("rs485", 2, 0),
            scaling=Scaling(0, 32767, 0.0, 10.0, "V"),
        )
    )
    image.add(ChannelSpec("rs485/m2/ao0", Kind.AO, Source("rs485", 2, 0), dtype=DataType.UINT16))
    image.add(ChannelSpec("rs485/m2/ao1", Kind.AO, Source("rs485", 2, 1), dtype=DataType.FLOAT32))
    return list(image)


def test_node_ids_are_channel_ids_and_only_listed_outputs_are_writable():
    space = model.build(
        "cell",
        channels(),
        writable=["rs485/m2/ao0"],
        modules={("rs485", 2): "M-7024"},
        lines={"rs485": "modbus on /dev/ttyUSB0 at 9600 baud"},
        locations={"rs485/m2/ai0": ["input register 0 (FC4)"]},
        other_fronts=["can"],
    )
    variables = {v.node_id: v for v in space.variables}
    assert variables["rs485/m1/di0"].data_type == "Boolean"
    assert variables["rs485/m2/ao0"].data_type == "UInt16" and variables["rs485/m2/ao0"].writable
    assert variables["rs485/m2/ao1"].data_type == "Float" and not variables["rs485/m2/ao1"].writable
    assert not variables["rs485/m1/di0"].writable  # an input never is
    ai = variables["rs485/m2/ai0"]
    assert ai.eu_range == (0, 32767)  # raw range: what a percent deadband on the raw value uses
    assert "module 2 (M-7024)" in ai.description and "input register 0 (FC4)" in ai.description
    assert "modbus on /dev/ttyUSB0 at 9600 baud" in ai.description
    eng = variables["rs485/m2/ai0/eng"]
    assert (eng.data_type, eng.eu_range, eng.unit, eng.writable) == (
        "Double",
        (0.0, 10.0),
        "V",
        False,
    )
    assert {f.node_id for f in space.folders} >= {
        "cell",
        "rs485",
        "rs485/m1",
        "rs485/m2",
        "rs485/m2/health",
        "fronts",
        "fronts/can",
    }
    assert "rs485/m2/health/online" in variables and "fronts/can/master_present" in variables
    assert "fronts/can/state" in variables


def test_the_address_space_does_not_depend_on_other_modules():
    """Stable node ids: adding a module leaves every other node id as it was."""
    full = model.build("cell", channels())
    part = model.build("cell", [c for c in channels() if c.source.module == 2])
    assert {v.node_id for v in part.variables} <= {v.node_id for v in full.variables}


# -- listener rules (fieldgate validate) ---------------------------------------------------------
def test_security_none_is_refused_off_loopback():
    found = errors(topology(listen="0.0.0.0:4840"))
    assert len(found) == 1
    assert "fronts[0]: listen 0.0.0.0:4840 is not a loopback address: security None" in found[0]


def test_off_loopback_needs_users():
    found = errors(topology(listen="10.0.0.5:4840", security=["SignAndEncrypt"]))
    assert "give users" in found[0]


def test_off_loopback_with_encryption_and_users_is_valid():
    data = topology(
        listen="10.0.0.5:4840",
        security=["Sign", "SignAndEncrypt"],
        users=[{"name": "scada", "password_env": "UA_PW"}],
    )
    topo = load_topology(data, REGISTRY)
    front = topo.fronts[0]
    assert front.anonymous_allowed is False  # type: ignore[attr-defined]


def test_a_user_needs_exactly_one_password_source():
    found = errors(topology(users=[{"name": "x"}]))
    assert "password_file or password_env" in found[0]


def test_an_output_written_by_two_northbound_fronts_is_refused_naming_both():
    data = topology(writable=["rs485/m4/ao0"])
    data["fronts"].append(
        {
            "name": "mb",
            "type": "modbus-tcp",
            "listen": "127.0.0.1:5020",
            "writable": ["rs485/m4/ao*"],
        }
    )  # type: ignore[attr-defined]
    found = errors(data)
    assert len(found) == 1
    assert "output rs485/m4/ao0 would be written by front 'mb' and by front 'ua'" in found[0]


# -- deadband (the filter's arithmetic; node-opcua drives it end to end in test_opcua_client) ----
def test_percent_deadband_uses_the_eu_range_and_the_last_reported_value():
    from asyncua import ua

    from fieldgate.plugins.opcua import deadband

    class Space:  # stands for an address space (weak-referenced by the range table)
        pass

    class Item:
        def __init__(self, flt: object) -> None:
            self.filter = flt
            self.read_value_id = ua.ReadValueId(NodeId=ua.NodeId("rs485/m2/ai0", 2))

    space = Space()
    deadband.set_ranges(space, {ua.NodeId("rs485/m2/ai0", 2): (0.0, 32767.0)})
    service = deadband.DeadbandMonitoredItems.__new__(deadband.DeadbandMonitoredItems)
    service.aspace = space
    service._reported = {}

    def dv(value: int, status: int = 0) -> ua.DataValue:
        return ua.DataValue(
            ua.Variant(value, ua.VariantType.Int16), ua.StatusCode(ua.UInt32(status))
        )

    percent = Item(
        ua.DataChangeFilter(
            Trigger=ua.DataChangeTrigger.StatusValue, DeadbandType=2, DeadbandValue=1.0
        )
    )
    assert service._passes(1, percent, dv(0))  # nothing reported yet
    service._reported[1] = dv(0)
    assert not service._passes(1, percent, dv(327))  # 1 % of 32767 is 327.67
    assert service._passes(1, percent, dv(328))
    assert service._passes(1, percent, dv(0, 0x40900000))  # a status change always
    status_only = Item(ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.Status))
    assert not service._passes(1, status_only, dv(30000))


async def test_a_port_in_use_is_one_line_at_start(tmp_path):
    import socket

    from fieldgate import Gateway
    from fieldgate.runtime import GatewayStartError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        data = topology(listen=f"127.0.0.1:{port}")
        data["gateway"]["state_dir"] = str(tmp_path)  # type: ignore[index]
        gw = Gateway.load(data, registry=REGISTRY, simulate=True)
        with pytest.raises(GatewayStartError) as info:
            await gw.start()
        await gw.stop()
    assert f"front ua (opcua): cannot listen on 127.0.0.1:{port}" in str(info.value)
    assert "\n" not in str(info.value)
