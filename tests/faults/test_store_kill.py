"""Store under power loss, short seed-fixed version of scripts/faults/store_kill.py (docs/reliability.md).

A forked child stores CANopen 0x1010, LSS and DeviceNet settings in a loop through the
fronts' engines; it is SIGKILLed at random moments and every restart must load the old or
the new settings, never a corrupt file, never defaults once something was confirmed.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
import store_kill  # scripts/faults (see conftest)

from fieldgate import persist

KILLS = 60


def test_sixty_kills_while_storing_leave_the_old_or_the_new_settings(tmp_path):
    result = store_kill.campaign(KILLS, seed=17, state_dir=tmp_path)
    assert result.failures == []
    assert result.kills == KILLS
    assert result.stores_confirmed > KILLS  # the child got to store between kills
    assert result.kills_mid_write > 0  # some kills fell between temp file and rename
    # what the last kill left behind is cleaned by the next write of each store
    node, _ = store_kill.build(tmp_path)
    node.boot(0.0)
    node.receive(store_kill.Frame(0x600 + node.node_id, bytes.fromhex("2310100173617665")), 0.0)
    assert persist.temp_files(tmp_path / store_kill.FILES["co"]) == []


@pytest.fixture
def torn_writes(monkeypatch):
    """Stores written in place, the way a naive implementation would (mutation check)."""

    def torn(path, data, make_parents=True):
        with open(path, "wb") as f:
            f.write(data[: len(data) // 2])
            f.flush()
            f.write(data[len(data) // 2 :])

    def torn_json(path, obj):
        torn(path, json.dumps(obj).encode())

    from fieldgate.plugins.canopen.cia301 import store
    from fieldgate.plugins.canopen.cia305 import lss
    from fieldgate.plugins.devicenet import store as dn_store

    monkeypatch.setattr(store, "write_atomic", torn)
    monkeypatch.setattr(lss, "write_json_atomic", torn_json)
    monkeypatch.setattr(dn_store, "write_json_atomic", torn_json)
    logging.disable(logging.CRITICAL)
    yield
    logging.disable(logging.NOTSET)


def test_the_probe_catches_a_store_written_in_place(tmp_path, torn_writes):
    result = store_kill.campaign(40, seed=17, state_dir=Path(tmp_path))
    assert any("corrupt file" in f or "expected" in f for f in result.failures), result.as_dict()
