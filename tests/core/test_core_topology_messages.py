"""Topology errors from a user review: files that are not UTF-8 or not YAML, --set paths and
values, error_mode, and every error reported at once. Each message names file, line and field."""

import textwrap
from pathlib import Path

import pytest
from test_core_topology import VALID

from fieldgate.cli import main
from fieldgate.topology import TopologyError, load_topology

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "i7232d-style.yaml"


def write(tmp_path: Path, text: str | bytes, name: str = "topology.yaml") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def issues(source, registry, overrides=None):
    with pytest.raises(TopologyError) as info:
        load_topology(source, registry, overrides)
    return info.value.issues


# -- 1. files that are not UTF-8 text ---------------------------------------------------


def test_a_latin1_file_is_one_error_naming_the_byte_and_its_line(tmp_path, registry):
    path = write(
        tmp_path,
        "gateway:\n  name: bench\n# Pr\xfcfstand 3\n".encode("latin-1")
        + VALID.split("\n", 2)[2].encode(),
    )
    (issue,) = issues(path, registry)
    assert (issue.line, issue.column) == (3, 5)
    assert (
        str(issue) == f"{path}:3:5: not UTF-8 text (byte 0xfc at offset 27); save the file as UTF-8"
    )


def test_a_binary_file_is_one_error(tmp_path, registry):
    path = write(tmp_path, b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    (issue,) = issues(path, registry)
    assert (
        str(issue) == f"{path}:1:1: not UTF-8 text (byte 0x89 at offset 0); save the file as UTF-8"
    )


def test_a_control_character_names_its_line(tmp_path, registry):
    path = write(tmp_path, VALID.replace("name: bench", "name: ben\x00ch"))
    (issue,) = issues(path, registry)
    assert (issue.line, issue.column) == (2, 12)
    assert "U+0000" in issue.message and "\n" not in issue.message


@pytest.mark.parametrize(
    "argv",
    [
        ["validate", "{}"],
        ["run", "{}"],
        ["eds", "{}"],
        ["devicenet", "eds", "{}"],
    ],
)
def test_commands_report_a_non_utf8_file_without_a_traceback(tmp_path, capsys, argv):
    path = write(tmp_path, b"# Pr\xfcfstand 3\n" + EXAMPLE.read_bytes())
    code = main([a.format(path) for a in argv])
    err = capsys.readouterr().err
    assert code != 0
    assert f"{path}:1:5: not UTF-8 text (byte 0xfc at offset 4); save the file as UTF-8" in err
    assert "Traceback" not in err


# -- 2. --set with a list index past the end --------------------------------------------


@pytest.mark.parametrize(
    "path, value, message",
    [
        ("fronts.1.expose", [], "--set fronts.1.expose=[]: fronts has 1 entry (index 0)"),
        ("fronts.-1.expose", [], "--set fronts.-1.expose=[]: fronts has 1 entry (index 0)"),
        (
            "backs.io.modules.3.poll_ms",
            50,
            "--set backs.io.modules.3.poll_ms=50: backs.io.modules has 2 entries (index 0..1)",
        ),
        (
            "backs.0.modules.-1.poll_ms",
            50,
            "--set backs.0.modules.-1.poll_ms=50: backs.0.modules has 2 entries (index 0..1)",
        ),
        (
            "fronts.nope.expose",
            [],
            "--set fronts.nope.expose=[]: no list entry named 'nope'; fronts has 1 entry (index 0), named 'plc'",
        ),
        ("gateway.name.x", 1, "--set gateway.name.x=1: gateway.name is not a mapping or list"),
    ],
)
def test_set_paths_that_address_no_entry(registry, topology_dict, path, value, message):
    (issue,) = issues(topology_dict(), registry, {path: value})
    assert issue.message == message


# -- 3. errors caused by a --set value say so -------------------------------------------


def test_an_error_from_a_set_value_names_the_override(tmp_path, registry):
    path = write(tmp_path, VALID.replace("expose:", "expse:"))
    got = issues(
        path,
        registry,
        {
            "backs.io.modules.1.digital": 100,
            "fronts.plc.colour": "red",
            "backs.io.modules.0.analog": 2,
        },
    )
    by_path = {i.path: i for i in got}
    assert set(by_path) == {"fronts[0].expse", "fronts[0].colour", "backs[0].modules[1].digital"}
    digital = by_path["backs[0].modules[1].digital"]
    assert digital.line == 18  # the key the override replaced
    assert (
        digital.message
        == "Input should be less than or equal to 64 (got 100) (from --set backs.io.modules.1.digital=100)"
    )
    assert by_path["fronts[0].colour"].message.endswith("(from --set fronts.plc.colour=red)")
    assert "--set" not in by_path["fronts[0].expse"].message  # the file's own error


def test_an_override_of_a_whole_mapping_tags_the_errors_inside_it(registry, topology_dict):
    got = issues(
        topology_dict(),
        registry,
        {"backs.io.modules.1.error_mode": {"valu": True}, "gateway.description": "ok"},
    )
    assert {i.path for i in got} == {
        "backs[0].modules[1].error_mode.valu",
        "backs[0].modules[1].error_mode.value",
    }
    assert all(
        i.message.endswith("(from --set backs.io.modules.1.error_mode={valu: true})") for i in got
    )


def test_a_set_that_creates_a_missing_section_is_named(registry, topology_dict):
    (issue,) = issues(topology_dict(), registry, {"gateway.extra.deep": 1})
    assert issue.path == "gateway.extra"
    assert issue.message.endswith("(from --set gateway.extra.deep=1)")


# -- 4. files that are not YAML ----------------------------------------------------------


def test_a_toml_file_is_not_a_yaml_mapping(tmp_path, registry):
    path = write(
        tmp_path, '[gateway]\nname = "bench"\n\n[[fronts]]\nname = "plc"\n', "topology.toml"
    )
    (issue,) = issues(path, registry)
    assert issue.message.startswith("not a YAML mapping: ")
    assert "INI or TOML" in issue.message
    assert "('" not in issue.message  # no raw tuple


def test_an_ini_file_read_as_one_string_is_not_a_yaml_mapping(tmp_path, registry):
    path = write(tmp_path, "; bench\nname=bench\nport=/dev/ttyUSB0\n", "topology.ini")
    (issue,) = issues(path, registry)
    assert (issue.line, issue.column) == (1, 1)
    assert issue.message.startswith(
        "not a YAML mapping: the file must be a mapping with keys gateway, fronts, backs"
    )
    assert "INI or TOML" in issue.message


def test_a_tab_used_for_indentation_gets_a_hint(tmp_path, registry):
    path = write(tmp_path, VALID.replace("  name: bench", "\tname: bench"))
    (issue,) = issues(path, registry)
    assert (issue.line, issue.column) == (2, 1)
    assert issue.message.endswith("(YAML indents with spaces, not tabs)")


# -- 5. error_mode, and every error at once -----------------------------------------------


@pytest.mark.parametrize(
    "key, text, path",
    [
        ("error_mode", "hodl", "backs[0].modules[0].error_mode"),
        ("shutdown_mode", "hodl", "backs[0].modules[0].shutdown_mode"),
        ("error_modes", "{do1: hodl}", "backs[0].modules[0].error_modes.do1"),
        ("error_mode", "3", "backs[0].modules[0].error_mode"),
    ],
)
def test_a_bad_error_mode_says_what_is_expected(tmp_path, registry, key, text, path):
    yaml = VALID.replace(
        "        error_mode: {value: 1}\n        error_modes:\n          do1: hold\n",
        f"        {key}: {text}\n",
    )
    (issue,) = issues(write(tmp_path, yaml), registry)
    assert issue.path == path and issue.line == 14
    got = "'hodl'" if "hodl" in text else "3"
    assert issue.message == f"expected 'hold' or {{value: X}} (got {got})"


def test_a_duplicate_address_is_reported_with_the_other_field_errors(tmp_path, registry):
    text = (
        VALID.replace("      - address: 1\n", "      - address: 3\n")
        .replace("expose:", "expse:")
        .replace("analog: 1", "analog: many")
    )
    got = issues(write(tmp_path, text), registry)
    assert [i.path for i in got] == [
        "fronts[0].expse",
        "backs[0].modules[0].analog",
        "backs[0].modules[1].address",
    ]
    assert "address 3 is already used by modules[0]" in got[2].message


def test_a_duplicate_name_and_a_bad_gateway_are_reported_with_the_other_errors(tmp_path, registry):
    text = (
        VALID.replace("name: bench", "name: 9bench")
        .replace("  - name: io", "  - name: plc")
        .replace("digital: 10", "digital: ten")
    )
    got = issues(write(tmp_path, text), registry)
    assert [i.path for i in got] == ["gateway.name", "backs[0].name", "backs[0].modules[1].digital"]


def test_a_back_that_checks_its_own_addresses_is_not_reported_twice(registry):
    data = {
        "gateway": {"name": "g"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "line",
                "type": "dcon",
                "port": "/dev/null",
                "modules": [{"address": 1, "model": "I-7017"}, {"address": 1, "model": "I-7053"}],
            }
        ],
    }
    (issue,) = issues(data, registry)
    assert issue.path == "backs[0]" and "two modules at address 1" in issue.message


def test_every_set_path_that_addresses_nothing_is_reported(registry, topology_dict):
    got = issues(
        topology_dict(),
        registry,
        {"fronts.pcl.expose": [], "fronts.plc.expose": ["io/m1/*"], "backs.0.modules.5.digital": 1},
    )
    assert [i.message for i in got] == [
        "--set fronts.pcl.expose=[]: no list entry named 'pcl'; fronts has 1 entry (index 0), named 'plc'; did you mean 'plc'?",
        "--set backs.0.modules.5.digital=1: backs.0.modules has 2 entries (index 0..1)",
    ]
