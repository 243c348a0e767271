"""core/can/link.py, rtnetlink.py and autobaud.py: the parts that need no kernel.

The netlink bytes are built and read here with struct from linux/can/netlink.h's layout
(independently of the module's own codec); the kernel's side is tested in the SocketCAN
guest (tests/socketcan/test_socketcan_can_link.py, test_socketcan_slcan.py).
"""

from __future__ import annotations

import errno
import struct

import pytest

from fieldgate.can import link as canlink
from fieldgate.can import rtnetlink
from fieldgate.can.autobaud import STANDARD_RATES, BitrateProbe, probe_bitrate
from fieldgate.can.link import LinkError, LinkSettings, plan
from fieldgate.can.rtnetlink import LinkChange, RawLink


def nla(kind: int, payload: bytes) -> bytes:
    length = 4 + len(payload)
    return struct.pack("=HH", length, kind) + payload + b"\0" * ((-length) % 4)


def parse(data: bytes) -> list[tuple[int, bytes]]:
    out, i = [], 0
    while i + 4 <= len(data):
        length, kind = struct.unpack_from("=HH", data, i)
        out.append((kind & 0x3FFF, data[i + 4 : i + length]))
        i += (length + 3) & ~3
    return out


def kernel_answer(
    *, kind: bytes = b"can", up: bool = True, state: int = 0, bitrate: int = 250000
) -> bytes:
    """An RTM_NEWLINK body as the kernel sends it for a SJA1000 at ``bitrate``."""
    can = (
        nla(1, struct.pack("=8I", bitrate, 875, 250, 6, 7, 2, 1, 2))
        + nla(2, b"sja1000".ljust(16, b"\0") + struct.pack("=8I", 1, 16, 1, 8, 4, 1, 64, 1))
        + nla(3, struct.pack("=I", 8_000_000))
        + nla(4, struct.pack("=I", state))
        + nla(5, struct.pack("=II", 0xFFFF, 0x02))
        + nla(6, struct.pack("=I", 100))
        + nla(8, struct.pack("=HH", 128, 7))
        + nla(17, nla(1, struct.pack("=I", 0x1DF)))
    )
    info = (
        nla(1, kind + b"\0") + nla(2 | 0x8000, can) + nla(3, struct.pack("=6I", 9, 3, 2, 1, 0, 1))
    )
    return struct.pack("=BxHiII", 0, 280, 7, 1 if up else 0, 0) + nla(3, b"can0\0") + nla(18, info)


def test_a_kernel_answer_decodes_to_every_field():
    link = rtnetlink.decode_link(kernel_answer(state=3))
    assert (link.name, link.index, link.up, link.kind) == ("can0", 7, True, "can")
    assert (link.bitrate, link.sample_point, link.clock_hz) == (250000, 0.875, 8_000_000)
    assert (link.state, link.listen_only, link.listen_only_supported) == ("bus-off", True, True)
    assert (link.restart_ms, link.tx_errors, link.rx_errors) == (100, 128, 7)
    assert link.timing_const == "sja1000"
    assert link.counters == {
        "bus_errors": 9,
        "error_warning": 3,
        "error_passive": 2,
        "bus_off": 1,
        "arbitration_lost": 0,
        "restarts": 1,
    }


def test_a_set_request_carries_the_can_attributes_the_kernel_parses():
    change = LinkChange(bitrate=500000, sample_point=0.8, restart_ms=50, listen_only=False)
    data = rtnetlink.set_link_request(7, change, sequence=42)
    length, kind, flags, seq, _ = struct.unpack_from("=IHHII", data)
    assert (length, kind, flags, seq) == (len(data), 16, 0x5, 42)
    _fam, _type, index, ifflags, change_mask = struct.unpack_from("=BxHiII", data, 16)
    assert (index, ifflags, change_mask) == (7, 0, 0)  # the up/down state is left alone
    (linkinfo,) = parse(data[32:])
    assert linkinfo[0] == 18
    info = dict(parse(linkinfo[1]))
    assert info[1] == b"can\0"
    can = dict(parse(info[2]))
    assert struct.unpack("=8I", can[1])[:2] == (500000, 800)
    assert struct.unpack("=II", can[5]) == (0x02, 0)  # listen-only in the mask, off
    assert struct.unpack("=I", can[6]) == (50,)
    assert 7 not in can  # no restart asked


