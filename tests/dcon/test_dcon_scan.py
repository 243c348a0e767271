"""Scanning a line for modules: in process against the simulator, and the two CLI commands together."""

import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ruamel.yaml import YAML

from fieldgate.plugins.dcon.link import DconLink
from fieldgate.plugins.dcon.scan import scan_line, topology_yaml
from fieldgate.plugins.dcon.scanfile import ScanFile
from fieldgate.plugins.dcon.simulator import DconSimulator
from fieldgate.serial_link import AsyncSerial, PtyPair
from fieldgate.topology import load_topology


async def _scan(modules, addresses, *, sim_checksum=False, checksum=False):
    with PtyPair() as pair:
        sim = DconSimulator.from_modules(pair.b, modules, checksum=sim_checksum)
        await sim.start()
        serial = await AsyncSerial.open(pair.a)
        progress = []
        try:
            found = await scan_line(
                DconLink(serial, checksum, 0.06, settle_after_timeout=False),
                addresses,
                9600,
                lambda *a: progress.append(a),
            )
        finally:
            await serial.close()
            await sim.stop()
    return found, progress


async def test_scan_finds_and_identifies_modules_and_prints_a_valid_topology(dcon_registry):
    modules = [(1, "I-7017", 0x09, "engineering"), (5, "I-7055"), (0x20, "I-87024", 0x35)]
    found, progress = await _scan(modules, range(0, 0x22))
    assert [(f.address, f.profile.model, f.config.type_code) for f in found] == [
        (1, "I-7017", 0x09),
        (5, "I-7055", 0x40),
        (0x20, "I-87024", 0x35),
    ]
    assert found[0].name == "7017" and found[0].firmware and found[0].describe_range() == "+/-5 V"
    assert len(progress) == 0x22 and progress[-1] == (0x22, 0x22, 3)
    text = topology_yaml(found, "/dev/ttyUSB0", False)
    back = YAML(typ="safe").load(text)["backs"][0]
    assert back["modules"][0] == {
        "address": 1,
        "model": "I-7017",
        "type_code": 9,
        "data_format": "engineering",
    }
    topo = load_topology(
        {"gateway": {"name": "g"}, "fronts": [{"name": "plc", "type": "memory"}], "backs": [back]},
        dcon_registry,
    )
    assert (
        len([s for s in topo.channel_specs if s.source.module == 0x20]) == 4
    )  # ready to paste: it validates


async def test_checksum_mismatch_finds_nothing():
    found, progress = await _scan([(1, "I-7060")], range(0, 3), sim_checksum=True, checksum=False)
    assert found == [] and progress[-1] == (3, 3, 0)
    found, _ = await _scan([(1, "I-7060")], range(0, 3), sim_checksum=True, checksum=True)
    assert [f.address for f in found] == [1]


def test_yaml_for_several_baud_rates_and_unknown_modules():
    from fieldgate.plugins.dcon.codec import ModuleConfigReply
    from fieldgate.plugins.dcon.profiles import find_profile
    from fieldgate.plugins.dcon.scan import Found

    found = [
        Found(1, 9600, "7060", "", ModuleConfigReply(0x40, 6, 0), find_profile("7060")),
        Found(2, 115200, "7099", "", ModuleConfigReply(0x40, 0x0A, 0x40), None),
    ]
    data = YAML(typ="safe").load(topology_yaml(found, "/dev/ttyS1", False))
    assert [b["name"] for b in data["backs"]] == ["rs485-9600", "rs485-115200"]
    text = topology_yaml(found, "/dev/ttyS1", False)
    assert "NOT SUPPORTED" in text and "module checksum is on" in text


