"""Coalescing of reads and choice of write functions (sans-I/O)."""

from fieldgate.plugins.modbus.config import ModbusModuleConfig, module_points
from fieldgate.plugins.modbus.plan import decode_block, plan_reads, plan_writes


def points(*channels, **module):
    return module_points("rs485", ModbusModuleConfig(address=1, channels=list(channels), **module))


def spans(blocks):
    return [(b.function, b.address, b.count) for b in blocks]


def test_adjacent_registers_are_read_in_one_request():
    pts = points(
        {"kind": "ai", "table": "input_registers", "address": 0, "count": 4},
        {"kind": "ai", "table": "input_registers", "address": 4, "count": 2, "type": "float32"},
    )
    assert spans(plan_reads(pts)) == [(4, 0, 8)]


def test_a_hole_splits_the_read_unless_a_gap_is_allowed():
    pts = points(
        {"kind": "ai", "table": "holding_registers", "address": 0, "count": 2},
        {"kind": "ai", "table": "holding_registers", "address": 5, "count": 2},
    )
    assert spans(plan_reads(pts)) == [(3, 0, 2), (3, 5, 2)]
    assert spans(plan_reads(pts, gap=3)) == [(3, 0, 7)]
    assert spans(plan_reads(pts, gap=2)) == [(3, 0, 2), (3, 5, 2)]


def test_register_reads_stop_at_125_and_bit_reads_at_2000():
    regs = points({"kind": "ai", "table": "input_registers", "address": 0, "count": 130})
    assert spans(plan_reads(regs)) == [(4, 0, 125), (4, 125, 5)]
    bits = points(
        {"kind": "di", "table": "discrete_inputs", "address": 10, "count": 2000},
        {"kind": "di", "table": "discrete_inputs", "address": 2010, "count": 1},
    )
    assert spans(plan_reads(bits)) == [(2, 10, 2000), (2, 2010, 1)]


def test_a_32_bit_value_is_never_split_by_the_limit():
    pts = points(
        {"kind": "ai", "table": "input_registers", "address": 0, "count": 63, "type": "int32"}
    )  # 126 registers
    blocks = plan_reads(pts)
    assert spans(blocks) == [(4, 0, 124), (4, 124, 2)]


def test_module_limits_are_honoured_and_tables_are_never_mixed():
    pts = points(
        {"kind": "di", "table": "discrete_inputs", "address": 0, "count": 8},
        {"kind": "di", "table": "coils", "address": 8, "count": 8},
        {"kind": "ai", "table": "input_registers", "address": 0, "count": 10},
    )
    assert sorted(spans(plan_reads(pts, max_registers=4, max_bits=5))) == [
        (1, 8, 5),
        (1, 13, 3),
        (2, 0, 5),
        (2, 5, 3),
        (4, 0, 4),
        (4, 4, 4),
        (4, 8, 2),
    ]


def test_bits_of_registers_share_one_read_and_decode():
    pts = points(
        {"kind": "di", "table": "holding_registers", "address": 7, "count": 20, "first_bit": 4}
    )
    (block,) = plan_reads(pts)
    assert (block.function, block.address, block.count) == (3, 7, 2)
    readings = decode_block(
        block, [0x8010, 0x0001]
    )  # bits 4 and 15 of register 7, bit 0 of register 8
    assert readings["rs485/m1/di0"] is True  # bit 4 of register 7
    assert readings["rs485/m1/di11"] is True  # bit 15 of register 7
    assert readings["rs485/m1/di12"] is True  # bit 0 of register 8
    assert readings["rs485/m1/di1"] is False


