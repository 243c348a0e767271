"""Device models defined once (``models:``, a CSV register map) and devices listed by model, one
line each, on the RTU and the TCP back; errors name the file, the line and the column."""

from __future__ import annotations

from pathlib import Path

import pytest

from fieldgate import DataType, load_registry
from fieldgate.topology import TopologyError, load_topology

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

MAP = """\
# a meter's map
kind,table,address,count,type,order,divider,decimals,unit,low,high,length,label
ai,input_registers,0x0000,3,float32,BADC,,2,V,0,500,,Voltage L-N
ai,input_registers,6,1,int32,CDAB,1000,3,A,,,,Current L1
ai,holding_registers,0x0100,1,uint64,,,,Wh,,,,Energy
ai,holding_registers,0x0104,1,string,,,,,,,16,Serial number
"""


def write_topology(
    tmp_path: Path, models: dict, modules_rtu: list, modules_tcp: list, **tcp: object
) -> Path:
    import json

    (tmp_path / "meter.csv").write_text(MAP)
    data = {
        "gateway": {"name": "t"},
        "models": models,
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {"name": "rs485", "type": "modbus", "port": "/dev/null", "modules": modules_rtu},
            {"name": "net", "type": "modbus-tcp-client", "modules": modules_tcp, **tcp},
        ],
    }
    path = tmp_path / "t.yaml"
    path.write_text(json.dumps(data))  # JSON is YAML
    return path


METER = {"type": "modbus", "map": "meter.csv", "max_read_registers": 50}


def test_one_model_many_devices_one_line_each(tmp_path):
    path = write_topology(
        tmp_path,
        {"meter": METER},
        [{"address": a, "model": "meter"} for a in (1, 2)],
        [
            {"address": a, "host": f"10.0.{a // 200}.{a % 200}", "model": "meter"}
            for a in range(1, 301)
        ],
        unit=1,  # meters with an address of their own answer unit 1
    )
    topology = load_topology(path, load_registry())
    specs = {s.id: s for s in topology.channel_specs}
    assert len(specs) == 302 * 6
    assert specs["net/m300/ai0"].engineering.unit == "V"
    assert specs["net/m300/ai0"].label == "Voltage L-N [0]"
    assert specs["rs485/m2/ai3"].data_type is DataType.FLOAT64  # divided: engineering units
    assert specs["rs485/m2/ai4"].data_type is DataType.UINT64
    assert specs["rs485/m2/ai5"].data_type is DataType.STRING and specs["rs485/m2/ai5"].length == 16
    back = topology.back("net")
    assert {back.unit_of(m) for m in back.modules} == {1}
    assert back.modules[0].max_read_registers == 50  # the model's limit where the device gives none
    assert back.modules[0].groups()[0].order == "BADC"


def test_counts_and_own_channels_apply_to_a_model_too(tmp_path):
    path = write_topology(
        tmp_path,
        {"meter": METER},
        [
            {
                "address": 1,
                "model": "meter",
                "counts": {"ai": 2},
                "channels": [{"kind": "ai", "table": "input_registers", "address": 40}],
            }
        ],
        [{"address": 1, "host": "10.0.0.1", "model": "meter"}],
    )
    ids = [s.id for s in load_topology(path, load_registry()).channel_specs if "rs485" in s.id]
    assert ids == ["rs485/m1/ai0", "rs485/m1/ai1", "rs485/m1/ai2"]


def issues(path: Path) -> list[str]:
    with pytest.raises(TopologyError) as info:
        load_topology(path, load_registry())
    return [str(i) for i in info.value.issues]


@pytest.mark.parametrize(
    "csv_text, expected",
    [
        ("kind,table,adress\n", "meter.csv:1: unknown column 'adress'"),
        ("kind,table\nai,coils\n", "meter.csv:1: no column address"),
        (
            "kind,table,address\nai,input_registers,x12\n",
            "meter.csv:2: address: 'x12' is not a number",
        ),
        (
            "# comment\nkind,table,address,type\nai,input_registers,0,float128\n",
            "meter.csv:3: type: Input should be",
        ),
        (
            "kind,table,address\ndi,holding_registers,0,5\n",
            "meter.csv:2: more cells than the header",
        ),
        (
            "kind,table,address,type,registers\nai,input_registers,0,float64,2\n",
            "meter.csv:2: a float64 takes 4 registers",
        ),
        ("", "meter.csv: empty"),
    ],
)
def test_a_bad_register_map_is_one_line_with_its_file_line_and_column(tmp_path, csv_text, expected):
    path = write_topology(tmp_path, {"meter": METER}, [{"address": 1, "model": "meter"}], [])
    (tmp_path / "meter.csv").write_text(csv_text)
    found = issues(path)
    assert any(expected in i and "models.meter.map" in i for i in found), found
    assert any("model 'meter' has errors of its own" in i for i in found), found


def test_unknown_model_names_the_topologys_models_and_the_presets(tmp_path):
    path = write_topology(
        tmp_path,
        {"meter": METER},
        [{"address": 1, "model": "meterr"}],
        [{"address": 1, "host": "h", "model": "meter"}],
    )
    (found,) = issues(path)
    assert "backs[0].modules[0].model: unknown model 'meterr'" in found
    assert "the topology's models: meter" in found and "M-7052D" in found


def test_a_missing_map_file(tmp_path):
    path = write_topology(
        tmp_path,
        {"meter": {"type": "modbus", "map": "nope.csv"}},
        [{"address": 1, "model": "meter"}],
        [],
    )
    assert any("models.meter.map: nope.csv: no such file" in i for i in issues(path))


def test_validate_counts_polls_per_host_against_the_budget(tmp_path):
    models = {"meter": METER}
    devices = [{"address": a, "host": "10.0.0.9", "model": "meter"} for a in range(1, 41)]
    path = write_topology(tmp_path, models, [{"address": 1, "model": "meter"}], devices)
    topology = load_topology(path, load_registry())
    summary = topology.summary()
    # each meter: 2 reads a second (input registers 0..7, holding registers 0x100..0x10B),
    # 40 meters on one host at 10 ms a request: 80 requests/s, 80 % of the host's time
    assert "polls: host 10.0.0.9:502: 80.0 requests/s, 80 % booked" in summary, summary
    assert "polls: line /dev/null at 9600 baud:" in summary
    devices = [{**d, "poll_ms": 200} for d in devices]
    path = write_topology(tmp_path, models, [{"address": 1, "model": "meter"}], devices)
    warnings = load_topology(path, load_registry()).warnings()
    assert any(
        "host 10.0.0.9:502 gets 400 requests/s" in w and "400 % booked" in w for w in warnings
    )


def test_the_example_polls_tcp_devices_by_model_and_csv_map():
    topology = load_topology(EXAMPLES / "modbus-tcp-meters.yaml", load_registry())
    assert set(topology.models) == {"power-meter", "pump-drive"}
    meters = topology.back("meters")
    assert [m.model for m in meters.modules].count("power-meter") == 4
    assert {s.id for s in topology.channel_specs} >= {"meters/m11/ai9", "meters/m20/ao0"}
