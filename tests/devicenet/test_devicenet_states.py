"""The node's network state is an enum with a transition table (plugins/devicenet/slave_state.py):
every state has its way out, the engine moves only along the table, and the status shows the
states by their names."""

from __future__ import annotations

import json

import pytest
from dnet_rig import Rig

from fieldgate.plugins.devicenet.slave_state import TRANSITIONS, DeviceState


def test_every_state_has_a_row_and_a_way_back_to_the_check():
    assert set(TRANSITIONS) == set(DeviceState)
    assert all(DeviceState.DUP_MAC_CHECK in targets for targets in TRANSITIONS.values())
    assert DeviceState.OFFLINE not in set().union(*TRANSITIONS.values())  # no way back to it


def test_the_engine_moves_along_the_table_and_refuses_the_rest():
    rig = Rig(online=False)
    assert rig.slave.state is DeviceState.DUP_MAC_CHECK
    rig.send("44F 80 34 12 07 00 00 00")  # a response to our check: a duplicate
    assert rig.slave.state is DeviceState.COMM_FAULT
    with pytest.raises(ValueError, match="comm-fault cannot go to online"):
        rig.slave.move_to(DeviceState.ONLINE)
    assert rig.slave.state is DeviceState.COMM_FAULT


def test_the_status_shows_the_state_by_its_name():
    rig = Rig()
    status = json.loads(json.dumps(rig.slave.status()))
    assert status["state"] == "online" == DeviceState.ONLINE
