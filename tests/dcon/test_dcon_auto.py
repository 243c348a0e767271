"""``modules: auto``: the DCON back finds its modules on the line when it starts, whichever
front serves them; scan files stand in for the line (validate, EDS, --simulate).

The line is a simulator on a pseudo-terminal pair that outlives the gateways (the port is
its other end), so a test can change the modules between two starts as a user would.
"""

from __future__ import annotations

import json
import logging
import uuid
from pathlib import Path

import pytest

from fieldgate import Gateway
from fieldgate.cli import main as cli_main
from fieldgate.plugins.dcon.scanfile import ScanFile, ScannedModule, differences
from fieldgate.plugins.dcon.simulator import DconSimulator
from fieldgate.runtime import GatewayStartError
from fieldgate.serial_link import PtyPair
from fieldgate.topology import TopologyError, load_topology

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
LINE = [(1, "I-7055"), (2, "I-7017", 0x08, "hex"), (3, "I-7024", 0x33, "hex")]


def topology(tmp_path: Path, port: str, front: dict | None = None, **back) -> dict:
    return {
        "gateway": {"name": "auto", "state_dir": str(tmp_path / "state")},
        "fronts": [front or {"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": port,
                "timeout_ms": 60,
                "poll_ms": 10,
                "modules": "auto",
                **back,
            }
        ],
    }


@pytest.fixture
async def line():
    """A pty pair: the gateway's port, and simulated modules on the other end (``line.sim``)."""
    pair = PtyPair()
    pair.sim = None

    async def serve(modules, **options):
        if pair.sim is not None:
            await pair.sim.stop()
        pair.sim = DconSimulator.from_modules(pair.b, modules, **options)
        await pair.sim.start()
        return pair.sim

    pair.serve = serve
    yield pair
    if pair.sim is not None:
        await pair.sim.stop()
    pair.close()


async def test_the_back_builds_its_modules_from_the_line_and_the_image_is_stable(
    tmp_path, line, dcon_registry, caplog
):
    await line.serve(LINE)
    source = topology(tmp_path, line.a, scan={"from_previous": False})  # probe at every start
    async with Gateway.load(source, registry=dcon_registry) as gw:
        ids = [c.id for c in gw.image]
        assert len(ids) == 28 and "rs485/m2/ai7" in ids and "rs485/m3/ao3" in ids
        assert [h.address for h in gw.health.modules()] == [1, 2, 3]
        scan = gw.status()["backs"]["rs485"]["start_scan"]
        assert scan["modules"] == [
            "I-7055 at 1",
            "I-7017 at 2 (type 0x08 +/-10 V, hex)",
            "I-7024 at 3 (type 0x33 +/-10 V, hex)",
        ]
        assert scan["changed_since_last_start"] == [] and scan["left_out"] == []
        assert gw.image["rs485/m2/ai0"].spec.scaling is not None  # the reported type code's range
        line.sim.set_input("rs485/m1/di3", True)
        for _ in range(100):
            if gw.read("rs485/m1/di3"):
                break
            await _sleep(0.02)
        assert gw.read("rs485/m1/di3") is True  # polled like listed modules
    recorded = ScanFile.read(tmp_path / "state" / "rs485.dcon-scan.json")
    assert [m.model for m in recorded.modules] == ["I-7055", "I-7017", "I-7024"]
    caplog.clear()
    async with Gateway.load(source, registry=dcon_registry) as again:  # the same line
        assert [c.id for c in again.image] == ids
    assert "the line changed" not in caplog.text
    await line.serve(LINE[:2] + [(4, "I-7053")])  # I-7024 gone, I-7053 added
    with caplog.at_level(logging.WARNING):
        async with Gateway.load(source, registry=dcon_registry) as changed:
            scan = changed.status()["backs"]["rs485"]["start_scan"]
            assert scan["changed_since_last_start"] == [
                "I-7024 at 3 (type 0x33 +/-10 V, hex) is missing",
                "I-7053 at 4 is new",
            ]
            assert "rs485/m4/di15" in changed.image and "rs485/m3/ao0" not in changed.image
    assert "the line changed since the last start, so did the image" in caplog.text


