"""Hostile inbound Sparkplug messages against the edge node's session (sans-I/O, the engine
``fieldgate run`` uses): each must be counted and ignored, the node keeps publishing, and a
burst of Rebirth requests costs one rebirth per interval. Prints the figures.

Run:  .venv/bin/python scripts/faults/sparkplug_inputs.py   (a few seconds)

Cases: a STATE nested 100,000 deep (a retained one used to raise RecursionError at every
reconnect), a 4 KiB STATE nested 1,960 deep, a 1 MB STATE, a 1 MB NCMD, an NCMD of
protobuf garbage; then 1,000 NCMD Rebirth requests within one second.
"""

from __future__ import annotations

import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from sparkplug import spb  # noqa: E402  (the tests' independent Sparkplug B encoder)

from fieldgate.image import ChannelSpec, Kind, ProcessImage, Source  # noqa: E402
from fieldgate.plugins.sparkplug.journal import MemoryJournal  # noqa: E402
from fieldgate.plugins.sparkplug.model import NodeModel, Sample  # noqa: E402
from fieldgate.plugins.sparkplug.session import (  # noqa: E402
    Instant,
    Publish,
    Session,
    SessionSettings,
)


def session() -> Session:
    image = ProcessImage(clock=lambda: 0.0)
    for i in range(4):
        image.add(ChannelSpec(f"io/m1/di{i}", Kind.DI, Source("io", 1, i)))
    channels = list(image)
    model = NodeModel.from_channels("plant", "gw1", channels, (), None)
    return Session(
        model,
        SessionSettings(primary_host_id="scada"),
        MemoryJournal(),
        last_bdseq=None,
        current=[Sample(c.id, c.value, c.quality, 0) for c in channels],
        rng=random.Random(1),
    )


def main() -> int:
    t = Instant(100.0, 1_700_000_000_000)
    s = session()
    s.start(t)
    s.on_connack(t, True)
    online = b'{"online": true, "timestamp": 1}'
    s.on_message(t, "spBv1.0/STATE/scada", online)
    deep = b'{"online": true, "timestamp": 2, "x": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    cases = {
        "STATE nested 100,000 deep (200 KB)": ("spBv1.0/STATE/scada", deep),
        "STATE of 4 KiB nested 1,960 deep": ("spBv1.0/STATE/scada", deep[:4000]),
        "STATE of 1 MB": ("spBv1.0/STATE/scada", b" " * 1_000_000),
        "NCMD of 1 MB": ("spBv1.0/plant/NCMD/gw1", b"\x00" * 1_000_000),
        "NCMD of protobuf garbage": ("spBv1.0/plant/NCMD/gw1", bytes(range(256)) * 4),
    }
    ok = True
    print("hostile inbound Sparkplug messages (the edge node's session, as fieldgate run has it)")
    for name, (topic, data) in cases.items():
        before = dict(s.ignored)
        started = time.perf_counter()
        try:
            actions = s.on_message(t, topic, data)
            outcome = ", ".join(
                f"{k} +{v - before.get(k, 0)}"
                for k, v in s.ignored.items()
                if v != before.get(k, 0)
            )
        except RecursionError:
            actions, outcome, ok = [], "RecursionError", False
        took = (time.perf_counter() - started) * 1000
        ok = ok and not actions and bool(outcome)
        print(f"  {name:36} -> counted and ignored ({outcome}) in {took:.1f} ms")
    cmd = spb.command(
        spb.command_metric(name="Node Control/Rebirth", datatype=spb.BOOLEAN, value=True)
    )
    births = 0
    for i in range(1000):
        now = Instant(200.0 + i / 1000, t.wall_ms)
        births += sum(
            1
            for a in s.on_message(now, "spBv1.0/plant/NCMD/gw1", cmd)
            if isinstance(a, Publish) and "NBIRTH" in a.topic
        )
        due = s.next_deadline()
        if due is not None and due <= now.mono:
            births += sum(1 for a in s.tick(now) if isinstance(a, Publish) and "NBIRTH" in a.topic)
    end = Instant(202.0, t.wall_ms)
    births += sum(1 for a in s.tick(end) if isinstance(a, Publish) and "NBIRTH" in a.topic)
    print(
        f"  1,000 Rebirth requests in 1 s -> {births} rebirths (rebirth_min_interval_ms 1000; "
        f"{s.rebirths['coalesced']} coalesced)"
    )
    ok = ok and births == 2 and s.publishing
    print(f"  the node still publishing: {s.publishing}")
    print("verdict:", "PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
