"""The Modbus TCP server's fuzz targets (issue 29; scripts/faults/fuzz_mbtcp.py,
docs/reliability.md): in memory (admission, timers and framing, the clock moved by the
inputs) and over real TCP to a gateway on uvloop. Their seed-fixed clean runs are in
test_fuzz_wires.py; here, that the inputs reach every path and that the oracle finds the
defects it is for (issue 29's D5 and D6, a desynchronised answer)."""

from __future__ import annotations

import fuzz  # scripts/faults (see conftest)
import pytest
from fuzz_mbtcp import ModbusTcpSocketTarget, ModbusTcpTarget

from fieldgate import load_registry
from fieldgate.plugins.modbus_tcp import front as front_module
from fieldgate.plugins.modbus_tcp import mbap


@pytest.fixture(scope="module")
def registry():
    return load_registry()


def test_the_inputs_reach_every_path_of_the_server(registry, tmp_path):
    """Reads, writes, each exception, each way a connection is closed (the clean runs
    themselves are in test_fuzz_wires.py, with every other wire)."""
    target = ModbusTcpTarget(tmp_path, registry)
    fuzz.fuzz(target, 1000, seed=7)
    counters = target.server.counters
    assert counters["reads"] > 1000 and counters["writes"] > 10
    for key in ("exception_01", "exception_02", "exception_03", "exception_0b"):
        assert counters[key] > 5, key
    for key in ("closed_malformed", "closed_evicted", "closed_idle_timeout", "pipeline_full"):
        assert counters[key] > 0, key
    sock = ModbusTcpSocketTarget(tmp_path / "socket", registry)
    try:
        fuzz.fuzz(sock, 200, seed=7)
        counters = sock.counters()
    finally:
        sock.close()
    assert counters["reads"] > 200 and counters["closed_malformed"] > 2


def echo_unknown_codes(original):
    """pymodbus's way with FC 8 (D6): the request echoed."""

    def handle(self, frame):
        if frame.pdu[0] == 8:
            return frame.pdu
        return original(self, frame)

    return handle


def keep_any_protocol_id(original):
    """D5: a header with a protocol id other than 0 taken as a request."""

    def parse(self, now):
        if self._fill >= 4 and self._buffer[2:4] != b"\0\0":
            self._buffer[2:4] = b"\0\0"
        return original(self, now)

    return parse


def wrong_transaction_id(original):
    """A desynchronised answer: another transaction id."""

    def answer(frame, pdu):
        data = bytearray(original(frame, pdu))
        if frame.tid % 7 == 3:
            data[1] ^= 1
        return bytes(data)

    return answer


@pytest.mark.parametrize(
    ("where", "name", "plant"),
    [
        (front_module.ModbusTcpFront, "handle", echo_unknown_codes),
        (mbap.MbapConnection, "_parse", keep_any_protocol_id),
        ("fieldgate.plugins.modbus_tcp.server", "answer", wrong_transaction_id),
    ],
    ids=["D6-echo", "D5-protocol-id", "desync"],
)
def test_the_oracle_finds_the_defects_it_is_for(
    where, name, plant, registry, tmp_path, monkeypatch
):
    if isinstance(where, str):
        import importlib

        where = importlib.import_module(where)
    monkeypatch.setattr(where, name, plant(getattr(where, name)))
    report = fuzz.fuzz(ModbusTcpTarget(tmp_path, registry), 1000, seed=2026)
    assert report.invariant_failures > 0, report.as_dict()