def test_simulate_and_scan_commands_together(tmp_path):
    exe = os.path.join(os.path.dirname(sys.executable), "fieldgate")
    sim = subprocess.Popen(
        [
            exe,
            "simulate",
            "dcon",
            "--pty",
            "--module",
            "3:I-7060",
            "--module",
            "7:I-7012:0x0A:percent",
            "--duration",
            "20",
            "--baudrate",
            "19200",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = None
        for line in sim.stdout:
            if line.startswith("simulating back "):
                port = line.split("point the gateway at ")[1].split()[0]
                break
        assert port and port.startswith("/dev/")
        scan = subprocess.run(
            [
                exe,
                "scan",
                "dcon",
                "--port",
                port,
                "--addresses",
                "0-9",
                "--timeout-ms",
                "100",
                "--baudrate",
                "19200",
                "-o",
                str(tmp_path / "line.json"),
            ],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert scan.returncode == 0, scan.stderr
        assert f"2 module(s) written to {tmp_path / 'line.json'}" in scan.stderr
        assert "10/10 addresses, 2 module(s) found" in scan.stderr
        backs = YAML(typ="safe").load(scan.stdout)["backs"]
        assert [(m["address"], m["model"]) for m in backs[0]["modules"]] == [
            (3, "I-7060"),
            (7, "I-7012"),
        ] and backs[0]["baudrate"] == 19200
        assert (
            backs[0]["modules"][1]["type_code"] == 0x0A
            and backs[0]["modules"][1]["data_format"] == "percent"
        )
        # the scan file: what modules: auto and the EDS generators read
        written = ScanFile.read(tmp_path / "line.json")
        assert (written.port, written.addresses, written.baudrates) == (port, "0-9", [19200])
        assert [m.describe() for m in written.supported()] == [
            "I-7060 at 3",
            "I-7012 at 7 (type 0x0A +/-1 V, percent)",
        ]
        assert [m.baudrate for m in written.modules] == [19200, 19200]
    finally:
        sim.terminate()
        sim.wait(timeout=10)


def test_cli_errors_are_one_line():
    exe = os.path.join(os.path.dirname(sys.executable), "fieldgate")
    result = subprocess.run(
        [exe, "scan", "dcon", "--port", "/dev/does-not-exist", "--addresses", "1"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert (
        result.returncode == 2
        and "cannot open serial port /dev/does-not-exist" in result.stderr
        and "Traceback" not in result.stderr
    )
    result = subprocess.run(
        [exe, "simulate", "dcon", "--pty", "--module", "3:I-7999"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2 and "unknown DCON module" in result.stderr


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_simulate_stops_with_exit_0_on_ctrl_c_and_sigterm(stopped_by_signal, sig):
    code, stderr = stopped_by_signal(
        ["simulate", "dcon", "--pty", "--module", "3:I-7060"], "simulating back ", sig
    )
    assert code == 0 and "Traceback" not in stderr


@pytest.mark.parametrize(
    "command, value",
    [
        (["scan", "dcon", "--port", "/dev/ttyS0"], "19200,115200"),
        (["simulate", "dcon", "--pty"], "19200"),
    ],
)
def test_baudrate_as_in_the_topology_and_baud_still_accepted(capsys, command, value):
    from fieldgate import load_registry
    from fieldgate.cli import build_parser

    parser = build_parser(load_registry())
    expected = value if "," in value else int(value)
    assert parser.parse_args([*command, "--baudrate", value]).baudrate == expected
    assert (
        parser.parse_args([*command, "--baud", value]).baudrate == expected
    )  # the older name, kept
    # scan: 9600; simulate: the topology's, or the back's default (9600), as simulate modbus
    assert parser.parse_args(command).baudrate in ("9600", None)
    assert "'--baud' is deprecated" in capsys.readouterr().err  # the note, once per use
    with pytest.raises(SystemExit):
        parser.parse_args([*command, "--help"])
    usage = capsys.readouterr().out
    assert "--baudrate" in usage and "--baud " not in usage


def test_ctrl_c_during_a_scan_prints_what_it_found_and_where_it_stopped():
    exe = os.path.join(os.path.dirname(sys.executable), "fieldgate")
    sim = subprocess.Popen(
        [
            exe,
            "simulate",
            "dcon",
            "--pty",
            "--module",
            "3:I-7060",
            "--module",
            "7:I-7012:0x0A:percent",
            "--duration",
            "60",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    scan = None
    try:
        port = next(
            line.split("point the gateway at ")[1].split()[0]
            for line in sim.stdout
            if line.startswith("simulating back ")
        )
        scan = subprocess.Popen(
            [exe, "scan", "dcon", "--port", port, "--baudrate", "9600,19200", "--timeout-ms", "50"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        progress, deadline = b"", time.monotonic() + 30
        while (
            b"2 module(s) found" not in progress and time.monotonic() < deadline
        ):  # addresses 0-255: ~13 s to go
            if select.select([scan.stderr], [], [], 0.5)[0]:
                progress += os.read(scan.stderr.fileno(), 4096)
        assert b"2 module(s) found" in progress
        scan.send_signal(signal.SIGINT)
        out, err = scan.communicate(timeout=20)
        err = (progress + err).decode()
        assert scan.returncode == 130 and "Traceback" not in err
        stopped = re.search(
            r"interrupted at address (\d+) at 9600 bit/s \(it and the addresses after it were not probed\), "
            r"19200 bit/s not scanned; the modules found so far:\n$",
            err,
        )
        assert stopped and 7 < int(stopped.group(1)) < 255, err[-300:]
        backs = YAML(typ="safe").load(out)["backs"]
        assert [(m["address"], m["model"]) for m in backs[0]["modules"]] == [
            (3, "I-7060"),
            (7, "I-7012"),
        ]
    finally:
        for proc in (scan, sim):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()


def test_simulate_takes_the_modules_of_an_auto_back_from_its_scan_file():
    """``modules: auto`` has no list: ``fieldgate simulate dcon --topology`` serves the modules
    of the back's scan file (the I-7241D example's)."""
    example = Path(__file__).resolve().parents[2] / "examples" / "i7241d-style.yaml"
    result = subprocess.run(
        [sys.executable, "-m", "fieldgate", "simulate", "dcon", "--topology", str(example)]
        + ["--pty", "--duration", "20"],
        input="get rs485/m2/ai0\nquit\n",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    banner = next(line for line in result.stdout.splitlines() if line.startswith("simulating"))
    assert banner.startswith("simulating back rs485 (dcon): modules 1, 2, 3; point the gateway at")
    assert "rs485/m2/ai0 = 0" in result.stdout.splitlines()