def test_restart_is_a_u32_and_up_down_is_the_flags_field():
    """The kernel's policy for IFLA_CAN_RESTART is NLA_U32: a zero-length flag is refused
    with ERANGE (what pyroute2 0.9.7 sends; docs/can-link.md)."""
    data = rtnetlink.set_link_request(3, LinkChange(restart=True), 1)
    (linkinfo,) = parse(data[32:])
    can = dict(parse(dict(parse(linkinfo[1]))[2]))
    assert struct.unpack("=I", can[7]) == (1,)
    down = rtnetlink.set_link_request(3, LinkChange(up=False), 2)
    assert struct.unpack_from("=BxHiII", down, 16)[3:] == (0, 1)
    assert len(down) == 32  # no attributes at all


def test_an_error_answer_is_its_errno():
    err = struct.pack("=IHHII", 36, 2, 0, 5, 0) + struct.pack("=i", -errno.EPERM) + b"\0" * 16
    assert rtnetlink.decode_ack(err, 5) == (errno.EPERM, None)
    ok = struct.pack("=IHHII", 36, 2, 0, 6, 0) + struct.pack("=i", 0) + b"\0" * 16
    assert rtnetlink.decode_ack(ok, 6) == (0, None)
    assert rtnetlink.decode_ack(ok, 7)[0] == -1  # another request's answer


def controller(**fields: object) -> RawLink:
    base: dict[str, object] = dict(
        name="can0",
        index=4,
        up=True,
        kind="can",
        bitrate=125000,
        sample_point=0.875,
        state="error-active",
        listen_only=False,
        listen_only_supported=True,
        restart_ms=0,
    )
    base.update(fields)
    return RawLink(**base)  # type: ignore[arg-type]


def test_plan_changes_only_what_differs():
    assert plan(controller(), LinkSettings(125000)).change is None
    steps = plan(controller(), LinkSettings(250000, restart_ms=100))
    assert steps.change == LinkChange(bitrate=250000, restart_ms=100)
    assert steps.differences == ["bit rate 125000 -> 250000", "restart-ms 0 -> 100"]
    # a sample point within the kernel's rounding is the same; a real difference resets the timing
    assert plan(controller(sample_point=0.874), LinkSettings(125000, 0.875)).change is None
    moved = plan(controller(), LinkSettings(125000, sample_point=0.75)).change
    assert moved == LinkChange(bitrate=125000, sample_point=0.75)
    assert plan(controller(listen_only=True), LinkSettings(125000)).change == LinkChange(
        listen_only=False
    )
    assert plan(controller(bitrate=0, up=False), LinkSettings(125000)).differences == [
        "bit rate unset -> 125000"
    ]


def test_plan_says_why_it_cannot_or_need_not():
    slcan = controller(bitrate_const=(10000, 125000, 250000, 500000, 1000000))
    assert (
        "cannot run at 83333 bit/s (its rates: 10000, 125000"
        in plan(slcan, LinkSettings(83333)).impossible
    )
    assert plan(slcan, LinkSettings(250000)).change == LinkChange(bitrate=250000)
    vcan = plan(controller(kind="vcan", bitrate=None), LinkSettings(250000))
    assert vcan.change is None and "virtual CAN interface (vcan)" in vcan.note
    assert "not a CAN controller" in plan(controller(kind="bond"), LinkSettings(250000)).impossible
    no_lom = controller(listen_only_supported=False)
    assert "no listen-only mode" in plan(no_lom, LinkSettings(125000, listen_only=True)).impossible


class FakeRoute:
    """RouteSocket's interface with a kernel that refuses changes (no CAP_NET_ADMIN)."""

    def __init__(self, link: RawLink, refuse: int = errno.EPERM) -> None:
        self.link, self.refuse, self.sets = link, refuse, 0

    def __enter__(self) -> FakeRoute:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def get(self, name: str) -> RawLink:
        return self.link

    def set(self, index: int, change: LinkChange) -> None:
        self.sets += 1
        raise rtnetlink.NetlinkError(self.refuse, "refused")


