"""Every wire fuzzed, short seed-fixed version of scripts/faults/fuzz.py (docs/reliability.md).

Each target feeds its inputs to a real engine (the fronts' CANopen node and DeviceNet
slave as ``fieldgate run`` builds them, the backs' Modbus and DCON link and module code,
the Modbus TCP front's server in memory and on a socket, the topology loader) and checks
after every input that it still answers a valid request.
"""

from __future__ import annotations

import time

import fuzz  # scripts/faults (see conftest)
import pytest
from fuzz_targets import TARGETS, Bytes, Target

from fieldgate import load_registry

CI_INPUTS = {name: 5000 for name in TARGETS} | {
    "yaml": 300,
    "opcua": 2000,
    "modbus_tcp": 2500,
    "modbus_tcp_socket": 400,
}


@pytest.fixture(scope="module")
def registry():
    return load_registry()


@pytest.mark.parametrize("name", list(TARGETS))
def test_wire_survives_its_fuzz_inputs(name, registry, tmp_path):
    target = TARGETS[name](tmp_path, registry)
    try:
        report = fuzz.fuzz(target, CI_INPUTS[name], seed=2026)
    finally:
        target.close()
    assert report.examples == []
    assert (report.crashes, report.hangs, report.invariant_failures) == (0, 0, 0)
    assert report.inputs == CI_INPUTS[name]
    if name == "opcua":
        opcua_inputs_reach_deep(target)


def test_the_inputs_reach_deep_into_the_engines(registry, tmp_path):
    """Structure-aware inputs: transfers complete, LSS answers, explicit requests are served,
    replies reach the decoders (the fuzzer does not stop at the first byte)."""
    sdo = TARGETS["sdo"](tmp_path / "sdo", registry)
    fuzz.fuzz(sdo, 1000, seed=7)
    assert sdo.node.service("sdo").counters["transfers"] > 10
    lss = TARGETS["nmt_lss"](tmp_path / "lss", registry)
    fuzz.fuzz(lss, 1000, seed=7)
    assert lss.node.service("lss").status()["answered"] > 10
    dnet = TARGETS["devicenet"](tmp_path / "dnet", registry)
    fuzz.fuzz(dnet, 1000, seed=7)
    assert dnet.slave.counters["cip_errors"] > 10
    modbus = TARGETS["modbus"](tmp_path / "modbus", registry)
    fuzz.fuzz(modbus, 1000, seed=7)
    errors = modbus.link.stats.errors
    assert errors["garbage"] > 10 and errors["crc"] > 0 and errors["timeout"] > 0


def opcua_inputs_reach_deep(target: Target) -> None:
    """The OPC UA server's fuzz inputs are acknowledged, open secure channels, and meet each
    of the framing's refusals (not only the first-byte one)."""
    answers, rejected = target.answers, target.guard.rejected  # type: ignore[attr-defined]
    assert answers["ACK"] > 100 and answers["OPN"] > 10 and answers["ERR"] > 100, answers
    for reason in (
        "not_hello_first",
        "hello_invalid",
        "endpoint_url_invalid",
        "message_type_invalid",
        "chunk_too_large",
        "decoding_error",
    ):
        assert rejected[reason] > 0, (reason, dict(rejected))


class Planted(Target):
    """A target with a bug to find: proves the runner counts what the real targets must not do."""

    name = "planted"

    def setup(self) -> None:
        self.broken = False

    def run(self, data: bytes) -> None:
        first = Bytes(data).u8()
        if first == 0x13:
            raise KeyError("a bug")
        if first == 0x42:
            time.sleep(5)  # a hang: only the runner's alarm ends it
        self.broken = first == 0x77

    def check(self) -> None:
        if self.broken:
            raise fuzz.InvariantBroken("no longer answers")


def test_the_runner_counts_crashes_hangs_and_broken_invariants(tmp_path):
    report = fuzz.fuzz(Planted(tmp_path), 1500, seed=3, hang_s=0.05)
    assert report.crashes > 0 and report.hangs > 0 and report.invariant_failures > 0
    assert any("KeyError" in e for e in report.examples)
    assert not report.ok
