"""PDO engine rules: parameter write checks and aborts, inhibit time, event timer, NMT gating,
SYNC start value, RTR rules, reset, robustness against garbage."""

from __future__ import annotations

import random

from io_bench import Bench, demo_7232d, make_image, wire


def abort(index, sub, code):
    return (
        f"80 {index & 0xFF:02X} {index >> 8:02X} {sub:02X} "
        + code.to_bytes(4, "little").hex(" ").upper()
    )


def ok(index, sub):
    return f"60 {index & 0xFF:02X} {index >> 8:02X} {sub:02X} 00 00 00 00"


def started():
    b = demo_7232d()
    b.start()
    return b


def test_cob_id_changes_only_while_invalid():
    b = started()
    assert b.write(0x1800, 1, 0x182, 4) == abort(0x1800, 1, 0x06090030)
    assert b.write(0x1800, 1, 0x80000181, 4) == ok(0x1800, 1)
    assert b.rx(0x201, "77") == []  # TPDO1 invalid: no frame on the DI change
    assert b.write(0x1800, 1, 0x1A1, 4) == ok(0x1800, 1)
    assert b.rx(0x201, "78") == ["1A1 [1] 78"]
    assert b.write(0x1800, 1, 0x1A1 | 1 << 30, 4) == abort(
        0x1800, 1, 0x06090030
    )  # bit 30 too while valid


def test_cob_id_format_restricted_ids_and_clashes_are_refused():
    b = started()
    assert b.write(0x1805, 1, 0x20000182, 4) == abort(0x1805, 1, 0x06090030)  # 29-bit frame
    assert b.write(0x1805, 1, 0x605, 4) == abort(0x1805, 1, 0x06090030)  # SDO range
    assert b.write(0x1805, 1, 0x701, 4) == abort(0x1805, 1, 0x06090030)  # NMT error control
    assert b.write(0x1805, 1, 0x281, 4) == abort(0x1805, 1, 0x06090030)  # TPDO2's
    assert b.write(0x1805, 1, 0x80000281, 4) == ok(0x1805, 1)  # invalid: no clash


def test_transmission_types_reserved_values_are_refused():
    b = started()
    assert b.write(0x1800, 2, 245, 1) == abort(0x1800, 2, 0x06090030)
    assert b.write(0x1400, 2, 252, 1) == abort(0x1400, 2, 0x06090030)
    assert b.write(0x1400, 2, 253, 1) == abort(0x1400, 2, 0x06090030)
    assert b.write(0x1400, 2, 240, 1) == ok(0x1400, 2)
    assert b.value(0x1800, 2) == 255


def test_mapping_rules_and_abort_codes():
    b = started()
    assert b.write(0x1A00, 1, 0x64010110, 4) == abort(0x1A00, 1, 0x08000022)  # sub 0 is not 0
    assert b.write(0x1A05, 1, 0x60020108, 4) == abort(
        0x1A05, 1, 0x06040041
    )  # polarity: not mappable
    assert b.write(0x1A05, 1, 0x60000110, 4) == abort(0x1A05, 1, 0x06040041)  # wrong length
    assert b.write(0x1A05, 1, 0x70000108, 4) == abort(0x1A05, 1, 0x06020000)  # no such object
    assert b.write(0x1A05, 1, 0x10000020, 4) == abort(
        0x1A05, 1, 0x06040041
    )  # device type: exists, not mappable
    assert b.write(0x1A05, 1, 0x60000908, 4) == abort(0x1A05, 1, 0x06090011)  # no such sub-index
    assert b.write(0x1605, 1, 0x64010110, 4) == abort(
        0x1605, 1, 0x06040041
    )  # AI is read-only: no RPDO
    for sub in range(1, 6):
        assert b.write(0x1A05, sub, 0x64010110, 4) == ok(0x1A05, sub)
    assert b.write(0x1A05, 0, 5, 1) == abort(0x1A05, 0, 0x06040042)  # 80 bits
    assert b.write(0x1A05, 0, 9, 1) == abort(0x1A05, 0, 0x06040042)  # more entries than exist
    assert b.write(0x1A05, 0, 4, 1) == ok(0x1A05, 0)
    assert b.value(0x1A05, 0) == 4
    assert b.write(0x1805, 1, 0x190, 4) == ok(0x1805, 1)
    assert b.rx(0x190, rtr=True) == ["190 [8] 00 00 00 00 00 00 00 00"]


