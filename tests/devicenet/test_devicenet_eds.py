"""`fieldgate eds` of a devicenet front: the EDS parses with an independent reader (eds_pie) and states
exactly what a DeviceNet master finds on the bus: identity, I/O sizes after allocation, and
parameters whose link paths answer with their defaults."""

from __future__ import annotations

import logging
import os
import uuid
from pathlib import Path

import pytest
from dnet_master import Master
from ruamel.yaml import YAML

from fieldgate import Gateway, load_registry
from fieldgate.cli import main as cli_main


def _import_eds_pie():
    """eds_pie configures the root logger at import (basicConfig DEBUG): keep ours as it is."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    root.addHandler(logging.NullHandler())  # basicConfig does nothing when a handler exists
    try:
        from eds_pie.eds_pie import CIP_EDS
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
    return CIP_EDS


CIP_EDS = _import_eds_pie()
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
REQUIRED = {
    "File": ["DescText", "CreateDate", "CreateTime", "Revision"],
    "Device": [
        "VendCode",
        "VendName",
        "ProdType",
        "ProdTypeStr",
        "ProdCode",
        "MajRev",
        "MinRev",
        "ProdName",
        "Catalog",
    ],
    "IO_Info": ["Default", "PollInfo", "StrobeInfo", "COSInfo", "CyclicInfo"],
    "ParamClass": ["MaxInst", "Descriptor", "CfgAssembly"],
}
IDENTITY = {
    "vendor_id": 803,
    "device_type": 12,
    "product_code": 7241,
    "major_revision": 2,
    "minor_revision": 1,
    "product_name": "ICPDAS-I7241D",
}


@pytest.fixture(scope="module")
def registry():
    registry = load_registry()
    for role, name in (("front", "devicenet"), ("back", "dcon"), ("back", "modbus")):
        if registry.lookup(role, name) is None:
            pytest.skip(f"the {name} plugin is not installed")
    return registry


def parse(text: str, caplog) -> object:
    """eds_pie's parse and semantic check; no error may be logged (its lexer raises on bad syntax)."""
    with caplog.at_level(logging.WARNING, logger="eds_pie"):
        caplog.clear()
        eds = CIP_EDS(text)
    errors = [
        r.getMessage()
        for r in caplog.records
        if r.name.startswith("eds_pie") and r.levelno >= logging.ERROR
    ]
    assert not errors, errors
    for section, keys in REQUIRED.items():
        for key in keys:
            assert eds.has_entry(section, key), f"[{section}] {key}"
    for section in (
        "File",
        "Device",
        "Params",
    ):  # sections eds_pie types: every field got its CIP type
        for entry in eds.get_section(section).entries.values():
            for f in entry.fields:
                assert f.value == "" or type(f.data).__name__ not in ("UNDEFINED", "NoneType"), (
                    section,
                    entry.keyword,
                    f.value,
                )
    return eds


def value(eds, section: str, key: str, index: int = 0) -> int | str:
    """A field as eds_pie read it; numbers as int (eds_pie leaves untyped [IO_Info] fields as text)."""
    v = eds.get_value(section, key, index)
    try:
        return int(v, 0) if isinstance(v, str) else v
    except ValueError:
        return v


def generate(tmp_path: Path, topology: Path, *options: str) -> str:
    out = tmp_path / "slave.eds"
    assert cli_main(["eds", str(topology), *options, "-o", str(out)]) == 0
    return out.read_text(encoding="latin-1")


def identity_options() -> list[str]:
    return [f"--set=fronts.dnet.identity.{key}={value}" for key, value in IDENTITY.items()]


async def get(master: Master, class_id: int, instance: int, attr: int) -> bytes:
    reply = await master.request(bytes([0x0E, class_id, instance, attr]))
    assert reply[0] == 0x8E, reply.hex(" ")
    return reply[1:]


def number(data: bytes) -> int:
    return int.from_bytes(data, "little")


def path_of(eds, key: str) -> int:
    """The assembly instance an InputN / OutputN entry's path names."""
    return bytes.fromhex(value(eds, "IO_Info", key, 5))[3]