async def test_nothing_answering_is_one_line_and_other_settings_are_tried(
    tmp_path, line, dcon_registry, caplog
):
    await line.serve(LINE, checksum=True)
    # nothing answers at the line's setting: the gateway starts anyway and says why in one
    # line (tests/dcon/test_dcon_auto_no_line.py: what it does next)
    async with Gateway.load(topology(tmp_path, line.a), registry=dcon_registry) as gw:
        message = gw.status()["backs"]["rs485"]["start_scan"]["error"]
    assert "\n" not in message and message.startswith("modules: auto:")
    assert "no DCON module answered" in message and "9600 bit/s checksum off" in message
    # the settings the topology allows are tried in order: the line runs at the one that answered
    allowed = topology(tmp_path, line.a, scan={"checksums": [False, True], "addresses": "1-4"})
    async with Gateway.load(allowed, registry=dcon_registry) as gw:
        status = gw.status()["backs"]["rs485"]
        assert (
            status["start_scan"]["checksum"] is True and len(status["start_scan"]["modules"]) == 3
        )
        assert gw.component("rs485").config.checksum is True


async def test_modules_at_another_setting_or_unsupported_are_left_out_with_a_warning(
    tmp_path, line, dcon_registry, caplog
):
    sim = await line.serve(LINE)
    sim.module(2).checksum = True  # this one alone expects checksums
    sim.module(3).name = "7099"  # a model fieldgate does not know
    allowed = topology(tmp_path, line.a, scan={"checksums": [False, True], "addresses": "1-4"})
    with caplog.at_level(logging.WARNING):
        async with Gateway.load(allowed, registry=dcon_registry) as gw:
            scan = gw.status()["backs"]["rs485"]["start_scan"]
            assert scan["modules"] == ["I-7055 at 1", "unsupported '7099' at 3"]
            assert [c.source.module for c in gw.image] == [1] * 16
    assert scan["left_out"][0].startswith(
        "I-7017 at 2 (type 0x08 +/-10 V, hex) answers at 9600 bit/s checksum on"
    )
    assert "'7099', a model fieldgate does not support: left out" in scan["left_out"][1]
    assert "left out" in caplog.text


async def test_listed_modules_keep_working_and_a_line_that_differs_is_a_warning(
    tmp_path, line, dcon_registry, caplog
):
    await line.serve(LINE + [(5, "I-7053")])
    listed = topology(
        tmp_path,
        line.a,
        modules=[{"address": 1, "model": "I-7055"}, {"address": 2, "model": "I-7018"}],
        scan={"addresses": "1-5", "survey": True},  # the other three, one a second
    )
    with caplog.at_level(logging.WARNING):
        async with Gateway.load(listed, registry=dcon_registry) as gw:
            back = gw.component("rs485")
            for _ in range(400):
                if back.survey_done:
                    break
                await _sleep(0.02)
            assert back.survey_done
            assert [c.source.module for c in gw.image if c.kind.value == "di"] == [1] * 8
            survey = gw.status()["backs"]["rs485"]["survey"]
    assert survey == ["I-7024 at 3 (type 0x33 +/-10 V, hex)", "I-7053 at 5"]
    assert "answer but are not in the topology: I-7024 at 3" in caplog.text
    assert "$AAM says '7017', topology says I-7018" in caplog.text


async def test_the_survey_waits_while_a_host_watchdog_is_on(tmp_path, line, dcon_registry):
    """An empty address holds the line for a reply timeout and its silence: longer than the
    keep-alive of a 300 ms watchdog may wait, so no probe then (modules would go safe)."""
    await line.serve(LINE)
    listed = topology(
        tmp_path,
        line.a,
        modules=[{"address": 1, "model": "I-7055", "watchdog": {"timeout_ms": 300}}],
        scan={"addresses": "1-3", "survey": True},
    )
    async with Gateway.load(listed, registry=dcon_registry) as gw:
        back = gw.component("rs485")
        await _sleep(2.5)
        assert back._survey_left == [2, 3] and not back.survey_done
        assert not line.sim.module(1).timed_out and back.host_ok_sent > 5


async def test_the_canopen_front_builds_its_objects_on_the_found_modules(
    tmp_path, line, dcon_registry
):
    """The I-7231D example, its module list replaced by modules: auto: the OD follows the line."""
    await line.serve([(1, "I-7043"), (2, "I-7053"), (3, "I-7021"), (4, "I-7012")])
    channel = f"auto-co-{uuid.uuid4().hex[:8]}"
    overrides = {
        "backs.rs485.modules": "auto",
        "backs.rs485.port": line.a,
        "backs.rs485.timeout_ms": 60,
        "fronts.can.channel": channel,
        "gateway.state_dir": str(tmp_path),
    }
    async with Gateway.load(EXAMPLES / "i7231d-style.yaml", overrides, dcon_registry) as gw:
        od = gw.component("can").node.od
        assert od.get(0x6000, 0) == 3 and od.get(0x6200, 0) == 3  # the seed's PDO demo
        assert od.get(0x6401, 0) == 1 and od.get(0x6411, 0) == 1


