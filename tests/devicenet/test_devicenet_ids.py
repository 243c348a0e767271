"""CAN identifier layout: Group 1-4 formulas, decoding, the Predefined Master/Slave set."""

from fieldgate.plugins.devicenet import ids


def test_group2_formula_matches_the_anchor_vectors():
    assert ids.group2_id(1, 4) == 0x40C  # braboj: can_addr(2, 4, 1)
    assert ids.decode(0x40B) == (2, 3, 1)  # braboj: devnet_addr(0x40B)


def test_predefined_set_for_slave_9_master_10():
    # seed-003 §2.1 table (slave 0x09, master 0x0A)
    assert ids.group1_id(ids.G1_COS_CYCLIC, 9) == 0x349
    assert ids.group1_id(ids.G1_STROBE_RESPONSE, 9) == 0x389
    assert ids.group1_id(ids.G1_POLL_RESPONSE, 9) == 0x3C9
    assert ids.group2_id(0x0A, ids.G2_STROBE) == 0x450
    assert [ids.group2_id(9, m) for m in (2, 3, 4, 5, 6, 7)] == [
        0x44A,
        0x44B,
        0x44C,
        0x44D,
        0x44E,
        0x44F,
    ]
    assert ids.group4_id(0x2D) == 0x7ED


def test_decode_every_group_and_out_of_range():
    assert ids.decode(0x3C9) == (1, 0xF, 9)
    assert ids.decode(0x44F) == (2, 7, 9)
    assert ids.decode(0x600 | 5 << 6 | 3) == (3, 5, 3)
    assert ids.decode(0x7EC) == (4, 0x2C, None)
    assert ids.decode(0x7F0)[0] == 0 and ids.decode(0x800)[0] == 0
    for can_id in range(0x400, 0x600):
        group, msg, mac = ids.decode(can_id)
        assert ids.group2_id(mac, msg) == can_id