def test_inhibit_time_holds_back_and_sends_the_latest_value():
    b = started()
    assert b.write(0x1800, 3, 100, 2) == abort(0x1800, 3, 0x06090030)  # only while invalid
    b.write(0x1800, 1, 0x80000181, 4)
    assert b.write(0x1800, 3, 100, 2) == ok(0x1800, 3)  # 10 ms
    b.write(0x1800, 1, 0x181, 4)
    assert b.rx(0x201, "01") == ["181 [1] 01"]
    b.advance(0.002)
    assert b.rx(0x201, "02") == []
    b.advance(0.002)
    assert b.rx(0x201, "03") == []
    assert b.advance(0.0055) == []
    assert b.advance(0.001) == ["181 [1] 03"]
    assert b.advance(0.05) == []


def test_event_timer_restarts_on_every_transmission():
    b = started()
    b.write(0x1800, 5, 100, 2)
    assert b.advance(0.06) == []
    assert b.rx(0x201, "05") == ["181 [1] 05"]
    assert b.advance(0.099) == []
    assert b.advance(0.002) == ["181 [1] 05"]
    b.write(0x1800, 2, 1, 1)  # synchronous: the event timer does not apply
    assert b.advance(0.5) == []


def test_pdos_only_in_operational():
    b = demo_7232d()
    assert b.rx(0x201, "34") == [] and b.image.value("bus/m3/do2") is False  # pre-operational
    assert b.start() == []  # TV-07: no frame after Start in the I-7232D style
    b.nmt(0x02)  # stopped
    assert b.rx(0x201, "34") == [] and b.rx(0x181, rtr=True) == [] and b.sync() == []
    b.image.write_output("bus/m3/do0", True)
    assert b.flush() == []
    b.nmt(0x80)
    b.write(0x1800, 5, 10, 2)
    assert b.advance(0.1) == []  # no event timer outside Operational


def test_rtr_refused_when_bit_30_is_set():
    b = started()
    b.write(0x1801, 1, 0x80000281, 4)
    b.write(0x1801, 1, 0x40000281, 4)
    assert b.rx(0x281, rtr=True) == []
    assert b.rx(0x181, rtr=True) == ["181 [1] 00"]


def test_sync_start_value_with_sync_counter():
    b = started()
    assert b.write(0x1019, 0, 10, 1) == ok(0x1019, 0)
    b.write(0x1800, 1, 0x80000181, 4)
    assert b.write(0x1800, 6, 3, 1) == ok(0x1800, 6)
    b.write(0x1800, 2, 2, 1)
    b.write(0x1800, 1, 0x181, 4)
    sent = [n for n in range(1, 11) if b.rx(0x080, bytes([n]))]
    assert sent == [3, 5, 7, 9]


def test_synchronous_rpdo_takes_the_last_frame_at_sync():
    b = started()
    b.write(0x1400, 2, 5, 1)  # any 1..240: applied at the next SYNC
    b.rx(0x201, "11")
    b.rx(0x201, "22")
    assert b.image.value("bus/m3/do1") is False
    assert b.sync() == ["181 [1] 22"]
    assert b.sync() == []


def test_reset_communication_restores_defaults():
    b = started()
    b.write(0x1800, 2, 1, 1)
    b.write(0x1A00, 0, 0, 1)
    b.nmt(0x82)
    assert (
        b.value(0x1800, 2) == 255 and b.value(0x1A00, 0) == 1 and b.value(0x1A00, 1) == 0x60000108
    )
    assert b.rx(0x201, "34") == []  # pre-operational after the reset


def test_garbage_never_raises_and_never_answers_with_junk():
    b = started()
    rng = random.Random(7)
    for _ in range(500):
        can_id = rng.choice([0x201, 0x301, 0x181, 0x281, 0x202, 0x080, 0x1FF])
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        frames = b.rx(can_id, data, rtr=rng.random() < 0.2)
        assert all(f.split()[0] in ("181", "281", "081") for f in frames), frames
    assert b.node.counters["internal_errors"] == 0


def test_start_policy_na9161_sends_every_mapped_tpdo_once():
    from fieldgate.plugins.canopen.cia401.iodevice import IoSettings

    image = make_image([(1, 8, 0, 0, 0), (2, 0, 0, 2, 0)])
    b = Bench(image, IoSettings(style="na9161"), node_id=5)
    assert b.start() == ["185 [1] 00", "285 [4] 00 00 00 00"]
    b2 = Bench(make_image([(1, 8, 0, 0, 0)]), IoSettings(start_policy="none"))
    assert b2.start() == []
    b3 = Bench(make_image([(1, 8, 0, 0, 0)]), IoSettings())  # icpdas: none, as TV-07
    assert b3.start() == []
    b4 = Bench(make_image([(1, 8, 0, 0, 0)]), IoSettings(start_policy="async"))
    assert b4.start() == ["181 [1] 00"]


