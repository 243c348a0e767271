"""``modules: auto`` without its line: a missing port or a silent line does not stop the
gateway (seed-001 #35, seed-003 #39). The fronts come up, the back starts with the modules it
expects (the previous start's scan, else the scan file) offline, or with none and scans again
on a back-off; the status says why (docs/dcon.md, "modules: auto without its line")."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

import fieldgate.plugins.dcon.discovery as dcon_discovery
from fieldgate import Gateway, Quality
from fieldgate.plugins.dcon.simulator import DconSimulator
from fieldgate.serial_link import PluggablePty, PtyPair

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
LINE = [(1, "I-7055"), (2, "I-7017", 0x08, "hex"), (3, "I-7024", 0x33, "hex")]


def topology(tmp_path: Path, port: str, **back) -> dict:
    return {
        "gateway": {"name": "auto", "state_dir": str(tmp_path / "state")},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": port,
                "timeout_ms": 40,
                "poll_ms": 10,
                "offline_probe_ms": 100,
                "modules": "auto",
                "scan": {"addresses": "1-4"},
                **back,
            }
        ],
    }


async def wait_until(check, seconds: float, what: str) -> None:
    import asyncio

    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    while not check():
        if loop.time() > end:
            raise AssertionError(f"never: {what}")
        await asyncio.sleep(0.02)


async def test_a_missing_port_starts_with_the_scan_files_modules_offline_until_it_appears(
    tmp_path, dcon_registry
):
    pty = PluggablePty(tmp_path / "ttyUSB0")
    pty.unplug()
    scan_file = EXAMPLES / "i7241d-style.scan.json"
    source = topology(tmp_path, pty.a, scan={"addresses": "1-15", "file": str(scan_file)})
    gateway = Gateway.load(source, registry=dcon_registry)
    back_cfg = gateway.topology.backs[0]
    try:
        await gateway.start()  # no GatewayStartError
        scan = gateway.status()["backs"]["rs485"]["start_scan"]
        assert scan["error"].startswith("cannot open serial port")
        assert scan["modules_from"] == f"the scan file {scan_file}"
        addresses = [m.address for m in back_cfg.modules]
        assert addresses and scan["modules"] == [
            f"{m.model} at {m.address}" for m in back_cfg.modules
        ]
        assert gateway.health.ports_lost.keys() == {"rs485"}
        assert {c.quality for c in gateway.image.channels(back="rs485")} == {Quality.COMM_FAULT}
        # the devices' "DCON modules init error", for the fronts to show, until all answered
        assert gateway.health.back_errors["rs485"].startswith("DCON modules init error: cannot")
        simulator = dcon_registry.simulators["dcon"](back_cfg, pty.b, False)
        await simulator.start()
        try:
            pty.plug()
            await wait_until(
                lambda: all(gateway.health.get("rs485", a).online for a in addresses), 5, "online"
            )
            assert not gateway.health.ports_lost
            await wait_until(lambda: not gateway.health.back_errors, 5, "the init error ends")
            assert gateway.status()["backs"]["rs485"]["start_scan"]["resolved"] is True
        finally:
            await simulator.stop()
    finally:
        await gateway.stop()
        pty.close()


async def test_a_silent_line_keeps_the_previous_starts_modules(tmp_path, dcon_registry):
    pair = PtyPair()
    try:
        sim = DconSimulator.from_modules(pair.b, LINE)
        await sim.start()
        source = topology(tmp_path, pair.a, scan={"addresses": "1-4", "from_previous": False})
        async with Gateway.load(source, registry=dcon_registry) as first:
            first_ids = [c.id for c in first.image]
        await sim.stop()  # the modules lose power
        async with Gateway.load(source, registry=dcon_registry) as second:
            scan = second.status()["backs"]["rs485"]["start_scan"]
            assert scan["error"].startswith("modules: auto: no DCON module answered")
            assert scan["modules_from"].startswith("the previous start's scan (")
            assert [c.id for c in second.image] == first_ids  # the master's image is unchanged
            await wait_until(
                lambda: not any(h.online for h in second.health.modules("rs485")), 3, "offline"
            )
    finally:
        pair.close()


async def test_nothing_to_expect_starts_empty_and_scans_again_until_modules_answer(
    tmp_path, dcon_registry, monkeypatch, caplog
):
    monkeypatch.setattr(dcon_discovery, "RESCAN_FIRST_S", 0.1)
    monkeypatch.setattr(dcon_discovery, "RESCAN_MAX_S", 0.2)
    pair = PtyPair()
    sim = None
    try:
        async with Gateway.load(topology(tmp_path, pair.a), registry=dcon_registry) as gw:
            assert list(gw.image.channels(back="rs485")) == []
            back = gw.component("rs485")
            scan = gw.status()["backs"]["rs485"]["start_scan"]
            assert scan["modules_from"] == "nowhere (no earlier scan, no scan file)"
            await wait_until(lambda: back.scan_problem["rescans"] >= 2, 5, "two rescans")
            assert not back.scan_problem["restart_needed"]
            sim = DconSimulator.from_modules(pair.b, LINE)
            await sim.start()
            await wait_until(lambda: back.scan_problem["restart_needed"], 5, "found")
            scan = gw.status()["backs"]["rs485"]["start_scan"]
            assert scan["found_later"][0] == "I-7055 at 1"
            assert len(scan["found_later"]) == 3
        assert "restart the gateway to serve them" in caplog.text
        # the scan was recorded: the next start builds its image from the line
        async with Gateway.load(topology(tmp_path, pair.a), registry=dcon_registry) as again:
            assert len(list(again.image.channels(back="rs485"))) == 28
            assert "error" not in again.status()["backs"]["rs485"]["start_scan"]
    finally:
        if sim is not None:
            await sim.stop()
        pair.close()


@pytest.mark.parametrize(
    ("example", "front"), [("i7241d-style.yaml", "dnet"), ("i7231d-style.yaml", "can")]
)
def test_the_shipped_examples_start_without_their_serial_port(
    example, front, tmp_path, stopped_by_signal
):
    code, stderr = stopped_by_signal(
        [
            "run",
            str(EXAMPLES / example),
            "--set",
            f"fronts.{front}.interface=virtual",
            "--set",
            f"backs.rs485.port={tmp_path / 'no-such-ttyUSB0'}",
            "--set",
            f"gateway.state_dir={tmp_path / 'state'}",
            "--status-every",
            "0.2",
        ],
        "status lines",
        signal.SIGINT,
    )
    assert code == 0, stderr
    assert "cannot open serial port" in stderr and "Traceback" not in stderr