@pytest.mark.parametrize(
    "example, mac, sizes",
    [("i7241d-style.yaml", 1, (17, 9)), ("devicenet-modbus.yaml", 5, (17, 1))],
)
async def test_eds_states_what_the_running_front_answers(
    tmp_path, caplog, registry, example, mac, sizes
):
    eds = parse(
        generate(tmp_path, EXAMPLES / example, "--front", "dnet", *identity_options()), caplog
    )
    assert (
        value(eds, "IO_Info", "Input1"),
        value(eds, "IO_Info", "Output1"),
    ) == sizes  # the docs' layout
    channel = f"fg-eds-{uuid.uuid4().hex[:8]}"
    overrides = {
        "fronts.dnet.interface": "virtual",
        "fronts.dnet.channel": channel,
        "fronts.dnet.dup_mac_timeout_ms": 50,
        "backs.rs485.poll_ms": 10,
        "gateway.state_dir": str(tmp_path / "state"),
        **{f"fronts.dnet.identity.{k}": v for k, v in IDENTITY.items()},
    }
    gw = Gateway.load(EXAMPLES / example, overrides, registry, simulate=True)
    master = Master(channel, slave=mac)
    await gw.start()
    try:
        await master.wait_online()
        assert await master.allocate(0x17) == bytes.fromhex(
            "0A CB 00"
        )  # explicit, poll, bit-strobe, COS
        assert number(await get(master, 1, 1, 1)) == value(eds, "Device", "VendCode") == 803
        assert number(await get(master, 1, 1, 2)) == value(eds, "Device", "ProdType") == 12
        assert value(eds, "Device", "ProdTypeStr") == "Communications Adapter"
        assert number(await get(master, 1, 1, 3)) == value(eds, "Device", "ProdCode") == 7241
        assert (
            tuple(await get(master, 1, 1, 4))
            == (value(eds, "Device", "MajRev"), value(eds, "Device", "MinRev"))
            == (2, 1)
        )
        name = await get(master, 1, 1, 7)
        assert name[1 : 1 + name[0]].decode() == value(eds, "Device", "ProdName") == "ICPDAS-I7241D"
        assert value(eds, "Device", "VendName") == "ICP DAS"
        # I/O sizes of the allocated connections (Connection attributes 7 produced, 8 consumed)
        poll_in, poll_out = number(await get(master, 5, 2, 7)), number(await get(master, 5, 2, 8))
        strobe_in, cos_in = number(await get(master, 5, 3, 7)), number(await get(master, 5, 4, 7))
        assert (poll_in, poll_out) == sizes
        assert value(eds, "IO_Info", "Output1", 5) == (
            "20 04 24 64 30 03" if poll_out == 1 else "20 04 24 68 30 03"
        )  # DO 0x64 alone, or fieldgate's all-outputs instance 0x68 (DO 0x64 + AO 0x65)
        assert (
            value(eds, "IO_Info", "PollInfo", 1) == 1 and value(eds, "IO_Info", "PollInfo", 2) == 1
        )
        assert value(eds, "IO_Info", "Input1") == poll_in and value(eds, "IO_Info", "Output1") == (
            poll_out
        )
        assert (
            value(eds, "IO_Info", "Input1", 2) == 0x000D
        )  # poll, COS, cyclic: the strobe answers fewer bytes
        # the defaults are the topology's paths: each names an entry of the connection's size
        strobe, cos = value(eds, "IO_Info", "StrobeInfo", 1), value(eds, "IO_Info", "COSInfo", 1)
        assert value(eds, "IO_Info", f"Input{strobe}") == strobe_in
        assert value(eds, "IO_Info", f"Input{strobe}", 2) & 0x0002
        assert value(eds, "IO_Info", f"Input{cos}") == cos_in
        assert value(eds, "IO_Info", f"Input{cos}", 2) & 0x0004
        cos_out = value(eds, "IO_Info", "COSInfo", 2)
        if example == "i7241d-style.yaml":  # strobe DI (1 byte), COS DI in and DO out
            assert (strobe_in, cos_in, cos_out) == (1, 1, 2) and path_of(eds, "Output2") == 0x64
        else:  # the defaults: the first 8 bytes of all inputs, COS all inputs and no outputs
            assert (strobe, strobe_in, cos, cos_out) == (4, 8, 1, 0)
        entries = [
            key for key in eds.get_section("IO_Info").entries if key.startswith(("Input", "Output"))
        ]
        assert len(entries) == (6 if poll_out == 9 else 5)
        for key in entries:  # every path names the assembly that holds its data
            path = bytes.fromhex(value(eds, "IO_Info", key, 5))
            assert value(eds, "IO_Info", key, 4) == 6 and path[:3] == b"\x20\x04\x24"
            assert path[4:] == b"\x30\x03"
            size = len(await get(master, 4, path[3], 3))
            assert size == value(eds, "IO_Info", key) or (key == f"Input{strobe}" and size > 8)
        # a configurator selects an entry by setting the connection's path: the size follows
        for key, attribute in (("Input2", 0x0E), ("Input3", 0x0E), ("Output1", 0x10)):
            path = bytes.fromhex(value(eds, "IO_Info", key, 5))
            reply = await master.request(bytes([0x10, 5, 2, attribute]) + path)
            assert reply == b"\x90"
            size = number(await get(master, 5, 2, 7 if attribute == 0x0E else 8))
            assert size == value(eds, "IO_Info", key)
            assert await get(master, 5, 2, attribute) == path
        input1 = bytes.fromhex(value(eds, "IO_Info", "Input1", 5))
        assert await master.request(bytes.fromhex("10 05 02 0E") + input1) == b"\x90"  # back
        # a poll of Output1's size is answered with Input1's size
        assert await master.request(bytes.fromhex("10 05 02 09 F4 01")) == bytes.fromhex("90 F4 01")
        assert len(await master.poll_fragmented_reply(bytes(poll_out), 17)) == poll_in
    finally:
        master.close()
        await gw.stop()


