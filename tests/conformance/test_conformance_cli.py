"""`fieldgate conformance` is registered through the plugin registry and behaves as a CLI."""

import subprocess
import sys

import pytest
from conformance_slave import eds_text

from fieldgate import load_registry
from fieldgate.conformance import PROFILES, select
from fieldgate.conformance.cli import main


@pytest.fixture
def device_eds(tmp_path):
    """An EDS of the test slave, for runs that must get past reading it."""
    eds = tmp_path / "dev.eds"
    eds.write_text(eds_text())
    return eds


def test_command_is_registered_through_the_registry():
    registry = load_registry()
    assert ("conformance",) in {c.path for c in registry.commands}


def test_list_through_the_fieldgate_cli():
    out = subprocess.run(
        [sys.executable, "-m", "fieldgate", "conformance", "--profile", "lss", "--list"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    listed = [line.split()[0] for line in out.stdout.splitlines()]
    assert listed == [c.id for c in select(["lss"])] and len(listed) >= 9


def test_every_profile_has_cases_and_selection_keeps_profile_order():
    opt_in = {"seed", "icpdas", "na9161", "delta-as300"}
    assert {c.profile for c in select()} == set(PROFILES) - opt_in
    assert {c.profile for c in select(["seed"])} == {"seed"}
    # "all" leaves out the master-fit profile, which runs when named (beside "all" too)
    assert {c.profile for c in select(["all"])} == set(PROFILES) - {"delta-as300"}
    chosen = select(["all", "delta-as300"])
    assert {c.profile for c in chosen} == set(PROFILES)
    order = [PROFILES.index(c.profile) for c in chosen]
    assert order == sorted(order)
    assert [c.id for c in select(patterns=["sdo.block_*"])] == [
        "sdo.block_upload",
        "sdo.block_upload_crc",
        "sdo.block_download",
        "sdo.block_download_crc",
        "sdo.block_bad_blksize",
        "sdo.block_bad_seqno",
        "sdo.block_crc_error",
    ]


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["--node-id", "200", "--eds", "x.eds", "--interface", "virtual"]) == 2
    assert main(["--eds", "x.eds", "--interface", "virtual"]) == 2
    assert (
        main(
            [
                "--node-id",
                "5",
                "--eds",
                str(tmp_path / "missing.eds"),
                "--interface",
                "virtual",
                "--channel",
                "cli-missing-eds",
            ]
        )
        == 2
    )
    assert "cannot start" in capsys.readouterr().err


def test_a_silent_device_stops_the_run_with_exit_2(device_eds, capsys):
    assert (
        main(
            [
                "--node-id",
                "5",
                "--eds",
                str(device_eds),
                "--interface",
                "virtual",
                "--channel",
                "cli-nobody",
                "--timeout",
                "0.05",
            ]
        )
        == 2
    )
    assert "does not answer an SDO read of 0x1000 on 0x605" in capsys.readouterr().err


def test_an_unknown_interface_is_one_line_naming_it_and_exit_2(device_eds, capsys):
    assert main(["--node-id", "5", "--eds", str(device_eds), "--interface", "pcann"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith(
            "conformance: cannot start: unknown CAN interface 'pcann' (python-can knows: "
        )
        and err.count("\n") == 1
    )
    assert main(["--protocol", "devicenet", "--mac-id", "5", "--interface", "pcann"]) == 2
    assert "unknown CAN interface 'pcann'" in capsys.readouterr().err


def test_a_silent_device_on_the_virtual_bus_hints_that_it_is_one_process_only(device_eds, capsys):
    assert (
        main(
            [
                "--node-id",
                "5",
                "--eds",
                str(device_eds),
                "--interface",
                "virtual",
                "--channel",
                "cli-alone",
                "--timeout",
                "0.05",
            ]
        )
        == 2
    )
    assert "python-can's virtual bus exists only inside one process" in capsys.readouterr().err
    assert (
        main(
            [
                "--protocol",
                "devicenet",
                "--mac-id",
                "5",
                "--interface",
                "virtual",
                "--channel",
                "cli-alone",
                "--timeout",
                "0.05",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert (
        "does not answer an Allocate" in err
        and "use socketcan with a vcan channel, or a real adapter" in err
    )
