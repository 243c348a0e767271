"""NMT (CiA 301 §7.3.2): the slave's states and the commands of the NMT master.

The node (:mod:`.node`) runs the state machine: it takes the NMT command frame (COB-ID 0,
two bytes: command specifier, node-ID or 0 for all), changes state and tells every service
(``on_nmt_state``), and on a reset reloads the dictionary, sends the boot-up and goes
Pre-operational. :func:`command` decides what a frame asks, :data:`STATE_OF` where a
state command leads.
"""

from __future__ import annotations

from enum import IntEnum


class NmtState(IntEnum):
    """NMT states with their CiA 301 heartbeat / guarding state codes."""

    INITIALISING = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F

    @property
    def label(self) -> str:
        return self.name.replace("_", "-")


UNCONFIGURED_NODE_ID = 0xFF  # CiA 305: a node without a node-ID waits for LSS

NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82
RESETS = (NMT_RESET_NODE, NMT_RESET_COMMUNICATION)

STATE_OF = {  # the state a state command leads to, from any state but Initialising
    NMT_START: NmtState.OPERATIONAL,
    NMT_STOP: NmtState.STOPPED,
    NMT_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
}


def command(data: bytes, node_id: int | None) -> int | str:
    """The command specifier of an NMT frame for this node (``node_id`` None: unconfigured),
    or the counter of why it is not one: ``nmt_malformed`` (shorter than 2 bytes),
    ``nmt_other_node`` (addressed to another node, or this one has no node-ID yet)."""
    if len(data) < 2:
        return "nmt_malformed"
    cs, target = data[0], data[1]
    if node_id is None or target not in (0, node_id):
        return "nmt_other_node"
    return cs
