"""64-bit integers, doubles and text as Sparkplug metrics, and engineering units (a value the back
scaled) as BIRTH properties, decoded by the tests' own codec; DCMDs of those types."""

from __future__ import annotations

import random

from fieldgate.image import ChannelSpec, DataType, Engineering, Kind, ProcessImage, Quality, Source
from fieldgate.plugins.sparkplug.journal import MemoryJournal
from fieldgate.plugins.sparkplug.model import NodeModel, Sample
from fieldgate.plugins.sparkplug.session import Session, SessionSettings, Write

from . import spb
from .test_session import Clock, online, publishes

VOLTS = Engineering(DataType.INT32, divider=10, decimals=1, unit="V", low=0, high=500)
BAR = Engineering(DataType.UINT32, gain=0.01, unit="bar", low=0, high=100)


def session() -> Session:
    img = ProcessImage(clock=lambda: 0.0)
    src = Source("m", 7, 0)
    for spec in (
        ChannelSpec("m/m7/ai0", Kind.AI, src, dtype=DataType.INT64),
        ChannelSpec("m/m7/ai1", Kind.AI, src, dtype=DataType.UINT64),
        ChannelSpec("m/m7/ai2", Kind.AI, src, dtype=DataType.FLOAT64, engineering=VOLTS),
        ChannelSpec("m/m7/ai3", Kind.AI, src, dtype=DataType.STRING, length=16),
        ChannelSpec("m/m7/ao0", Kind.AO, src, dtype=DataType.FLOAT64, engineering=BAR),
        ChannelSpec("m/m7/ao1", Kind.AO, src, dtype=DataType.STRING, length=8),
        ChannelSpec("m/m7/ao2", Kind.AO, src, dtype=DataType.INT64),
    ):
        img.add(spec)
    channels = list(img)
    model = NodeModel.from_channels("plant", "gw1", channels, ["m/m7/ao*"])
    return Session(
        model,
        SessionSettings(brokers=1),
        MemoryJournal(),
        current=[Sample(c.id, c.value, c.quality, 1_600_000_000_000) for c in channels],
        rng=random.Random(1),
    )


def test_wide_types_text_and_engineering_units_in_birth_and_data():
    clock = Clock()
    s = session()
    actions = online(s, clock)
    (birth,) = [spb.decode(p.payload) for p in publishes(actions) if "DBIRTH" in p.topic]
    by_name = {m.name: m for m in birth.metrics}
    assert by_name["ai0"].datatype == spb.INT64 and by_name["ai1"].datatype == spb.UINT64
    assert by_name["ai2"].datatype == spb.DOUBLE and by_name["ai3"].datatype == spb.STRING
    volts = by_name["ai2"].properties
    assert volts["engUnit"] == "V" and (volts["engLow"], volts["engHigh"]) == (0.0, 500.0)
    assert "rawLow" not in volts  # the value is in volts already: no raw range to scale from
    assert by_name["ao0"].properties["engUnit"] == "bar"
    for cid, value in (
        ("m/m7/ai0", -(2**62) - 1),
        ("m/m7/ai1", 2**64 - 1),
        ("m/m7/ai2", 230.1),
        ("m/m7/ai3", "SN-Ü42"),
    ):
        s.on_change(Sample(cid, value, Quality.GOOD, 5))
    (data,) = [spb.decode(p.payload) for p in publishes(s.flush(clock()))]
    got = [
        spb.value_of(m, t) for m, t in zip(data.metrics, (spb.INT64, None, None, None), strict=True)
    ]
    assert got == [-(2**62) - 1, 2**64 - 1, 230.1, "SN-Ü42"]


def test_commands_of_those_types_and_a_setpoint_outside_its_range():
    clock = Clock()
    s = session()
    online(s, clock)
    aliases = {m.channel_id: m.alias for m in s.model.by_channel.values()}
    payload = spb.command(
        spb.command_metric(alias=aliases["m/m7/ao0"], datatype=spb.DOUBLE, value=42.5),
        spb.command_metric(alias=aliases["m/m7/ao1"], datatype=spb.STRING, value="ÄB✓"),
        spb.command_metric(alias=aliases["m/m7/ao2"], datatype=spb.INT64, value=-(2**63)),
        spb.command_metric(alias=aliases["m/m7/ao0"], datatype=spb.DOUBLE, value=150.0),
    )
    actions = s.on_message(clock(), "spBv1.0/plant/DCMD/gw1/m-m7", payload)
    writes = [a for a in actions if isinstance(a, Write)]
    assert [(w.channel_id, w.value) for w in writes] == [
        ("m/m7/ao0", 42.5),
        ("m/m7/ao1", "ÄB✓"),
        ("m/m7/ao2", -(2**63)),
    ]
    assert s.ignored["bad_value"] == 1  # 150 bar: outside 0..100
