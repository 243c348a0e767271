"""``fieldgate scan modbus``: the unit ids that answer on a line, as a topology section whose
models are left to fill in (Modbus RTU does not name a module)."""

from __future__ import annotations

import subprocess
import sys

from ruamel.yaml import YAML


def test_scan_modbus_finds_the_simulated_unit_ids():
    sim = subprocess.Popen(
        [sys.executable, "-m", "fieldgate", "simulate", "modbus", "--pty", "--duration", "30"]
        + ["--module", "1:M-7052D", "--module", "3:M-7055D", "--module", "5:M-7017R"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        banner = sim.stdout.readline()
        port = banner.split("point the gateway at ")[1].split()[0]
        scan = subprocess.run(
            [sys.executable, "-m", "fieldgate", "scan", "modbus", "--port", port]
            + ["--addresses", "1-6", "--baudrate", "9600", "--timeout-ms", "100"],
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        sim.terminate()
        sim.wait(timeout=10)
    assert scan.returncode == 0, scan.stderr
    assert "6/6 addresses, 3 module(s) found" in scan.stderr
    (back,) = YAML(typ="safe").load(scan.stdout)["backs"]
    assert (back["type"], back["port"], back["baudrate"], back["parity"]) == (
        "modbus",
        port,
        9600,
        "N",
    )
    assert [(m["address"], m["model"]) for m in back["modules"]] == [
        (1, "FILL-IN"),
        (3, "FILL-IN"),
        (5, "FILL-IN"),
    ]
    assert "# answered FC3 register 0: exception 2" in scan.stdout


def test_unit_id_0_is_the_broadcast_address_and_not_scanned():
    result = subprocess.run(
        [sys.executable, "-m", "fieldgate", "scan", "modbus", "--port", "/dev/null"]
        + ["--addresses", "0-3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "address range '0-3' outside 1..247" in result.stderr
