"""The independent stacks the suite is graded against (issue 31): canopen's LocalNode and
durand, both from PyPI, and the verdicts expected of each, checked in beside this file
(``peers/<name>.verdicts``: one ``case-id VERDICT`` a line). Every verdict but PASS there is
explained, with the clause the peer deviates from or why the case does not apply, in
docs/conformance-peers.md.

Regenerate the files after a deliberate change (then explain every new non-PASS)::

    python tests/conformance/conformance_peers.py --write
"""

from __future__ import annotations

import sys
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import can

HERE = Path(__file__).resolve().parent
VERDICTS = HERE / "peers"
DOC = HERE.parents[1] / "docs" / "conformance-peers.md"
# virtual-bus timing of the host tests (the SocketCAN stage uses the CLI's defaults); the
# verdicts are the same with both (measured: LocalNode 10 s / 34 s, durand 8 s / 19 s)
TIMING = dict(response=0.1, silence=0.05, heartbeat_ms=50, bootup=0.2, sdo_server_timeout=0.3)


@dataclass(frozen=True)
class Peer:
    name: str
    node_id: int
    script: Path  # serves the peer on a real bus: --channel C --eds FILE


PEERS = {
    "localnode": Peer("localnode", 7, HERE / "conformance_localnode.py"),
    "durand": Peer("durand", 9, HERE / "conformance_durand.py"),
}


def expected(name: str) -> dict[str, str]:
    out = {}
    for line in (VERDICTS / f"{name}.verdicts").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            case_id, verdict = line.split()
            out[case_id] = verdict
    return out


def differences(name: str, seen: dict[str, str]) -> dict[str, tuple[str | None, str | None]]:
    """Each case whose verdict is not the expected one: (expected, seen)."""
    want = expected(name)
    return {
        c: (want.get(c), seen.get(c))
        for c in sorted(set(want) | set(seen))
        if want.get(c) != seen.get(c)
    }


@contextmanager
def virtual_peer(name: str, eds_dir: Path) -> Iterator[tuple[can.BusABC, Path]]:
    """The peer on a private virtual channel: (the tester's bus, the peer's EDS)."""
    channel = f"peer-{uuid.uuid4().hex[:8]}"
    if name == "localnode":
        from conformance_localnode import LocalNodeDevice, write_eds

        eds = write_eds(eds_dir / "localnode.eds")
        with LocalNodeDevice(channel, eds):
            bus = can.Bus(interface="virtual", channel=channel)
            try:
                yield bus, eds
            finally:
                bus.shutdown()
        return
    from conformance_durand import DurandDevice

    peer_bus = can.Bus(interface="virtual", channel=channel)
    device = DurandDevice(peer_bus)
    eds = device.write_eds(eds_dir / "durand.eds")
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        yield bus, eds
    finally:
        bus.shutdown()
        device.close()
        peer_bus.shutdown()


def grade(name: str, eds_dir: Path, shuffle: int | None = None) -> dict[str, str]:
    """``--profile all`` against the peer on the virtual bus: case id -> verdict."""
    from fieldgate.conformance import SuiteConfig, Timing, run_suite

    with virtual_peer(name, eds_dir) as (bus, eds):
        config = SuiteConfig(
            PEERS[name].node_id,
            str(eds),
            profiles=["all"],
            timing=Timing(**TIMING),
            shuffle=shuffle,
        )
        return {r.case.id: r.verdict.value for r in run_suite(config, bus=bus)}


def write() -> None:
    import tempfile

    for name in PEERS:
        with tempfile.TemporaryDirectory() as tmp:
            seen = grade(name, Path(tmp))
        head = [
            f"# fieldgate conformance --profile all against {name} (tests/conformance/conformance_peers.py --write);",
            "# every verdict but PASS is explained in docs/conformance-peers.md",
        ]
        lines = [f"{c} {v}" for c, v in seen.items()]
        (VERDICTS / f"{name}.verdicts").write_text("\n".join(head + lines) + "\n")
        print(name, len(lines), "cases")


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    if sys.argv[1:] == ["--write"]:
        write()
    else:
        sys.exit(__doc__)