def test_decode_of_mixed_types_and_word_orders():
    pts = points(
        {"kind": "ai", "table": "input_registers", "address": 0, "type": "uint16"},
        {
            "kind": "ai",
            "table": "input_registers",
            "address": 1,
            "type": "int32",
            "word_order": "little",
        },
        {"kind": "ai", "table": "input_registers", "address": 3, "type": "float32"},
    )
    (block,) = plan_reads(pts)
    got = decode_block(block, [0xFFFF, 0xFFFE, 0xFFFF, 0x4120, 0x0000])
    assert got == {"rs485/m1/ai0": 65535, "rs485/m1/ai1": -2, "rs485/m1/ai2": 10.0}


def writes(changes, **kw):
    return [(op.function, op.address, op.values) for op in plan_writes(changes, **kw)]


def test_one_changed_coil_is_fc5_and_a_run_is_fc15():
    pts = points({"kind": "do", "table": "coils", "address": 0, "count": 8})
    assert writes([(pts[2], True)]) == [(5, 2, [True])]
    assert writes([(pts[1], True), (pts[2], False), (pts[3], True), (pts[6], True)]) == [
        (15, 1, [True, False, True]),
        (5, 6, [True]),
    ]


def test_one_register_is_fc6_runs_and_32_bit_values_are_fc16():
    pts = points(
        {"kind": "ao", "table": "holding_registers", "address": 10, "count": 3},
        {"kind": "ao", "table": "holding_registers", "address": 20, "type": "float32"},
    )
    assert writes([(pts[1], -1)]) == [(6, 11, [0xFFFF])]
    assert writes([(pts[0], 1), (pts[1], 2)]) == [(16, 10, [1, 2])]
    assert writes([(pts[3], 1.0)]) == [(16, 20, [0x3F80, 0])]


def test_forced_write_functions():
    pts = points(
        {"kind": "do", "table": "coils", "address": 0, "count": 2, "write_fc": 15},
        {"kind": "ao", "table": "holding_registers", "address": 0, "count": 2, "write_fc": 6},
    )
    assert writes([(pts[0], True)]) == [(15, 0, [True])]
    assert writes([(pts[2], 1), (pts[3], 2)]) == [(6, 0, [1]), (6, 1, [2])]


def test_single_writes_only_when_the_module_refuses_multiple_writes():
    pts = points({"kind": "do", "table": "coils", "address": 0, "count": 3})
    assert writes([(p, True) for p in pts], allow_multiple=False) == [
        (5, 0, [True]),
        (5, 1, [True]),
        (5, 2, [True]),
    ]


def test_long_runs_are_split_at_the_write_limits():
    pts = points(
        {"kind": "ao", "table": "holding_registers", "address": 0, "count": 125, "type": "uint16"}
    )
    assert [(f, a, len(v)) for f, a, v in writes([(p, 7) for p in pts])] == [
        (16, 0, 123),
        (16, 123, 2),
    ]
    floats = points(
        {"kind": "ao", "table": "holding_registers", "address": 0, "count": 62, "type": "float32"}
    )
    assert [(f, a, len(v)) for f, a, v in writes([(p, 1.0) for p in floats])] == [
        (16, 0, 122),
        (16, 122, 2),
    ]


def test_one_batch_of_non_adjacent_coils_is_one_fc15_over_the_span():
    pts = points({"kind": "do", "table": "coils", "address": 0, "count": 8})
    held = [(pts[2], False), (pts[3], True), (pts[4], False), (pts[7], True)]
    ops = plan_writes([(pts[5], True), (pts[0], True), (pts[1], True)], held=held)
    assert [(op.function, op.address, op.values) for op in ops] == [
        (15, 0, [True, True, False, True, False, True])  # coils 2-4 at their held values
    ]
    assert ops[0].filled == {"rs485/m1/do2", "rs485/m1/do3", "rs485/m1/do4"}
    # without held values only adjacent changes share a request (the former plan)
    assert writes([(pts[0], True), (pts[1], True), (pts[5], True)]) == [
        (15, 0, [True, True]),
        (5, 5, [True]),
    ]


