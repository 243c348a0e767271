"""`fieldgate eds`: the EDS imports with canopen, passes Lely's dcfchk, and matches the served dictionary."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import canopen
import pytest

from fieldgate import Gateway, load_registry
from fieldgate.cli import main as cli_main
from fieldgate.plugins.canopen.cia301.od import decode

DCFCHK = shutil.which("dcfchk") or str(Path(sys.executable).with_name("dcfchk"))


def topology(tmp_path: Path, **front) -> dict:
    return {
        "gateway": {"name": "eds-test", "state_dir": str(tmp_path / "state")},
        "fronts": [
            {
                "name": "plc",
                "type": "canopen",
                "interface": "virtual",
                "channel": f"eds-{uuid.uuid4().hex[:8]}",
                "node_id": 5,
                "identity": {
                    "vendor_id": 0xABCD,
                    "product_code": 0x7232,
                    "device_name": "fieldgate I-7232D",
                },
                **front,
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [
                    {"address": 1, "digital": 8, "analog": 2, "error_mode": {"value": 0}},
                    {"address": 3, "digital": 12},
                ],
            }
        ],
    }


def write_topology(tmp_path: Path, **front) -> Path:
    from ruamel.yaml import YAML

    path = tmp_path / "topo.yaml"
    with path.open("w") as f:
        YAML().dump(topology(tmp_path, **front), f)
    return path


def generate(tmp_path: Path, **front) -> Path:
    topo = write_topology(tmp_path, **front)
    out = tmp_path / "plc.eds"
    assert cli_main(["eds", str(topo), "--front", "plc", "-o", str(out)]) == 0
    return out


def dcfchk(path: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [DCFCHK, "-n", "5", str(path)], capture_output=True, text=True, timeout=60
    )


@pytest.mark.parametrize("style", ["icpdas", "na9161"])
def test_eds_imports_with_canopen_and_describes_the_layout(tmp_path, style):
    od = canopen.import_od(str(generate(tmp_path, style=style)), node_id=5)
    assert od[0x1000].default == 0x000F0191
    assert (
        od[0x6000][0].default == 3 and od[0x6200][0].default == 3
    )  # 1 byte + 2 bytes (12 DO of module 3)
    assert od[0x6401][0].default == 2 and od[0x6411][0].default == 2
    assert od[0x1800][1].default == 0x185 and od[0x1800][1].relative
    assert (
        od[0x1A00][1].default == 0x60000108
        and od[0x6200][1].access_type == "rw"
        and od[0x6200][1].pdo_mappable
    )
    assert od[0x6401][1].data_type == canopen.objectdictionary.INTEGER16 and not od[0x6000][
        1
    ].access_type.startswith("w")
    assert od[0x2000][0].default == 2 and od[0x2010][2].default == 3
    count = 32 if style == "icpdas" else 8
    assert (
        od.device_information.nr_of_TXPDO == count
        and (0x1800 + count - 1) in od
        and (0x1800 + count) not in od
    )
    assert od[0x1800][2].default == (255 if style == "icpdas" else 254)


@pytest.mark.parametrize(
    "options",
    [
        {"style": "icpdas", "pdo_count": 64},
        {"style": "na9161", "compressed": False},
        # the profiles' defaults and the topology's PDO keys are EDS defaults too
        {
            "style": "icpdas",
            "master": "delta-as300",
            "tpdos": {2: {"transmission_type": 1}, 5: {"cob_id": 0x1A5, "mapping": ["0x6000:1/8"]}},
            "rpdos": {1: {"transmission_type": 0}},
        },
        {"style": "na9161", "consumer_heartbeats": [{"node": 1, "time_ms": 300}]},
    ],
)
def test_eds_passes_lely_dcfchk(tmp_path, options):
    assert Path(DCFCHK).exists(), "dcf-tools is in the test extra"
    path = generate(tmp_path, **options)
    result = dcfchk(path)
    assert (
        result.returncode == 0 and "Warning" not in result.stderr and "rror" not in result.stderr
    ), result.stderr
    # the check can fail: a default outside its limits is reported
    broken = tmp_path / "broken.eds"
    broken.write_text(
        path.read_text().replace("[1A00sub1]\n", "[1A00sub1]\nLowLimit=0x0\nHighLimit=0x1\n", 1)
    )
    assert dcfchk(broken).returncode != 0


def test_cli_with_an_unknown_front_fails_with_a_message(tmp_path, capsys):
    path = write_topology(tmp_path)
    assert cli_main(["eds", str(path), "--front", "nosuch"]) == 1
    assert "no front named 'nosuch' (fronts: plc (canopen))" in capsys.readouterr().err
    assert not (tmp_path / "plc.eds").exists()


@pytest.mark.parametrize(
    "output, reason",
    [("no/such/dir/x.eds", "No such file or directory"), ("outdir", "Is a directory")],
)
def test_an_output_that_cannot_be_written_is_one_line_and_exit_1(tmp_path, capsys, output, reason):
    path = write_topology(tmp_path)
    (tmp_path / "outdir").mkdir()
    out = tmp_path / output
    assert cli_main(["eds", str(path), "-o", str(out)]) == 1
    assert capsys.readouterr().err == f"{out}: cannot write the EDS: {reason}\n"
    assert not (tmp_path / "no").exists() and not any(
        (tmp_path / "outdir").iterdir()
    )  # no folder made, no temporary left


def test_the_eds_file_gets_the_umask_mode_and_its_own_file_name(tmp_path, capsys):
    path = write_topology(tmp_path)
    out = tmp_path / "my.eds"
    old = os.umask(0o022)
    try:
        assert cli_main(["eds", str(path), "-o", str(out)]) == 0
    finally:
        os.umask(old)
    assert out.stat().st_mode & 0o777 == 0o644
    assert "\nFileName=my.eds\n" in out.read_text()
    assert (
        cli_main(["eds", str(path)]) == 0 and "\nFileName=plc.eds\n" in capsys.readouterr().out
    )  # standard output: the front's name


def test_set_overrides_the_topology_as_run_does(tmp_path, capsys):
    path = write_topology(tmp_path)
    assert cli_main(["eds", str(path), "--set", "fronts.plc.identity.product_code=77"]) == 0
    assert "\nProductNumber=77\n" in capsys.readouterr().out
    assert cli_main(["eds", str(path), "--set", "fronts.plc.node_id=200"]) == 1
    assert "(from --set fronts.plc.node_id=200)" in capsys.readouterr().err


def assert_served_as_described(eds: canopen.ObjectDictionary, node) -> None:
    in_eds = set()
    for obj in eds.values():
        if obj.index < 0x1000:
            continue  # [DummyUsage] declarations (canopen imports them as objects 0x0001-0x0007)
        for var in (
            [obj]
            if isinstance(obj, canopen.objectdictionary.ODVariable)
            else obj.subindices.values()
        ):
            in_eds.add((var.index, var.subindex))
            served = node.od.variable(var.index, var.subindex)
            assert (served.access_type, served.data_type) == (var.access_type, var.data_type), (
                f"0x{var.index:04X}:{var.subindex}"
            )
            if var.index == 0x1003 and var.subindex:
                continue  # empty error history answers 0800 0024
            if var.data_type == canopen.objectdictionary.DOMAIN:
                continue  # a live block of bytes (NA-9161 slot memory, parameters): no default
            assert decode(served, node.od.read(var.index, var.subindex)) == var.default, (
                f"0x{var.index:04X}:{var.subindex}"
            )
    assert {(v.index, v.subindex) for v in node.od.variables()} == in_eds


@pytest.mark.parametrize("style", ["icpdas", "na9161"])
async def test_every_eds_object_is_served_with_its_default_and_access(tmp_path, style):
    eds = canopen.import_od(str(generate(tmp_path, style=style)), node_id=5)
    gw = Gateway.load(topology(tmp_path, style=style), registry=load_registry())
    await gw.start()
    try:
        assert_served_as_described(eds, gw.component("plc").node)
    finally:
        await gw.stop()


async def test_dcon_watchdog_objects_in_the_eds_match_the_running_gateway(tmp_path):
    registry = load_registry()
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    topo = topology(tmp_path)
    topo["backs"] = [
        {
            "name": "rs485",
            "type": "dcon",
            "port": "simulated",
            "timeout_ms": 60,
            "poll_ms": 10,
            "modules": [
                {
                    "address": 1,
                    "model": "I-7060",
                    "watchdog": {"enabled": True, "timeout_ms": 1500},
                },
                {"address": 2, "model": "I-7017"},
            ],
        }
    ]
    from ruamel.yaml import YAML

    path = tmp_path / "dcon.yaml"
    with path.open("w") as f:
        YAML().dump(topo, f)
    out = tmp_path / "dcon.eds"
    assert cli_main(["eds", str(path), "-o", str(out)]) == 0
    assert dcfchk(out).returncode == 0
    eds = canopen.import_od(str(out), node_id=5)
    assert (
        eds[0x2001][1].default == 1 and eds[0x2002][1].default == 15 and eds[0x2003][0].default == 2
    )
    gw = Gateway.load(topo, registry=registry, simulate=True)
    await gw.start()
    try:
        assert_served_as_described(eds, gw.component("plc").node)
    finally:
        await gw.stop()


def test_cli_on_a_devicenet_topology_writes_the_devicenet_eds(capsys):
    """One command for every front with an EDS: the DeviceNet example gets its DeviceNet EDS."""
    example = Path(__file__).resolve().parents[2] / "examples" / "i7241d-style.yaml"
    assert cli_main(["eds", str(example)]) == 0
    out = capsys.readouterr().out
    assert "\n[IO_Info]\n" in out and "[DeviceInfo]" not in out


@pytest.mark.parametrize(
    "example",
    ["i7232d-style.yaml", "i7231d-style.yaml", "na9161-style.yaml", "canopen-sparkplug.yaml"],
)
def test_every_canopen_examples_eds_passes_dcfchk(tmp_path, example):
    """The EDS states each example's profile defaults (style, master, keys) and dcfchk is clean."""
    source = Path(__file__).resolve().parents[2] / "examples" / example
    out = tmp_path / "example.eds"
    assert cli_main(["eds", str(source), "-o", str(out)]) == 0
    result = dcfchk(out)
    assert result.returncode == 0 and "Warning" not in result.stderr, result.stderr
    od = canopen.import_od(str(out), node_id=5)
    if example == "canopen-sparkplug.yaml":  # master: delta-as300
        assert od[0x1016][1].default == 1 << 16 | 500 and od[0x1017].default == 1000
    elif example == "na9161-style.yaml":
        assert od[0x100C].default == 200 and od[0x6206][1].default == 0xFF
    else:  # an I-7232D / I-7231D: guarding only
        assert 0x1017 not in od and 0x1016 not in od


def test_the_eds_is_the_same_from_any_interpreter_and_lists_bit_rates_in_ascending_order(
    tmp_path,
):
    """canopen's writer iterates a set of rates; 20 and 800 kbit/s collide in it, and two
    installs wrote the same example's EDS in two orders. Written without bytecode caches and
    with them, under two hash seeds, the file is one and the same."""
    example = str(Path(__file__).resolve().parents[2] / "examples" / "i7232d-style.yaml")
    texts = []
    for flags, seed in (([], "1"), (["-B"], "2")):
        out = tmp_path / seed / "device.eds"
        out.parent.mkdir()
        env = {**os.environ, "PYTHONHASHSEED": seed}
        subprocess.run(
            [sys.executable, *flags, "-m", "fieldgate.cli", "eds", example, "-o", str(out)],
            check=True,
            env=env,
            capture_output=True,
        )
        texts.append([line for line in out.read_text().splitlines() if "Time" not in line])
    assert texts[0] == texts[1]
    rates = [int(line[9:].split("=")[0]) for line in texts[0] if line.startswith("BaudRate_")]
    assert rates == [10, 20, 50, 125, 250, 500, 800, 1000]