def test_scan_files_are_checked_and_feed_validate_and_both_eds_generators(
    tmp_path, dcon_registry, capsys
):
    shipped = EXAMPLES / "i7241d-style.scan.json"
    source = tmp_path / "topo.yaml"
    source.write_text(
        json.dumps(
            topology(tmp_path, "/dev/ttyUSB9", {"name": "dnet", "type": "devicenet", "mac_id": 1})
        )
    )
    assert cli_main(["validate", str(source), "--scan-file", str(shipped)]) == 0
    out = capsys.readouterr().out
    assert "3 module(s), 28 channel(s)" in out and "scan file" in out
    eds = tmp_path / "dnet.eds"
    assert (
        cli_main(
            ["devicenet", "eds", str(source), "--scan-file", f"rs485={shipped}", "-o", str(eds)]
        )
        == 0
    )
    assert '"20 04 24 69 30 03"' in eds.read_text() and "17," in eds.read_text()
    co = topology(
        tmp_path,
        "/dev/ttyUSB9",
        {"name": "can", "type": "canopen", "interface": "virtual", "node_id": 3},
        scan={"file": str(shipped)},
    )
    (tmp_path / "co.yaml").write_text(json.dumps(co))
    assert cli_main(["eds", str(tmp_path / "co.yaml"), "-o", str(tmp_path / "co.eds")]) == 0
    assert "[6401sub8]" in (tmp_path / "co.eds").read_text()  # the I-7017's 8 AI
    for text, message in (
        ("{", "not JSON"),
        ('{"format": "other"}', "not a DCON scan file"),
        (
            '{"format": "fieldgate-dcon-scan/1", "modules": [{"address": 1, "model": "I-9999"}]}',
            "unknown DCON module 'I-9999'",
        ),
        (
            '{"format": "fieldgate-dcon-scan/1", "modules": [{"address": 1}, {"address": 1}]}',
            "address 1 appears twice",
        ),
    ):
        bad = tmp_path / "bad.json"
        bad.write_text(text)
        with pytest.raises(TopologyError) as err:
            load_topology(topology(tmp_path, "/dev/x", scan={"file": str(bad)}), dcon_registry)
        (issue,) = err.value.issues
        assert issue.path == "backs[0].scan.file" and message in issue.message, issue
    with pytest.raises(TopologyError) as err:
        load_topology(topology(tmp_path, "/dev/x", modules=[]), dcon_registry)
    assert "give at least one module, or modules: auto" in str(err.value.issues[0])
    # without a scan file the channel ids come at start: a front's expose on them is not refused,
    # one on another back still is
    front = {"name": "plc", "type": "memory", "expose": ["rs485/m1/*"]}
    assert load_topology(topology(tmp_path, "/dev/x", front), dcon_registry).channel_specs == []
    front["expose"] = ["other/m1/*"]
    with pytest.raises(TopologyError, match="matches no channel"):
        load_topology(topology(tmp_path, "/dev/x", front), dcon_registry)


async def test_simulate_serves_the_scan_files_modules_and_needs_one(tmp_path, dcon_registry):
    with pytest.raises(GatewayStartError) as err:
        await Gateway.load(
            topology(tmp_path, "/dev/x"), registry=dcon_registry, simulate=True
        ).start()
    assert "modules: auto can be simulated only from a scan file" in str(err.value)
    source = topology(tmp_path, "/dev/x", scan={"file": str(EXAMPLES / "i7241d-style.scan.json")})
    async with Gateway.load(source, registry=dcon_registry, simulate=True) as gw:
        assert len(gw.status()["backs"]["rs485"]["start_scan"]["modules"]) == 3
        assert len(list(gw.image)) == 28


def test_differences_name_each_module():
    a = ScannedModule(1, 9600, False, "7055", model="I-7055")
    b = ScannedModule(2, 9600, False, "7017", model="I-7017", type_code=8, data_format="hex")
    c = ScannedModule(2, 9600, False, "7017", model="I-7017", type_code=9, data_format="hex")
    assert differences([a, b], [a, b]) == []
    assert differences([a, b], [a, c]) == [
        "I-7017 at 2 (type 0x08 +/-10 V, hex) is now I-7017 at 2 (type 0x09 +/-5 V, hex)"
    ]
    assert differences([a], []) == ["I-7055 at 1 is missing"]