def test_one_batch_of_registers_is_one_fc16_with_wide_values_held_whole():
    pts = points(
        {"kind": "ao", "table": "holding_registers", "address": 10, "count": 2},
        {"kind": "ao", "table": "holding_registers", "address": 12, "type": "float32"},
        {"kind": "ao", "table": "holding_registers", "address": 14, "count": 2},
    )
    held = [(pts[1], 7), (pts[2], 1.0), (pts[4], 9)]
    assert writes([(pts[0], 1), (pts[3], -1)], held=held) == [(16, 10, [1, 7, 0x3F80, 0, 0xFFFF])]


def test_a_gap_the_back_does_not_hold_keeps_separate_writes():
    pts = points(
        {"kind": "do", "table": "coils", "address": 0, "count": 2},
        {"kind": "di", "table": "coils", "address": 2},  # an input among the coils
        {"kind": "do", "table": "coils", "address": 3, "count": 3},
        {"kind": "do", "table": "coils", "address": 7, "count": 2},  # a hole at 6
        {"kind": "ao", "table": "holding_registers", "address": 0},
        {"kind": "ao", "table": "holding_registers", "address": 1, "write_fc": 6},
        {"kind": "ao", "table": "holding_registers", "address": 2},
    )
    coil = {p.address: p for p in pts if p.kind.value == "do"}
    ao = [p for p in pts if p.kind.value == "ao"]
    held = [(p, False) for p in coil.values()]
    assert writes([(coil[0], True), (coil[3], True)], held=held) == [(5, 0, [True]), (5, 3, [True])]
    assert writes([(coil[5], True), (coil[7], True)], held=held) == [(5, 5, [True]), (5, 7, [True])]
    # coil 4 of unknown value (not held): separate; held: one FC15
    assert writes([(coil[3], True), (coil[5], True)]) == [(5, 3, [True]), (5, 5, [True])]
    assert writes([(coil[3], True), (coil[5], True)], held=held) == [(15, 3, [True, False, True])]
    # a register forced to FC6 is no filler; registers written singly stay single
    assert writes([(ao[0], 1), (ao[2], 3)], held=[(ao[1], 2)]) == [(6, 0, [1]), (6, 2, [3])]
    assert writes([(coil[3], True), (coil[5], True)], held=held, allow_multiple=False) == [
        (5, 3, [True]),
        (5, 5, [True]),
    ]


def test_spans_split_at_the_write_limits_and_the_module_maximum():
    pts = points({"kind": "do", "table": "coils", "address": 0, "count": 2000})
    held = [(p, False) for p in pts]
    last = len(pts) - 1

    def shape(ops):
        return [(op.function, op.address, len(op.values)) for op in ops]

    assert shape(plan_writes([(pts[0], True), (pts[1967], True)], held=held)) == [(15, 0, 1968)]
    assert shape(plan_writes([(pts[0], True), (pts[1968], True)], held=held)) == [
        (5, 0, 1),
        (5, 1968, 1),
    ]
    assert shape(plan_writes([(p, True) for p in pts], held=held)) == [
        (15, 0, 1968),
        (15, 1968, 32),
    ]
    assert shape(
        plan_writes([(pts[0], True), (pts[5], True), (pts[last], True)], held=held, max_bits=4)
    ) == [(5, 0, 1), (5, 5, 1), (5, last, 1)]
    regs = points({"kind": "ao", "table": "holding_registers", "address": 0, "count": 130})
    held_regs = [(p, 0) for p in regs]
    assert shape(plan_writes([(regs[0], 1), (regs[122], 1)], held=held_regs)) == [(16, 0, 123)]
    assert shape(plan_writes([(regs[0], 1), (regs[123], 1)], held=held_regs)) == [
        (6, 0, 1),
        (6, 123, 1),
    ]
    assert shape(
        plan_writes([(regs[0], 1), (regs[3], 1), (regs[9], 1)], held=held_regs, max_registers=4)
    ) == [(16, 0, 4), (6, 9, 1)]