def test_without_cap_net_admin_one_line_names_the_capability(monkeypatch):
    route = FakeRoute(controller())
    monkeypatch.setattr(canlink, "_socket", lambda: route)
    with pytest.raises(LinkError) as caught:
        canlink.apply_settings("can0", LinkSettings(250000))
    text = str(caught.value)
    assert "\n" not in text and caught.value.errno == errno.EPERM
    assert text.startswith("can0: bit rate 125000 -> 250000: ")
    assert "needs the capability CAP_NET_ADMIN" in text
    # what already matches needs no capability: nothing is sent
    route.sets = 0
    applied = canlink.apply_settings("can0", LinkSettings(125000))
    assert route.sets == 0 and not applied.changed


def test_restart_of_a_controller_that_is_not_bus_off_says_so(monkeypatch):
    monkeypatch.setattr(canlink, "_socket", lambda: FakeRoute(controller(), errno.EBUSY))
    with pytest.raises(LinkError, match="not restarted: the controller is not bus-off"):
        canlink.restart("can0")


# -- the auto-baud decision -----------------------------------------------------------------
def run_probe(bus_rate: int | None, errors_at_wrong_rates: bool, **kw: object) -> BitrateProbe:
    """Drive the probe as a bus at ``bus_rate`` would: valid frames every 0.1 s at the right
    rate, at a wrong one nothing or an error frame."""
    probe = BitrateProbe(**kw)  # type: ignore[arg-type]
    now = 0.0
    step = probe.start(now)
    while step.action == "listen":
        now += 0.1
        if step.bitrate == bus_rate:
            step = probe.on_frame(now, error_frame=False) or step
        elif errors_at_wrong_rates:
            step = probe.on_frame(now, error_frame=True) or step
        else:
            step = probe.on_time(now) or step
        assert now < 1000
    return probe


def test_the_probe_finds_the_rate_that_carries_valid_frames():
    quiet = run_probe(125000, errors_at_wrong_rates=False, dwell_s=1.0)
    assert quiet.found == 125000
    assert quiet.tried == [1_000_000, 800_000, 500_000, 250_000, 125_000]
    noisy = run_probe(50000, errors_at_wrong_rates=True, dwell_s=1.0)
    assert noisy.found == 50000  # an error frame moves on at once


def test_the_probe_gives_up_after_its_rounds_and_needs_consecutive_frames():
    probe = run_probe(None, errors_at_wrong_rates=False, rounds=2, dwell_s=0.5)
    assert probe.found is None and probe.tried == list(STANDARD_RATES) * 2
    probe = BitrateProbe(rates=[250000, 125000], frames_needed=3)
    assert probe.start(0.0).bitrate == 250000
    assert probe.on_frame(0.1, False) is None
    assert probe.on_frame(0.2, True).bitrate == 125000  # type: ignore[union-attr]
    assert probe.on_frame(0.3, False) is None and probe.on_frame(0.4, False) is None
    assert probe.on_frame(0.5, False).action == "found"  # type: ignore[union-attr]
    with pytest.raises(ValueError):
        BitrateProbe(rates=[])


def test_restart_refused_because_the_kernel_restarts_by_itself_says_so(monkeypatch):
    monkeypatch.setattr(
        canlink, "_socket", lambda: FakeRoute(controller(restart_ms=100), errno.EINVAL)
    )
    with pytest.raises(LinkError, match="restart-ms is 100: the kernel restarts it by itself"):
        canlink.restart("can0")


def test_probing_needs_a_controller_with_listen_only(monkeypatch):
    for link, why in (
        (controller(kind="vcan"), "vcan0 has no bit timing|can0 has no bit timing"),
        (controller(listen_only_supported=False), "no listen-only mode: probing the bit rate"),
    ):
        route = FakeRoute(link)
        monkeypatch.setattr(canlink, "_socket", lambda route=route: route)
        with pytest.raises(LinkError, match=why):
            probe_bitrate("can0", BitrateProbe())
        assert route.sets == 0  # nothing was touched
