"""The CANopen front's topology fields that the plugin checks itself."""

from __future__ import annotations

import pytest

from fieldgate import load_registry
from fieldgate.topology import TopologyError, load_topology

REGISTRY = load_registry()


def topology(tmp_path, front: str):
    path = tmp_path / "t.yaml"
    path.write_text(
        "gateway: {name: t}\n"
        f"fronts:\n  - {{name: plc, type: canopen, interface: virtual, channel: x, node_id: 5, {front}}}\n"
        "backs:\n  - {name: io, type: loopback, modules: [{address: 1, digital: 8}]}\n"
    )
    return path


@pytest.mark.parametrize("bitrate", [10_000, 100_000, 125_000, 800_000, 1_000_000])
def test_every_cia_bitrate_is_accepted(tmp_path, bitrate):
    assert (
        load_topology(topology(tmp_path, f"bitrate: {bitrate}"), REGISTRY).fronts[0].bitrate
        == bitrate
    )


def test_null_leaves_the_bitrate_to_the_interface(tmp_path):
    assert load_topology(topology(tmp_path, "bitrate: null"), REGISTRY).fronts[0].bitrate is None


@pytest.mark.parametrize("bitrate", [250_001, 83_333, 0, -125_000])
def test_other_bitrates_are_refused_with_the_list(tmp_path, bitrate):
    with pytest.raises(TopologyError) as err:
        load_topology(topology(tmp_path, f"bitrate: {bitrate}"), REGISTRY)
    (issue,) = err.value.issues
    assert issue.line == 3 and "bitrate" in str(issue)
    assert issue.message.startswith("expected one of")  # no "Value error, " from pydantic
    assert (
        "expected one of the CiA 301 bit rates 10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000"
        in issue.message
    )
