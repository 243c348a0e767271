"""The modbus back's topology section: presets, channel groups, validation errors."""

import pytest

from fieldgate import DataType, ErrorMode, Kind
from fieldgate.plugins.modbus import presets
from fieldgate.plugins.modbus.client import inter_frame_gap
from fieldgate.topology import TopologyError, load_topology


def topology(modules, **back):
    return {
        "gateway": {"name": "t"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {"name": "rs485", "type": "modbus", "port": "/dev/null", "modules": modules, **back}
        ],
    }


def specs(registry, modules, **back):
    return {s.id: s for s in load_topology(topology(modules, **back), registry).channel_specs}


def errors(registry, modules, **back):
    with pytest.raises(TopologyError) as info:
        load_topology(topology(modules, **back), registry)
    return [f"{i.path}: {i.message}" for i in info.value.issues]


def test_a_model_preset_is_enough(registry):
    got = specs(registry, [{"address": 3, "model": "M-7055D"}])
    assert sorted(got) == sorted(
        [f"rs485/m3/di{i}" for i in range(8)] + [f"rs485/m3/do{i}" for i in range(8)]
    )
    assert got["rs485/m3/do7"].kind is Kind.DO and got["rs485/m3/do7"].data_type is DataType.BOOL


def test_every_requested_preset_exists_with_its_channel_counts():
    expected = {
        "M-7017R": {"ai": 8},
        "M-7024": {"ao": 4},
        "M-7050D": {"di": 7, "do": 8},
        "M-7052D": {"di": 8},
        "M-7055D": {"di": 8, "do": 8},
        "M-7060D": {"di": 4, "do": 4},
    }
    for model, counts in expected.items():
        preset = presets.find(model.lower())
        assert preset is not None and preset.source
        got: dict = {}
        for g in preset.groups:
            got[g["kind"]] = got.get(g["kind"], 0) + g["count"]
        assert got == counts, model