async def _sleep(seconds: float) -> None:
    import asyncio

    await asyncio.sleep(seconds)


async def _until(check, seconds: float, what: str) -> None:
    for _ in range(int(seconds / 0.02)):
        if check():
            return
        await _sleep(0.02)
    raise AssertionError(f"not within {seconds} s: {what}")


def _scan_of(gw) -> dict:
    return gw.status()["backs"]["rs485"]["start_scan"]


async def test_a_start_takes_the_previous_scan_at_once_and_verifies_the_line_after(
    tmp_path, line, dcon_registry, caplog
):
    """scan.from_previous (the default): the first start probes the line; the next ones build
    the image from the previous start's scan before touching the line, so READY and the
    fieldbus boot-up do not wait for the scan (issue 33), and verify the line in the
    background: a changed line is recorded and logged (a restart serves it)."""
    await line.serve(LINE)
    source = topology(tmp_path, line.a)
    async with Gateway.load(source, registry=dcon_registry) as first:
        assert "from_previous" not in _scan_of(first)  # nothing recorded yet: probed
        ids = [c.id for c in first.image]
    record = tmp_path / "state" / "rs485.dcon-scan.json"
    async with Gateway.load(source, registry=dcon_registry) as same:
        assert _scan_of(same)["from_previous"] == str(record)
        assert [c.id for c in same.image] == ids
        await _until(lambda: _scan_of(same)["verified"] == "same", 5, "verified")
        assert _scan_of(same)["changed_since_last_start"] == []
        await _until(lambda: all(h.online for h in same.health.modules()), 3, "online")
        assert not same.health.back_errors

    await line.serve(LINE[:2] + [(4, "I-7053")])  # I-7024 gone, I-7053 added
    with caplog.at_level(logging.WARNING):
        async with Gateway.load(source, registry=dcon_registry) as changed:
            assert [c.id for c in changed.image] == ids  # the previous image, at once
            await _until(lambda: _scan_of(changed)["verified"] == "changed", 5, "verified")
            assert _scan_of(changed)["changed_since_last_start"] == [
                "I-7024 at 3 (type 0x33 +/-10 V, hex) is missing",
                "I-7053 at 4 is new",
            ]
    assert "restart the gateway to serve the line as it is now" in caplog.text
    assert [m.model for m in ScanFile.read(record).modules] == ["I-7055", "I-7017", "I-7053"]
    async with Gateway.load(source, registry=dcon_registry) as restarted:
        assert "rs485/m4/di15" in restarted.image and "rs485/m3/ao0" not in restarted.image


async def test_a_silent_line_at_a_start_from_the_previous_scan_is_the_init_error(
    tmp_path, line, dcon_registry
):
    await line.serve(LINE)
    source = topology(tmp_path, line.a)
    async with Gateway.load(source, registry=dcon_registry) as first:
        ids = [c.id for c in first.image]
    await line.sim.stop()  # the modules lose power
    line.sim = None
    async with Gateway.load(source, registry=dcon_registry) as silent:
        # a probe first would have found nothing: the start took the previous scan
        assert _scan_of(silent)["from_previous"] and [c.id for c in silent.image] == ids
        await _until(lambda: _scan_of(silent)["verified"] == "silent", 8, "verified")
        assert silent.health.back_errors["rs485"].startswith(
            "DCON modules init error: modules: auto: no DCON module answered"
        )
        assert not any(h.online for h in silent.health.modules("rs485"))
    recorded = ScanFile.read(tmp_path / "state" / "rs485.dcon-scan.json")
    assert [m.model for m in recorded.modules] == ["I-7055", "I-7017", "I-7024"]  # kept


async def test_other_scan_settings_or_from_previous_false_probe_first(
    tmp_path, line, dcon_registry
):
    await line.serve(LINE)
    async with Gateway.load(topology(tmp_path, line.a), registry=dcon_registry):
        pass
    for scan in ({"addresses": "1-3"}, {"from_previous": False}):
        async with Gateway.load(
            topology(tmp_path, line.a, scan=scan), registry=dcon_registry
        ) as gw:
            assert "from_previous" not in _scan_of(gw)
            assert len([c.id for c in gw.image]) == 28
