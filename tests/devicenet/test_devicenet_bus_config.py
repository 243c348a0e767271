"""The devicenet front's bus settings are core's (fieldgate.can.front.CanBusConfig): ``bitrate``
like every CAN front, ``baudrate`` still taken as its old spelling with a one-line note."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from fieldgate.plugin import load_registry
from fieldgate.plugins.devicenet.config import DeviceNetFrontConfig
from fieldgate.topology import load_topology

NOTE = "'baudrate' is deprecated and goes away in the next release; use 'bitrate'"


def section(**keys) -> dict:
    return {"name": "dnet", "type": "devicenet", "mac_id": 1, **keys}


def test_bitrate_is_one_of_devicenet_s_three():
    assert DeviceNetFrontConfig.model_validate(section()).bitrate == 125_000
    assert DeviceNetFrontConfig.model_validate(section(bitrate=500_000)).bitrate == 500_000
    with pytest.raises(ValidationError, match="bitrate"):
        DeviceNetFrontConfig.model_validate(section(bitrate=1_000_000))


def test_baudrate_is_taken_as_the_old_spelling_with_a_note():
    cfg = DeviceNetFrontConfig.model_validate(section(baudrate=250_000))
    assert cfg.bitrate == 250_000 and "baudrate" not in type(cfg).model_fields
    assert cfg.validation_warnings() == [NOTE]
    assert DeviceNetFrontConfig.model_validate(section(bitrate=250_000)).validation_warnings() == []


def test_both_spellings_at_once_are_refused():
    with pytest.raises(ValidationError, match="give bitrate only"):
        DeviceNetFrontConfig.model_validate(section(bitrate=250_000, baudrate=250_000))


def test_validate_prints_the_note_under_the_front(tmp_path):
    topology = {
        "gateway": {"name": "t", "state_dir": str(tmp_path)},
        "fronts": [section(interface="virtual", channel="x", baudrate=500_000)],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }
    loaded = load_topology(topology, load_registry())
    assert loaded.fronts[0].bitrate == 500_000
    assert f"    warning: {NOTE}" in loaded.summary().splitlines()
