"""A topology beyond the box a style replaces validates (fieldgate serves it) with a warning that
it would not go back onto the real box (audit 000 #40: I-7232D 10 modules at 0x01-0x0F; 001 #12:
I-7231D 15 modules at 0x01-0x0F; 003 #30: I-7241D 15 DCON modules)."""

from __future__ import annotations

from fieldgate import load_registry
from fieldgate.topology import load_topology

REGISTRY = load_registry()


def warnings(front: dict, *backs: dict) -> list[str]:
    topology = {"gateway": {"name": "limits"}, "fronts": [front], "backs": list(backs)}
    notes = load_topology(topology, REGISTRY).warnings()
    return [n for n in notes if n.startswith("front ")]  # (not the line's timing notes)


CANOPEN = {"name": "can", "type": "canopen", "interface": "virtual", "channel": "x", "node_id": 3}


def modbus(addresses: list[int]) -> dict:
    return {
        "name": "rs485",
        "type": "modbus",
        "port": "/dev/ttyUSB0",
        "modules": [{"address": a, "model": "M-7052D"} for a in addresses],
    }


def dcon(count: int) -> dict:
    return {
        "name": "rs485",
        "type": "dcon",
        "port": "/dev/ttyUSB0",
        "modules": [{"address": a, "model": "I-7053"} for a in range(1, count + 1)],
    }


def test_an_i7232d_topology_within_its_limits_has_no_warning():
    assert warnings(CANOPEN, modbus(list(range(1, 11)))) == []


def test_an_i7232d_topology_past_its_limits_validates_with_warnings():
    notes = warnings(CANOPEN, modbus([*range(1, 11), 20]))
    assert notes == [
        "front can: back rs485 has 11 modules; the I-7232D holds at most 10: fieldgate serves "
        "them, the topology would not go back onto an I-7232D",
        "front can: back rs485 has modules at 20; the I-7232D takes RS-485 addresses 1..15 "
        "only: fieldgate serves them, the topology would not go back onto an I-7232D",
    ]


def test_the_i7231d_takes_15_dcon_modules_and_the_na9161_style_has_no_such_note():
    assert warnings(CANOPEN, dcon(15)) == []
    assert "the I-7231D holds at most 15" in warnings(CANOPEN, dcon(16))[0]
    assert warnings({**CANOPEN, "style": "na9161"}, modbus([1, 20])) == []


def test_the_i7241d_takes_15_dcon_modules():
    front = {
        "name": "dnet",
        "type": "devicenet",
        "interface": "virtual",
        "channel": "x",
        "mac_id": 1,
    }
    assert warnings(front, dcon(15)) == []
    (note,) = warnings(front, dcon(16))
    assert "16 DCON modules; the I-7241D holds at most 15" in note


def test_a_front_that_does_not_serve_the_back_says_nothing():
    other = {**modbus([1]), "name": "other", "port": "/dev/ttyUSB1"}
    assert warnings({**CANOPEN, "expose": ["other/*"]}, modbus([20]), other) == []
