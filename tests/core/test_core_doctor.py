"""``fieldgate doctor``: each condition issue 34 lists, found on a host the test builds (a /dev and
/proc tree of its own, CAN links as the kernel would describe them, a port really in use), one
line per finding with its fix, and the exit codes."""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate import load_registry
from fieldgate.can.link import LinkError
from fieldgate.can.rtnetlink import RawLink
from fieldgate.doctorcmd import FAIL, NOTE, OK, WARN, Finding, Host, Unit, check, run
from fieldgate.exitcodes import ExitCode
from fieldgate.topology import load_topology

REGISTRY = load_registry()
UNIT = """\
[Service]
User=fieldgate
Group=fieldgate
SupplementaryGroups=dialout
CapabilityBoundingSet=CAP_NET_ADMIN
AmbientCapabilities=CAP_NET_ADMIN
RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_CAN AF_NETLINK
"""
GIDS = {"fieldgate": 990, "dialout": 20, "uucp": 14}


def link(**kw) -> RawLink:
    base = dict(
        name="can0",
        index=3,
        up=True,
        kind="can",
        bitrate=125000,
        restart_ms=100,
        state="error-active",
    )
    base.update(kw)
    return RawLink(**base)  # type: ignore[arg-type]


def host(tmp_path: Path, links: dict[str, RawLink] | None = None) -> Host:
    def read_link(name: str) -> RawLink:
        if links is None or name not in links:
            raise LinkError(f"{name}: no such network interface")
        return links[name]

    return Host(
        str(tmp_path),
        read_link=read_link,
        users=lambda name: (990, 990) if name == "fieldgate" else None,
        groups=GIDS.get,
        group_name={v: k for k, v in GIDS.items()}.get,  # type: ignore[arg-type]
    )


def device(tmp_path: Path, name: str, gid: int = 20, mode: int = 0o660) -> Path:
    path = tmp_path / name.lstrip("/")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("")
    os.chmod(path, mode)
    os.chown(path, 0, gid)
    return path


def topology(tmp_path: Path, **parts) -> object:
    data = {
        "gateway": {"name": "d", **parts.pop("gateway", {})},
        "fronts": parts.pop("fronts", [{"name": "plc", "type": "memory"}]),
        "backs": parts.pop(
            "backs",
            [
                {
                    "name": "rs485",
                    "type": "modbus",
                    "port": "/dev/ttyS1",
                    "modules": [{"address": 1, "model": "M-7052D"}],
                }
            ],
        ),
    }
    return load_topology(data, REGISTRY)


CAN = {
    "name": "can",
    "type": "canopen",
    "interface": "socketcan",
    "channel": "can0",
    "node_id": 5,
    "bitrate": 125000,
}


def lines(findings) -> list[str]:
    return [f.line() for f in findings]


def only(findings, level: str, subject_part: str) -> list[str]:
    return [f.line() for f in findings if f.level == level and subject_part in f.subject]


@pytest.fixture
def unit() -> Unit:
    return Unit.parse("test.service", UNIT)


def test_can_missing_down_wrong_bit_rate_and_restart_ms_0(tmp_path, unit):
    device(tmp_path, "/dev/ttyS1")
    topo = topology(tmp_path, fronts=[CAN])
    (missing,) = only(check(topo, host(tmp_path), unit), FAIL, "can0")
    assert "can0: no such network interface; fix: plug the adapter" in missing
    assert "ip link set can0 type can bitrate 125000 restart-ms 100" in missing

    down = check(topo, host(tmp_path, {"can0": link(up=False)}), unit)
    assert only(down, FAIL, "can0") == [
        "FAIL  front can: can0: the interface is down; fix: ip link set can0 type can bitrate "
        "125000 restart-ms 100; ip link set can0 up"
    ]
    slow = check(topo, host(tmp_path, {"can0": link(bitrate=250000)}), unit)
    (warning,) = only(slow, WARN, "can0")  # the unit lets fieldgate set it at start
    assert (
        "runs at 250000 bit/s, the topology says 125000" in warning and "CAP_NET_ADMIN" in warning
    )
    no_cap = Unit.parse("u", UNIT.replace("CAP_NET_ADMIN", ""))
    assert only(check(topo, host(tmp_path, {"can0": link(bitrate=250000)}), no_cap), FAIL, "can0")
    stuck = check(topo, host(tmp_path, {"can0": link(restart_ms=0)}), unit)
    (restart,) = only(stuck, FAIL, "can0")
    assert "restart-ms is 0: after a bus-off" in restart and "restart-ms 100" in restart
    good = check(topo, host(tmp_path, {"can0": link()}), unit)
    assert only(good, OK, "can0") == [
        "ok    front can: can0: up at 125000 bit/s, restart-ms 100, state error-active"
    ]


