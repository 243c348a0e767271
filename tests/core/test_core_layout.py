"""Default channel order and packing (I-7232D §3.1 / TV-25 rules)."""

from fieldgate import ChannelSpec, Kind, ProcessImage, Source, channel_id
from fieldgate.layout import byte_value, default_order, of_kind, pack_bits, write_byte


def build(modules):
    image = ProcessImage()
    for back, address, kind, count in modules:
        for i in range(count):
            image.add(
                ChannelSpec(channel_id(back, address, kind, i), kind, Source(back, address, i))
            )
    return image


def test_modules_ascending_and_digital_bytes_never_shared_between_modules():
    image = build([("b", 5, Kind.DI, 3), ("b", 1, Kind.DI, 10), ("b", 3, Kind.DO, 8)])
    order = default_order(image)
    assert [c.id for c in order[:2]] == ["b/m1/di0", "b/m1/di1"]
    di_bytes = pack_bits(of_kind(order, Kind.DI))
    assert len(di_bytes) == 3  # m1: 8 + 2 (padded), m5: 3 (padded)
    assert [c.id if c else None for c in di_bytes[1]] == ["b/m1/di8", "b/m1/di9"] + [None] * 6
    assert di_bytes[2][0].id == "b/m5/di0"
    assert (
        len(pack_bits(of_kind(order, Kind.DI), per_module=False)) == 2
    )  # NA-9161 style packs across modules


def test_backs_follow_topology_order():
    image = build([("z", 1, Kind.AI, 1), ("a", 1, Kind.AI, 1)])
    assert [c.id for c in default_order(image, ["z", "a"])] == ["z/m1/ai0", "a/m1/ai0"]


def test_byte_value_and_write_byte_lsb_first():
    image = build([("b", 3, Kind.DO, 6)])
    slots = pack_bits(of_kind(default_order(image), Kind.DO))[0]
    changed = write_byte(image, slots, 0b1010_0101, "can")
    assert changed == ["b/m3/do0", "b/m3/do2", "b/m3/do5"]  # bit 7 has no channel: padding
    assert byte_value(slots) == 0b0010_0101