async def test_every_parameter_link_path_answers_its_default_and_takes_it(
    tmp_path, caplog, registry
):
    """The i7241d example: heartbeat, BOI, Host OK and the three DCON modules' watchdog enable and time."""
    eds = parse(generate(tmp_path, EXAMPLES / "i7241d-style.yaml"), caplog)
    params = {
        key: entry
        for key, entry in eds.get_section("Params").entries.items()
        if key.startswith("Param")
    }
    assert value(eds, "ParamClass", "MaxInst") == 0 and len(params) == 2 + 1 + 3 * 2
    channel = f"fg-edsp-{uuid.uuid4().hex[:8]}"
    overrides = {
        "fronts.dnet.interface": "virtual",
        "fronts.dnet.channel": channel,
        "fronts.dnet.dup_mac_timeout_ms": 50,
        "backs.rs485.poll_ms": 10,
        "backs.rs485.timeout_ms": 150,
        "gateway.state_dir": str(tmp_path / "state"),
    }
    gw = Gateway.load(EXAMPLES / "i7241d-style.yaml", overrides, registry, simulate=True)
    master = Master(channel, slave=1)
    await gw.start()
    try:
        await master.wait_online()
        await master.allocate(0x01)
        for key in params:
            path = bytes.fromhex(value(eds, "Params", key, 2))
            assert value(eds, "Params", key, 1) == len(path) == 6 and path[0::2] == bytes(
                [0x20, 0x24, 0x30]
            )
            class_id, instance, attr = path[1::2]
            size, minimum, maximum, default = (value(eds, "Params", key, i) for i in (5, 9, 10, 11))
            current = await get(master, class_id, instance, attr)
            assert len(current) == size == 1 and minimum <= default <= maximum
            if attr != 0x09:  # a DCON watchdog time never set reads 0; the EDS offers 5.0 s
                assert number(current) == default, key
            reply = await master.request(bytes([0x10, class_id, instance, attr, default]))
            assert reply == b"\x90", (key, reply.hex(" "))
        assert number(await get(master, 0x64, 1, 0x09)) == 50  # the module took the EDS default
    finally:
        master.close()
        await gw.stop()


def write_topology(tmp_path: Path, fronts: list[dict], modules: list[dict] | None = None) -> Path:
    path = tmp_path / "topology.yaml"
    data = {
        "gateway": {"name": "eds-test", "state_dir": str(tmp_path / "state")},
        "fronts": fronts,
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": modules or [{"address": 1, "digital": 8, "analog": 2}],
            }
        ],
    }
    with path.open("w") as f:
        YAML().dump(data, f)
    return path


def dnet_front(**extra) -> dict:
    return {
        "name": "dnet",
        "type": "devicenet",
        "interface": "virtual",
        "channel": "unused",
        "mac_id": 3,
        **extra,
    }


def test_one_assembly_per_side_names_its_path_and_small_inputs_serve_every_connection(
    tmp_path, caplog
):
    topology = write_topology(tmp_path, [dnet_front(expose=["io/m1/di*", "io/m1/do*"])])
    eds = parse(generate(tmp_path, topology), caplog)
    # DO 0x64 (1 byte) is the only output assembly, DI 0x65 (1 byte) the only input assembly
    assert value(eds, "IO_Info", "Input1") == 1 and value(eds, "IO_Info", "Input1", 2) == 0x000F
    assert (value(eds, "IO_Info", "Input1", 4), value(eds, "IO_Info", "Input1", 5)) == (
        6,
        "20 04 24 65 30 03",
    )
    assert (value(eds, "IO_Info", "Output1", 4), value(eds, "IO_Info", "Output1", 5)) == (
        6,
        "20 04 24 64 30 03",
    )
    assert not eds.has_entry("IO_Info", "Input2") and value(eds, "IO_Info", "StrobeInfo", 1) == 1
    assert (
        value(eds, "Device", "VendName") == "fieldgate"
        and value(eds, "Device", "ProdTypeStr") == "Generic Device"
    )
    assert not any(
        k.startswith("Param") and value(eds, "Params", k, 6) == "Host OK"
        for k in eds.get_section("Params").entries
    )


