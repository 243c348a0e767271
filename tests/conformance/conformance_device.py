"""EDS devices (the ``canopen-device`` front) as devices under test: the example battery
pack and CANopenNode's demo EDS, each on a gateway in a thread on python-can's virtual bus,
a loopback back behind it, graded with the EDS ``fieldgate eds`` writes."""

from __future__ import annotations

from pathlib import Path

from fieldgate.topology import read_yaml

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "canopen-device" / "battery.yaml"
CANOPENNODE_EDS = REPO / "tests" / "canopen" / "device" / "DS301_profile.eds"
NODE_ID = 5


def loopback_back(name: str) -> dict:
    return {
        "name": name,
        "type": "loopback",
        "modules": [{"address": 1, "digital": 8, "analog": 2}],
    }


def battery_topology(state_dir: Path, channel: str) -> dict:
    """The example as shipped, on the virtual bus; its RS-485 module is a loopback module."""
    topo = read_yaml(EXAMPLE)
    front = topo["fronts"][0]
    base = EXAMPLE.parent
    front.update(
        interface="virtual",
        channel=channel,
        node_id=NODE_ID,
        bitrate=125000,
        eds=str(base / front["eds"]),
        hooks=str(base / front["hooks"]),
    )
    topo["gateway"]["state_dir"] = str(state_dir)
    topo["backs"] = [loopback_back("bms")]
    return topo


def canopennode_topology(state_dir: Path, channel: str) -> dict:
    return {
        "gateway": {"name": "canopennode-eds", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "dev",
                "type": "canopen-device",
                "interface": "virtual",
                "channel": channel,
                "node_id": NODE_ID,
                "eds": str(CANOPENNODE_EDS),
            }
        ],
        "backs": [loopback_back("io")],
    }