def test_serial_missing_not_readable_busy_and_unstable_names(tmp_path, unit):
    topo = topology(tmp_path)
    (missing,) = only(check(topo, host(tmp_path), unit), FAIL, "/dev/ttyS1")
    assert "no such device; fix: plug the adapter" in missing

    device(tmp_path, "/dev/ttyS1", gid=GIDS["uucp"])
    (locked,) = only(check(topo, host(tmp_path), unit), FAIL, "/dev/ttyS1")
    assert (
        "owned by group uucp, mode crw-rw----" in locked
        or "owned by group uucp, mode -rw-rw----" in locked
    )
    assert "user fieldgate (groups fieldgate, dialout) cannot open it" in locked
    assert "fix: SupplementaryGroups=uucp" in locked

    tty = device(tmp_path, "/dev/ttyS1")
    fd = tmp_path / "proc" / "812" / "fd"
    fd.mkdir(parents=True)
    (fd / "3").symlink_to(tty)
    (tmp_path / "proc" / "812" / "comm").write_text("ModemManager\n")
    (busy,) = only(check(topo, host(tmp_path), unit), FAIL, "/dev/ttyS1")
    assert (
        "busy: held by pid 812 (ModemManager)" in busy
        and "systemctl disable --now ModemManager" in busy
    )

    usb = device(tmp_path, "/dev/ttyUSB0")
    by_id = tmp_path / "dev" / "serial" / "by-id"
    by_id.mkdir(parents=True)
    (by_id / "usb-FTDI_FT232R_A10K3XYZ-if00-port0").symlink_to("../../ttyUSB0")
    usb_topo = topology(
        tmp_path,
        backs=[
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/ttyUSB0",
                "modules": [{"address": 1, "model": "M-7052D"}],
            }
        ],
    )
    (unstable,) = only(check(usb_topo, host(tmp_path), unit), WARN, "ttyUSB0")
    assert "may be another adapter" in unstable
    assert unstable.endswith("fix: port: /dev/serial/by-id/usb-FTDI_FT232R_A10K3XYZ-if00-port0")
    assert usb.exists()


def test_listeners_in_use_privileged_and_foreign_addresses(tmp_path, unit):
    device(tmp_path, "/dev/ttyS1")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        topo = topology(
            tmp_path,
            gateway={"http": {"listen": f"127.0.0.1:{port}"}},
            fronts=[
                {"name": "mb", "type": "modbus-tcp", "listen": "127.0.0.1:502"},
                {"name": "ua", "type": "opcua", "listen": "127.0.0.1:0"},
            ],
        )
        found = check(topo, Host(), unit)
    (in_use,) = only(found, FAIL, "http")
    assert f"http: 127.0.0.1:{port}: in use" in in_use and "by pid" in in_use  # this test's socket
    (low,) = only(found, FAIL, "front mb")
    assert "port 502 is below 1024: user fieldgate needs CAP_NET_BIND_SERVICE" in low
    assert only(found, NOTE, "front ua") == ["note  front ua: 127.0.0.1:0: port 0: any free port"]
    bound = Unit.parse("u", UNIT.replace("CAP_NET_ADMIN", "CAP_NET_ADMIN CAP_NET_BIND_SERVICE"))
    assert not only(check(topo, Host(), bound), FAIL, "front mb")