def test_several_assemblies_have_a_combined_instance_and_each_its_entry(tmp_path, caplog):
    eds = parse(generate(tmp_path, write_topology(tmp_path, [dnet_front()])), caplog)
    # loopback module: DO 0x64 (1), AO 0x65 (4), DI 0x66 (1), AI 0x67 (4); all outputs 0x68,
    # all inputs 0x69 (5 bytes each: the strobe answers them whole)
    assert [
        (value(eds, "IO_Info", key), value(eds, "IO_Info", key, 2), path_of(eds, key))
        for key in ("Input1", "Input2", "Input3", "Output1", "Output2", "Output3")
    ] == [
        (5, 0x000F, 0x69),
        (1, 0x000F, 0x66),
        (4, 0x000F, 0x67),
        (5, 0x000D, 0x68),
        (1, 0x000D, 0x64),
        (4, 0x000D, 0x65),
    ]
    assert not eds.has_entry("IO_Info", "Input4") and value(eds, "IO_Info", "StrobeInfo", 1) == 1
    assert (
        value(eds, "IO_Info", "Input1", 6)
        == "all inputs assembly 0x69: DI 0x66 (1 byte) + AI 0x67 (4 bytes)"
    )
    assert value(eds, "IO_Info", "Output3", 6) == "AO assembly 0x65 (4 bytes)"


def test_the_topologys_paths_are_the_eds_defaults(tmp_path, caplog):
    paths = {
        "poll": {"produce": "di", "consume": "do"},
        "strobe": {"produce": "ai"},
        "cos": {"produce": "ai", "consume": "ao"},
        "cyclic": {"produce": 0x66, "consume": "outputs"},
    }
    eds = parse(generate(tmp_path, write_topology(tmp_path, [dnet_front(io_paths=paths)])), caplog)
    # the poll's assemblies come first: Input1 DI 0x66, Input2 AI 0x67, Input3 all inputs 0x69;
    # Output1 DO 0x64, Output2 AO 0x65, Output3 all outputs 0x68
    assert [path_of(eds, f"Input{n}") for n in (1, 2, 3)] == [0x66, 0x67, 0x69]
    assert [path_of(eds, f"Output{n}") for n in (1, 2, 3)] == [0x64, 0x65, 0x68]
    defaults = {
        kind: (value(eds, "IO_Info", f"{kind}Info", 1), value(eds, "IO_Info", f"{kind}Info", 2))
        for kind in ("Poll", "Strobe", "COS", "Cyclic")
    }
    assert defaults == {"Poll": (1, 1), "Strobe": (2, 0), "COS": (2, 2), "Cyclic": (1, 3)}