def test_counts_cut_a_preset_like_the_i7232d_demo(registry):
    got = specs(
        registry,
        [
            {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
            {"address": 5, "model": "M-7017R", "counts": {"ai": 1}},
        ],
    )
    assert sorted(got) == sorted([f"rs485/m3/do{i}" for i in range(8)] + ["rs485/m5/ai0"])


@pytest.mark.parametrize(
    "module, issue",
    [
        (
            {"address": 3, "model": "M-7055D", "counts": {"di": 9}},
            "backs[0].modules[0].counts.di: M-7055D has 8 DI (got 9)",
        ),
        (
            {"address": 1, "model": "M-7052D", "counts": {"ai": 2, "do": 3}},
            "backs[0].modules[0].counts.ai: M-7052D has no AI, only 8 DI (got 2)",
        ),
        (
            {"address": 1, "model": "M-7052D", "counts": {"do": 3}},
            "backs[0].modules[0].counts.do: M-7052D has no DO, only 8 DI (got 3)",
        ),
        (
            {"address": 4, "model": "M-7024", "counts": {"ao": -1}},
            "backs[0].modules[0].counts.ao: must be 0 or more (got -1)",
        ),
        (
            {
                "address": 4,
                "channels": [{"kind": "ao", "table": "holding_registers", "address": 0}],
                "counts": {"ao": 1},
            },
            "backs[0].modules[0].counts.ao: counts applies to a model's channels; this module has no model",
        ),
    ],
)
def test_counts_beyond_the_preset_are_refused_at_the_field(registry, module, issue):
    assert errors(registry, [module]) == [issue]


def test_counts_up_to_the_preset_are_kept(registry):
    got = specs(
        registry,
        [
            {"address": 3, "model": "M-7055D", "counts": {"di": 8, "do": 2}},
            {"address": 1, "model": "M-7052D", "counts": {"ai": 0}},
        ],
    )
    assert sum(1 for c in got if c.startswith("rs485/m3/di")) == 8
    assert sorted(c for c in got if c.startswith("rs485/m3/do")) == ["rs485/m3/do0", "rs485/m3/do1"]
    assert sum(1 for c in got if c.startswith("rs485/m1/")) == 8


def only_issue(registry, tmp_path, modules_yaml: str):
    """The one error of a Modbus back with these modules (YAML lines after ``modules:``, from line 8)."""
    path = tmp_path / "t.yaml"
    path.write_text(
        "gateway: {name: t}\nfronts: [{name: plc, type: memory}]\nbacks:\n  - name: rs485\n    type: modbus\n"
        "    port: /dev/null\n    modules:\n" + modules_yaml
    )
    with pytest.raises(TopologyError) as info:
        load_topology(path, registry)
    (issue,) = info.value.issues
    return path, issue


def test_a_counts_error_names_the_line_of_the_count(registry, tmp_path):
    path, issue = only_issue(
        registry,
        tmp_path,
        "      - address: 3\n        model: M-7055D\n        counts:\n          do: 2\n          di: 9\n",
    )
    assert str(issue) == f"{path}:12:15: backs[0].modules[0].counts.di: M-7055D has 8 DI (got 9)"


def test_declared_channels_follow_the_preset_and_number_on(registry):
    got = specs(
        registry,
        [
            {
                "address": 7,
                "model": "M-7052D",
                "channels": [
                    {
                        "kind": "di",
                        "table": "holding_registers",
                        "address": 100,
                        "count": 3,
                        "first_bit": 2,
                    },
                    {
                        "kind": "ai",
                        "table": "input_registers",
                        "address": 10,
                        "count": 2,
                        "type": "float32",
                        "word_order": "little",
                    },
                    {"kind": "ao", "table": "holding_registers", "address": 200, "type": "uint32"},
                ],
            }
        ],
    )
    assert "rs485/m7/di10" in got and "rs485/m7/di11" not in got
    assert got["rs485/m7/ai1"].data_type is DataType.FLOAT32
    assert got["rs485/m7/ao0"].data_type is DataType.UINT32


def test_output_error_modes_come_from_the_module(registry):
    got = specs(
        registry,
        [
            {
                "address": 3,
                "model": "M-7060D",
                "error_mode": {"value": 1},
                "error_modes": {"do2": "hold"},
                "shutdown_mode": {"value": 0},
            }
        ],
    )
    assert got["rs485/m3/do0"].error_mode == ErrorMode.to(True)
    assert got["rs485/m3/do2"].error_mode == ErrorMode.hold()
    assert got["rs485/m3/do1"].shutdown_mode == ErrorMode.to(False)


@pytest.mark.parametrize(
    "module, path, message",
    [
        (
            {"address": 0, "model": "M-7052D"},
            "backs[0].modules[0].address",
            "greater than or equal to 1",
        ),
        (
            {"address": 248, "model": "M-7052D"},
            "backs[0].modules[0].address",
            "less than or equal to 247",
        ),
        (
            {"address": 1, "model": "M-7999"},
            "backs[0].modules[0].model",
            "unknown model 'M-7999'; presets: M-7002",
        ),
        (
            {"address": 1},
            "backs[0].modules[0]",
            "needs a model (yours or a preset) or a channels list",
        ),
        (
            {"address": 1, "channels": [{"kind": "ao", "table": "input_registers", "address": 0}]},
            "backs[0].modules[0].channels[0]",
            "ao channels cannot live in input_registers; use one of: holding_registers",
        ),
        (
            {"address": 1, "channels": [{"kind": "do", "table": "discrete_inputs", "address": 0}]},
            "backs[0].modules[0].channels[0]",
            "use one of: coils, holding_registers",
        ),
        (
            {
                "address": 1,
                "channels": [{"kind": "di", "table": "coils", "address": 0, "type": "int16"}],
            },
            "backs[0].modules[0].channels[0]",
            "type applies to analog channels",
        ),
        (
            {
                "address": 1,
                "channels": [{"kind": "do", "table": "coils", "address": 0, "write_fc": 16}],
            },
            "backs[0].modules[0].channels[0]",
            "write_fc 16 does not write coils",
        ),
        (
            {
                "address": 1,
                "channels": [
                    {
                        "kind": "ao",
                        "table": "holding_registers",
                        "address": 0,
                        "type": "float32",
                        "write_fc": 6,
                    }
                ],
            },
            "backs[0].modules[0].channels[0]",
            "takes 2 registers: it needs write_fc 16",
        ),
        (
            {
                "address": 1,
                "channels": [
                    {"kind": "ai", "table": "input_registers", "address": 65535, "type": "int32"}
                ],
            },
            "backs[0].modules[0].channels[0]",
            "runs past address 65535",
        ),
        (
            {
                "address": 1,
                "model": "M-7055D",
                "channels": [{"kind": "do", "table": "coils", "address": 7}],
            },
            "backs[0].modules[0]",
            "output channels overlap in coils at address 7",
        ),
        (
            {
                "address": 1,
                "channels": [
                    {"kind": "ai", "table": "input_registers", "address": 0, "colour": "red"}
                ],
            },
            "backs[0].modules[0].channels[0].colour",
            "",
        ),
    ],
)
def test_configuration_errors_name_the_field_and_say_what_is_expected(
    registry, module, path, message
):
    issues = errors(registry, [module])
    assert any(issue.startswith(path) and message in issue for issue in issues), issues


def test_duplicate_module_addresses_are_refused(registry):
    issues = errors(
        registry, [{"address": 3, "model": "M-7055D"}, {"address": 3, "model": "M-7052D"}]
    )
    assert any("address 3 is already used" in i for i in issues)


def test_yaml_errors_name_the_line(registry, tmp_path):
    _, issue = only_issue(
        registry,
        tmp_path,
        "      - address: 3\n        model: M-7055D\n      - address: 4\n        channels:\n"
        "          - {kind: ao, table: coils, address: 0}\n",
    )
    assert issue.line == 12 and "ao channels cannot live in coils" in issue.message


def test_inter_frame_gap_follows_the_serial_line_spec():
    assert inter_frame_gap(9600) == pytest.approx(3.5 * 11 / 9600)  # 4.01 ms
    assert inter_frame_gap(19200) == pytest.approx(3.5 * 11 / 19200)
    assert inter_frame_gap(115200) == 0.00175


def test_the_link_takes_its_serial_settings_from_the_topology(registry):
    from fieldgate.plugins.modbus.client import ModbusLink

    topo = load_topology(
        topology(
            [{"address": 1, "model": "M-7052D"}],
            baudrate=9600,
            parity="E",
            stopbits=1,
            timeout_ms=300,
        ),
        registry,
    )
    link = ModbusLink.from_config(topo.backs[0])
    assert (link.timeout, link.gap, link._settings["parity"], link._settings["baudrate"]) == (
        0.3,
        inter_frame_gap(9600),
        "E",
        9600,
    )
    topo = load_topology(topology([{"address": 1, "model": "M-7052D"}], inter_frame_ms=0), registry)
    assert ModbusLink.from_config(topo.backs[0]).gap == 0