def test_store_keeps_pdo_and_401_parameters_across_resets(tmp_path):
    from io_bench import make_image as mk

    def bench():
        image = mk([(1, 8, 0, 0, 0), (3, 0, 8, 0, 0)])
        wire(image, 3, 1)
        return Bench(image, store_path=tmp_path / "node.json")

    b = bench()
    b.write(0x1800, 2, 1, 1)
    b.write(0x1A00, 0, 0, 1)
    b.write(0x6206, 1, 0x0F, 1)
    assert b.write(0x1010, 1, 0x65766173, 4) == ok(0x1010, 1)  # "save"
    b.write(0x1800, 2, 3, 1)
    b.nmt(0x81)  # reset node: the stored values come back
    assert b.value(0x1800, 2) == 1 and b.value(0x1A00, 0) == 0 and b.value(0x6206, 1) == 0x0F
    b2 = bench()  # power cycle
    assert b2.value(0x1800, 2) == 1 and b2.value(0x6206, 1) == 0x0F
    assert b2.write(0x1011, 1, 0x64616F6C, 4) == ok(0x1011, 1)  # "load": defaults at the next reset
    b2.nmt(0x81)
    assert b2.value(0x1800, 2) == 255 and b2.value(0x1A00, 0) == 1 and b2.value(0x6206, 1) == 0


def test_stored_parameters_of_another_module_set_are_ignored(tmp_path):
    b = Bench(make_image([(1, 8, 0, 0, 0)]), store_path=tmp_path / "node.json")
    b.write(0x1800, 2, 7, 1)
    b.write(0x1010, 2, 0x65766173, 4)
    other = Bench(make_image([(1, 16, 0, 0, 0)]), store_path=tmp_path / "node.json")
    assert other.value(0x1800, 2) == 255
    same = Bench(make_image([(1, 8, 0, 0, 0)]), store_path=tmp_path / "node.json")
    assert same.value(0x1800, 2) == 7


def test_512_pdos_per_direction():
    from fieldgate.plugins.canopen.cia401.iodevice import IoSettings

    b = Bench(make_image([(1, 8, 8, 0, 0)]), IoSettings(pdo_count=512))
    assert 0x15FF in b.node.od and 0x1BFF in b.node.od and 0x1C00 not in b.node.od
    assert b.write(0x19FF, 1, 0x1F0, 4) == ok(0x19FF, 1)
    assert b.write(0x1BFF, 1, 0x60000108, 4) == ok(0x1BFF, 1)
    assert b.write(0x1BFF, 0, 1, 1) == ok(0x1BFF, 0)
    b.start()
    b.image.update_input("bus/m1/di3", True)
    assert b.flush() == ["181 [1] 08", "1F0 [1] 08"]


def test_io_parameters_and_node_values_share_one_store_write_and_fingerprint(tmp_path, monkeypatch):
    """One "save" = one atomic write of one file; a layout change drops all of it."""
    from fieldgate.plugins.canopen.cia301 import store as store_module
    from fieldgate.plugins.canopen.cia401.iodevice import IoSettings

    path = tmp_path / "node.json"
    writes = []
    real_write = store_module.write_atomic
    monkeypatch.setattr(
        store_module, "write_atomic", lambda p, data: (writes.append(p), real_write(p, data))
    )
    b = Bench(make_image([(1, 8, 8, 0, 0)]), IoSettings(style="icpdas"), store_path=path)
    b.write(0x1017, 0, 100, 2)
    b.write(0x1800, 2, 7, 1)
    assert b.write(0x1010, 1, 0x65766173, 4) == ok(0x1010, 1)
    assert writes == [path]
    assert list(tmp_path.iterdir()) == [path]
    same = Bench(make_image([(1, 8, 8, 0, 0)]), IoSettings(style="icpdas"), store_path=path)
    assert same.value(0x1017, 0) == 100 and same.value(0x1800, 2) == 7
    other_style = Bench(
        make_image([(1, 8, 8, 0, 0)]),
        IoSettings(style="icpdas", mapping_closed=True),
        store_path=path,
    )
    assert other_style.value(0x1017, 0) == 0 and other_style.value(0x1800, 2) == 255