def test_a_topology_without_outputs_has_no_output_entry(tmp_path, caplog):
    eds = parse(
        generate(tmp_path, write_topology(tmp_path, [dnet_front(expose=["io/m1/di*"])])), caplog
    )
    assert not eds.has_entry("IO_Info", "Output1") and value(eds, "IO_Info", "PollInfo", 2) == 0
    assert value(eds, "IO_Info", "Input1") == 1


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["--front", "nosuch"],
            "no front named 'nosuch' (fronts: plc (canopen), dnet (devicenet), panel (memory))",
        ),
        (
            ["--front", "panel"],
            "front 'panel' is a memory front, which has no EDS (EDS for: canopen, canopen-device, devicenet)",
        ),
    ],
)
def test_bad_front_is_one_line_and_exit_code_1(tmp_path, capsys, args, message):
    canopen = {
        "name": "plc",
        "type": "canopen",
        "interface": "virtual",
        "channel": "unused",
        "node_id": 5,
        "expose": ["io/m1/di*"],  # one output has one writing front: the dnet front here
    }
    panel = {"name": "panel", "type": "memory", "expose": ["io/m1/di*"]}
    topology = write_topology(tmp_path, [canopen, dnet_front(), panel])
    out = tmp_path / "x.eds"
    assert cli_main(["eds", str(topology), *args, "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err == f"{topology}: {message}\n" and not out.exists()
    # one command for both fronts: the first with an EDS by default, or the one named
    assert (
        cli_main(["eds", str(topology), "-o", str(out)]) == 0 and "[DeviceInfo]" in out.read_text()
    )
    assert cli_main(["eds", str(topology), "--front", "dnet", "-o", str(out)]) == 0
    assert "\n[IO_Info]\n" in out.read_text(encoding="latin-1")


def test_no_front_with_an_eds_and_invalid_topology_exit_1_as_validate(tmp_path, capsys):
    topology = write_topology(tmp_path, [{"name": "panel", "type": "memory"}])
    assert cli_main(["eds", str(topology)]) == 1
    assert capsys.readouterr().err == (
        f"{topology}: no front with an EDS in the topology (fronts: panel (memory); "
        "EDS for: canopen, canopen-device, devicenet)\n"
    )
    bad = write_topology(tmp_path, [dnet_front(mac_id=64)])
    assert cli_main(["eds", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "mac_id" in err and "Traceback" not in err
    assert cli_main(["eds", str(bad)]) == cli_main(["validate", str(bad)]) == 1


def test_the_old_spelling_writes_the_same_eds_with_a_deprecation_note(tmp_path, capsys):
    topology = write_topology(tmp_path, [dnet_front()])
    old, new = tmp_path / "old.eds", tmp_path / "new.eds"
    assert cli_main(["devicenet", "eds", str(topology), "-o", str(old)]) == 0
    assert capsys.readouterr().err.splitlines()[0] == (
        "fieldgate: 'fieldgate devicenet eds' is deprecated and goes away in the next release; "
        "use 'fieldgate eds TOPOLOGY [--front NAME]'"
    )
    assert cli_main(["eds", str(topology), "-o", str(new)]) == 0

    def body(path: Path) -> list[str]:  # without the creation date and time
        return [
            line
            for line in path.read_text(encoding="latin-1").splitlines()
            if not line.strip().startswith(("CreateDate", "CreateTime", "ModDate", "ModTime"))
        ]

    # the two runs may fall in different seconds: the four date and time lines are left out
    assert len(body(new)) == len(new.read_text(encoding="latin-1").splitlines()) - 4
    assert body(old) == body(new)


def test_vendor_name_applies_to_devicenet_fronts_only(tmp_path, capsys):
    canopen = {
        "name": "plc",
        "type": "canopen",
        "interface": "virtual",
        "channel": "x",
        "node_id": 5,
    }
    topology = write_topology(tmp_path, [canopen])
    assert cli_main(["eds", str(topology), "--vendor-name", "Acme"]) == 1
    assert capsys.readouterr().err == (
        f"{topology}: --vendor-name applies to devicenet fronts; plc is canopen\n"
    )


def test_standard_output_without_o(tmp_path, capsys):
    topology = write_topology(tmp_path, [dnet_front()])
    assert cli_main(["eds", str(topology), "--vendor-name", 'Acme "Fieldbus" Ltd']) == 0
    text = capsys.readouterr().out
    assert (
        CIP_EDS(text).get_value("Device", "VendName") == 'Acme \\"Fieldbus\\" Ltd'
    )  # eds_pie keeps the escape
    assert text.startswith("$ ") and "\n[File]\n" in text


def test_unwritable_output_exits_1_with_one_line(tmp_path, capsys):
    topology = write_topology(tmp_path, [dnet_front()])
    out = topology / "x.eds"  # below a regular file
    assert cli_main(["eds", str(topology), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{out}: cannot write the EDS: ") and err.count("\n") == 1


@pytest.mark.parametrize(
    "output, reason",
    [("no/such/dir/x.eds", "No such file or directory"), ("outdir", "Is a directory")],
)
def test_a_missing_folder_or_a_directory_is_one_line_and_exit_1(tmp_path, capsys, output, reason):
    topology = write_topology(tmp_path, [dnet_front()])
    (tmp_path / "outdir").mkdir()
    out = tmp_path / output
    assert cli_main(["eds", str(topology), "-o", str(out)]) == 1
    assert capsys.readouterr().err == f"{out}: cannot write the EDS: {reason}\n"
    assert not (tmp_path / "no").exists() and not any(
        (tmp_path / "outdir").iterdir()
    )  # no folder made, no temporary left


def test_the_eds_file_gets_the_umask_mode(tmp_path):
    topology = write_topology(tmp_path, [dnet_front()])
    out = tmp_path / "slave.eds"
    old = os.umask(0o022)
    try:
        assert cli_main(["eds", str(topology), "-o", str(out)]) == 0
    finally:
        os.umask(old)
    assert out.stat().st_mode & 0o777 == 0o644
