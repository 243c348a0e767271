"""Topology validation: valid files give a summary; broken ones name file, line, field and what is expected."""

import textwrap
from pathlib import Path

import pytest

from fieldgate.topology import TopologyError, load_topology

VALID = """\
gateway:
  name: bench
fronts:
  - name: plc
    type: memory
    expose: ["io/m1/*", "io/m3/ao0"]
backs:
  - name: io
    type: loopback
    modules:
      - address: 3
        digital: 2
        analog: 1
        error_mode: {value: 1}
        error_modes:
          do1: hold
      - address: 1
        digital: 10
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "topology.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def issues_of(tmp_path, registry, text):
    path = write(tmp_path, text)
    with pytest.raises(TopologyError) as info:
        load_topology(path, registry)
    return path, info.value.issues


def test_valid_file_loads_with_channels_and_error_modes(tmp_path, registry):
    topo = load_topology(write(tmp_path, VALID), registry)
    assert [f.name for f in topo.fronts] == ["plc"] and topo.backs[0].type == "loopback"
    ids = [s.id for s in topo.channel_specs]
    assert len(ids) == 2 * 2 + 2 + 2 * 10
    do0 = next(s for s in topo.channel_specs if s.id == "io/m3/do0")
    do1 = next(s for s in topo.channel_specs if s.id == "io/m3/do1")
    assert do0.error_mode.use_value and do0.error_mode.value == 1
    assert not do1.error_mode.use_value
    summary = topo.summary()
    assert "1 front(s), 1 back(s), 2 module(s), 26 channel(s)" in summary
    assert "12 DI, 12 DO, 1 AI, 1 AO" in summary
    assert topo.state_dir == (tmp_path / "fieldgate-state").resolve()


def test_dict_source_and_overrides_by_name_and_index(registry, topology_dict):
    topo = load_topology(
        topology_dict(),
        registry,
        overrides={"fronts.plc.expose": ["io/m1/di0"], "backs.0.modules.1.digital": 3},
    )
    assert topo.fronts[0].expose == ["io/m1/di0"]
    assert sum(1 for s in topo.channel_specs if s.source.module == 1) == 6
    with pytest.raises(TopologyError, match="no list entry named 'nope'"):
        load_topology(topology_dict(), registry, overrides={"fronts.nope.expose": []})


# Each broken file: the text, the line the first issue must point at, the field path, and words of the message.
BROKEN = {
    "duplicate-key": (
        VALID.replace("    type: memory\n", "    type: memory\n    type: memory\n"),
        6,
        "",
        'duplicate key "type" in the mapping that starts on line 4',
    ),
    "yaml-syntax": (
        VALID.replace('expose: ["io/m1/*", "io/m3/ao0"]', 'expose: ["io/m1/*", "io/m3/ao0"'),
        7,
        "",
        "YAML syntax",
    ),
    "unknown-top-level-key": (
        VALID.replace("fronts:", "frnts:"),
        3,
        "frnts",
        "unknown field 'frnts'; did you mean 'fronts'?",
    ),
    "unknown-front-field": (
        VALID.replace("expose:", "expse:"),
        6,
        "fronts[0].expse",
        "did you mean 'expose'?",
    ),
    "unknown-field-no-suggestion": (
        VALID.replace("        digital: 10", "        digital: 10\n        colour: red"),
        19,
        "backs[0].modules[1].colour",
        "expected one of: address, analog, digital, error_mode",
    ),
    "missing-gateway-name": (
        VALID.replace("  name: bench\n", "  description: x\n"),
        2,
        "gateway.name",
        "required field is missing",
    ),
    "wrong-type": (
        VALID.replace("        digital: 10", "        digital: ten"),
        18,
        "backs[0].modules[1].digital",
        "valid integer",
    ),
    "out-of-range": (
        VALID.replace("        digital: 10", "        digital: 100"),
        18,
        "backs[0].modules[1].digital",
        "less than or equal to 64",
    ),
    "plugin-not-installed": (
        VALID.replace("type: memory", "type: profibus"),
        5,
        "fronts[0].type",
        "no installed plugin provides front type 'profibus'",
    ),
    "type-typo": (
        VALID.replace("type: loopback", "type: lopback"),
        9,
        "backs[0].type",
        "did you mean 'loopback'?",
    ),
    "duplicate-names": (
        VALID.replace("  - name: io", "  - name: plc"),
        8,
        "backs[0].name",
        "already used by fronts[0]",
    ),
    "duplicate-address": (
        VALID.replace("      - address: 1\n", "      - address: 3\n"),
        17,
        "backs[0].modules[1].address",
        "address 3 is already used by modules[0]",
    ),
    "expose-matches-nothing": (
        VALID.replace('"io/m3/ao0"', '"io/m3/ao9"'),
        6,
        "fronts[0].expose[1]",
        "'io/m3/ao9' matches no channel",
    ),
    "bad-error-mode": (
        VALID.replace("error_mode: {value: 1}", "error_mode: {valu: 1}"),
        14,
        "backs[0].modules[0].error_mode.valu",
        "unknown field 'valu'; did you mean 'value'?",
    ),
    "bad-name": (
        VALID.replace("name: bench", "name: 9bench"),
        2,
        "gateway.name",
        "should match pattern",
    ),
    "missing-type": (
        VALID.replace("    type: loopback\n", ""),
        8,
        "backs[0].type",
        "required field is missing: the back type, one of: ",
    ),
    "empty-fronts": (
        "gateway:\n  name: g\nfronts: []\nbacks:\n  - {name: io, type: loopback, modules: [{address: 1, digital: 1}]}\n",
        3,
        "fronts",
        "at least 1 item",
    ),
    "not-a-mapping": ("- just\n- a list\n", 1, "", "must be a mapping"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_files_report_file_line_field_and_expectation(case, tmp_path, registry):
    text, line, field, words = BROKEN[case]
    path, issues = issues_of(tmp_path, registry, text)
    matching = [i for i in issues if i.path == field]
    assert matching, f"no issue at {field!r}: {[str(i) for i in issues]}"
    first = matching[0]
    assert first.file == str(path)
    assert first.line == line, str(first)
    assert first.path == field, str(first)
    assert words in first.message, str(first)
    assert str(first).startswith(f"{path}:{line}:")


def test_every_error_is_reported_not_just_the_first(tmp_path, registry):
    text = VALID.replace("expose:", "expse:").replace("        digital: 10", "        digital: ten")
    _, issues = issues_of(tmp_path, registry, text)
    assert [i.path for i in issues] == ["fronts[0].expse", "backs[0].modules[1].digital"]


def test_unreadable_file(tmp_path, registry):
    with pytest.raises(TopologyError, match="cannot read file"):
        load_topology(tmp_path / "missing.yaml", registry)


def test_yaml_1_2_semantics_no_sexagesimal_and_no_on_off(tmp_path, registry):
    # PyYAML would read 12:30 as 750; ruamel (YAML 1.2) keeps it a string, which pydantic rejects as a name
    text = VALID.replace("name: bench", "name: 12:30")
    _, issues = issues_of(tmp_path, registry, text)
    assert "'12:30'" in issues[0].message
