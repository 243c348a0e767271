"""The suite against stacks we did not write (canopen's LocalNode, durand), on the virtual bus:
the verdicts are the checked-in ones whatever the case order, and every verdict but PASS is
explained in docs/conformance-peers.md (the SocketCAN stage grades the same peers as their own
processes over vcan0: tests/socketcan/test_socketcan_conformance_peers.py)."""

from __future__ import annotations

import re

import pytest
from conformance_peers import DOC, PEERS, differences, expected, grade


@pytest.mark.parametrize("name", sorted(PEERS))
def test_shuffled_order_gives_the_expected_verdicts(name, tmp_path):
    seen = grade(name, tmp_path, shuffle=31)
    assert not differences(name, seen), differences(name, seen)


def doc_rows(name: str) -> dict[str, str]:
    """case id -> the row that explains it, from the peer's section of the doc."""
    text = DOC.read_text()
    section = re.split(r"^## ", text, flags=re.MULTILINE)
    body = next(s for s in section if s.lower().startswith(name))
    rows = {}
    for line in body.splitlines():
        if line.startswith("| `"):
            for case_id in re.findall(r"`([a-z0-9-]+\.[a-z0-9_]+)`", line.split("|")[1]):
                rows[case_id] = line
    return rows


@pytest.mark.parametrize("name", sorted(PEERS))
def test_every_verdict_but_pass_is_explained_with_its_verdict(name):
    rows = doc_rows(name)
    for case_id, verdict in expected(name).items():
        if verdict == "PASS":
            continue
        assert case_id in rows, f"{name}: {case_id} {verdict} not explained in {DOC.name}"
        assert verdict in rows[case_id], f"{name}: {case_id}: the row does not say {verdict}"
        if verdict == "FAIL":
            assert "§" in rows[case_id], f"{name}: {case_id} FAIL without the clause"
