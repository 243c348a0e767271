"""The sparkplug section of a topology, the one-writer rule, the examples, the schema module."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate import load_registry
from fieldgate.plugins.sparkplug.config import BrokerSettings
from fieldgate.topology import TopologyError, load_topology

REGISTRY = load_registry()
ROOT = Path(__file__).parent.parent.parent
PACKAGE = ROOT / "plugins" / "sparkplug"


def topology(**front: object) -> dict:
    return {
        "gateway": {"name": "gw"},
        "fronts": [
            {
                "name": "spb",
                "type": "sparkplug",
                "group_id": "g",
                "brokers": [{"host": "127.0.0.1"}],
                **front,
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 2}]}],
    }


def test_data_qos_1_is_valid_but_validate_says_it_is_not_sparkplug_conformant():
    front = load_topology(topology(data_qos=1), REGISTRY).fronts[0]
    (warning,) = front.validation_warnings()
    assert "at-least-once" in warning and "tck-id-payloads-ddata-qos" in warning
    assert "not Sparkplug B 3.0 conformant" in warning


def errors(data: dict) -> list[str]:
    with pytest.raises(TopologyError) as info:
        load_topology(data, REGISTRY)
    return [f"{i.path}: {i.message}" for i in info.value.issues]


def test_a_minimal_front_validates_with_defaults():
    topo = load_topology(topology(), REGISTRY)
    front = topo.fronts[0]
    assert front.edge_node_id is None and front.data_qos == 0 and front.writable == []
    assert front.validation_warnings() == []  # the defaults are Sparkplug 3.0 conformant
    assert (
        front.brokers[0].effective_port == 1883
        and front.brokers[0].label == "mqtt://127.0.0.1:1883"
    )
    tls = load_topology(topology(brokers=[{"host": "b", "tls": {}}]), REGISTRY).fronts[0].brokers[0]
    assert tls.label == "mqtts://b:8883"


@pytest.mark.parametrize(
    "front, expected",
    [
        ({"group_id": "a/b"}, "fronts[0].group_id"),
        ({"edge_node_id": "e+"}, "fronts[0].edge_node_id"),
        ({"brokers": []}, "fronts[0].brokers"),
        ({"brokers": [{"host": "h", "password_env": "X"}]}, "a password needs a username"),
        (
            {
                "brokers": [
                    {"host": "h", "username": "u", "password_env": "X", "password_file": "f"}
                ]
            },
            "not both",
        ),
        (
            {"brokers": [{"host": "h", "tls": {"cert_file": "c"}}]},
            "cert_file and key_file go together",
        ),
        ({"brokers": [{"host": "h"}, {"host": "h", "port": 1883}]}, "listed twice"),
        ({"reconnect_min_s": 5, "reconnect_max_s": 1}, "reconnect_max_s"),
        ({"password": "x"}, "fronts[0].password"),  # no secrets in the YAML: unknown key
    ],
)
def test_bad_settings_are_reported_at_their_field(front, expected):
    assert any(expected in e for e in errors(topology(**front))), errors(topology(**front))


def test_passwords_come_from_a_file_or_the_environment(tmp_path, monkeypatch):
    (tmp_path / "pw").write_text("s3cret\n")
    broker = BrokerSettings(host="h", username="u", password_file="pw")
    assert broker.password(tmp_path) == "s3cret"
    monkeypatch.setenv("FG_PW", "env-secret")
    assert (
        BrokerSettings(host="h", username="u", password_env="FG_PW").password(tmp_path)
        == "env-secret"
    )
    monkeypatch.delenv("FG_PW")
    with pytest.raises(ValueError, match="FG_PW is not set"):
        BrokerSettings(host="h", username="u", password_env="FG_PW").password(tmp_path)
    with pytest.raises(ValueError, match="password_file") as info:
        BrokerSettings(host="h", username="u", password_file="nope").password(tmp_path)
    assert "s3cret" not in str(info.value)


def test_a_second_writer_of_an_output_is_an_error_naming_both_fronts():
    data = topology(writable=["io/m1/do*"])
    data["fronts"].append({"name": "plc", "type": "memory"})  # serves (and writes) every output
    (message,) = errors(data)
    assert message.startswith("fronts[1]")
    assert (
        "output io/m1/do0 and 1 more would be written by front 'plc' and by front 'spb'" in message
    )
    data["fronts"][1]["expose"] = ["io/m1/di*", "io/m1/do1"]
    (message,) = errors(data)
    assert "output io/m1/do1 would be written by front 'plc' and by front 'spb'" in message
    data["fronts"][0]["writable"] = ["io/m1/do0"]
    assert load_topology(data, REGISTRY).fronts[0].writable == ["io/m1/do0"]


def test_a_writable_pattern_must_match_an_output():
    (message,) = errors(topology(writable=["io/m1/di0"]))
    assert message.startswith("fronts[0].writable[0]: 'io/m1/di0' matches no output channel")


def test_a_front_that_writes_nothing_shares_every_output():
    data = topology()  # sparkplug without writable: it only reads
    data["fronts"].append({"name": "plc", "type": "memory"})
    assert len(load_topology(data, REGISTRY).fronts) == 2


@pytest.mark.parametrize("name", ["sparkplug-modbus", "canopen-sparkplug"])
def test_the_sparkplug_examples_validate(name):
    topo = load_topology(ROOT / "examples" / f"{name}.yaml", REGISTRY)
    assert any(f.type == "sparkplug" for f in topo.fronts)
    assert any(f.writable for f in topo.fronts if f.type == "sparkplug")


def test_the_committed_schema_module_is_what_protoc_makes_of_the_proto(tmp_path):
    subprocess.run(
        [
            sys.executable,
            "-m",
            "grpc_tools.protoc",
            f"--proto_path={PACKAGE}",
            f"--python_out={tmp_path}",
            str(PACKAGE / "sparkplug_b.proto"),
        ],
        check=True,
    )
    assert (tmp_path / "sparkplug_b_pb2.py").read_text() == (
        PACKAGE / "sparkplug_b_pb2.py"
    ).read_text()


async def test_status_and_metric_rows_follow_the_metrics_contract(tmp_path):
    from fieldgate.runtime import Gateway

    data = topology(brokers=[{"host": "127.0.0.1", "port": 1}])  # nothing listens: disconnected
    data["gateway"]["state_dir"] = str(tmp_path)
    async with Gateway.load(data) as gw:
        gw.write("io/m1/do0", True)  # changes while disconnected go to the journal
        front = gw.component("spb")
        for _ in range(1500):  # the front's child reports its status once a second
            await asyncio.sleep(0.01)
            if front.status().get("backlog_messages", 0) >= 2:
                break
        status = gw.status()["fronts"]["spb"]
        rows = front.metrics()
    assert status["state"] in ("disconnected", "connecting")
    assert status["backlog_messages"] >= 2 and status["backlog_oldest_age_s"] >= 0
    assert status["dropped_messages"] == 0
    by_name = {}
    for name, kind, help_text, value, labels in rows:
        assert not name.startswith("fieldgate_") and help_text and isinstance(value, float)
        assert kind in ("counter", "gauge")
        assert name.endswith("_total") == (kind == "counter"), name
        assert labels["front"] == "spb"
        by_name[name] = value
    assert by_name["sparkplug_backlog_messages"] == status["backlog_messages"]
    assert by_name["sparkplug_dropped_messages_total"] == 0
    assert by_name["sparkplug_connected"] == 0
    assert "sparkplug_backlog_oldest_age_seconds" in by_name


def test_the_configuration_sample_in_the_docs_validates(tmp_path):
    """docs/sparkplug.md's configuration block, with the Modbus line it refers to, loads."""
    doc = (ROOT / "docs" / "sparkplug.md").read_text()
    sample = doc.split("## Configuration", 1)[1].split("```yaml\n", 1)[1].split("```", 1)[0]
    text = (
        "gateway: {name: line3}\n"
        + sample
        + "backs:\n  - name: rs485\n    type: modbus\n    port: /dev/ttyUSB0\n    modules:\n"
        "      - {address: 3, model: M-7055D, counts: {di: 0}}\n      - {address: 5, model: M-7017R}\n"
    )
    path = tmp_path / "doc.yaml"
    path.write_text(text)
    front = load_topology(path, REGISTRY).fronts[0]
    assert front.brokers[0].tls is not None and front.brokers[0].password_file
    assert front.writable == ["rs485/m3/do*"]