def test_the_unit_s_capabilities_and_address_families(tmp_path):
    device(tmp_path, "/dev/ttyS1")
    topo = topology(tmp_path, fronts=[CAN], gateway={"isolation": {"fieldbus_nice": -5}})
    bare = Unit.parse(
        "bare.service", "[Service]\nUser=fieldgate\nRestrictAddressFamilies=AF_INET AF_UNIX\n"
    )
    found = check(topo, host(tmp_path, {"can0": link()}), bare)
    assert any("leaves out AF_CAN" in line for line in only(found, FAIL, "unit"))
    warned = " ".join(only(found, WARN, "unit"))
    assert "no CAP_NET_ADMIN" in warned and "AF_NETLINK" in warned
    assert "fieldbus_nice -5 needs CAP_SYS_NICE" in warned and "Nice=-5" in warned


def test_the_cpu_sets_against_the_cpus_the_host_offers(tmp_path):
    device(tmp_path, "/dev/ttyS1")

    def cpus_found(isolation: dict, offered: set[int]) -> list[Finding]:
        topo = topology(tmp_path, gateway={"isolation": isolation})
        return [
            f
            for f in check(topo, Host(root=str(tmp_path), cpus=lambda: offered), None)
            if f.subject == "cpus"
        ]

    assert cpus_found({}, {0, 1}) == []  # nothing pinned: nothing to say
    (ok,) = cpus_found({"fieldbus_cpus": [0]}, {0, 1})
    assert ok.level == OK
    (missing,) = cpus_found({"fieldbus_cpus": [2], "north_cpus": [0]}, {0, 1})
    assert (
        missing.level == WARN
        and "fieldbus_cpus: CPU 2 not on this host (it offers 0,1)" in missing.text
    )
    (crowded,) = cpus_found({"fieldbus_cpus": [0]}, {0})
    assert crowded.level == WARN and "takes every CPU (0): the children share them" in crowded.text


def test_exit_codes_as_documented(tmp_path, unit, capsys):
    (tmp_path / "u.service").write_text(UNIT)
    good = tmp_path / "good.yaml"
    good.write_text(
        "gateway: {name: d}\nfronts: [{name: plc, type: memory}]\n"
        "backs: [{name: rs485, type: modbus, port: /dev/ttyS1, modules: [{address: 1, model: M-7052D}]}]\n"
    )
    device(tmp_path, "/dev/ttyS1")
    args = argparse.Namespace(
        file=str(good), set=[], scan_file=[], unit=str(tmp_path / "u.service")
    )
    assert run(args, REGISTRY, host(tmp_path)) == ExitCode.OK
    assert capsys.readouterr().out.endswith("this host has what the topology needs\n")
    (tmp_path / "dev" / "ttyS1").unlink()
    assert run(args, REGISTRY, host(tmp_path)) == ExitCode.FAILED
    assert "1 problem(s) that stop the gateway" in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text("gateway: {name: 3x}\n")
    assert (
        run(argparse.Namespace(file=str(bad), set=[], scan_file=[], unit=None), REGISTRY)
        == ExitCode.FAILED
    )
    missing_unit = argparse.Namespace(
        file=str(good), set=[], scan_file=[], unit=str(tmp_path / "nope")
    )
    assert run(missing_unit, REGISTRY, host(tmp_path)) == ExitCode.CANNOT_RUN


def test_the_command_line_on_this_host(tmp_path):
    topo = tmp_path / "t.yaml"
    topo.write_text(
        "gateway: {name: d}\nfronts: [{name: plc, type: memory}]\n"
        "backs: [{name: rs485, type: modbus, port: /dev/fieldgate-no-such-tty, modules: [{address: 1, model: M-7052D}]}]\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "fieldgate", "doctor", str(topo)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == ExitCode.FAILED
    assert "FAIL  back rs485: /dev/fieldgate-no-such-tty: no such device; fix:" in done.stdout
