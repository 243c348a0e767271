"""Get_Attributes_All (0x01) on Identity instance 1: attributes 1-7 in the DeviceNet specification's order."""

from dnet_rig import Rig


def test_identity_get_attributes_all_in_specification_order():
    rig = Rig(
        vendor_id=803,
        device_type=0x000C,
        product_code=0x0102,
        major_revision=2,
        minor_revision=1,
        serial=0x0A0B0C0D,
        product_name="ICPDAS-I7241D",
    )
    assert rig.allocate(0x01) == "44B 0A CB 00"
    # 81 | vendor 23 03 | type 0C 00 | product 02 01 | revision 02 01 | status 01 00 (owned) |
    # serial 0D 0C 0B 0A | 0D "ICPDAS-I7241D": 29 bytes, sent in acknowledged fragments of 6
    assert rig.send("44C 0A 01 01 01") == ["44B 8A 00 81 23 03 0C 00 02"]
    assert rig.send("44C 8A C0 00") == ["44B 8A 41 01 02 01 01 00 0D"]
    assert rig.send("44C 8A C1 00") == ["44B 8A 42 0C 0B 0A 0D 49 43"]
    assert rig.send("44C 8A C2 00") == ["44B 8A 43 50 44 41 53 2D 49"]
    assert rig.send("44C 8A C3 00") == ["44B 8A 84 37 32 34 31 44"]
    assert rig.send("44C 8A C4 00") == []
    assert rig.slave.outgoing is None


def test_identity_get_attributes_all_follows_the_live_status():
    rig = Rig(product_name="fg")
    rig.allocate(0x01)
    rig.slave.module_fault = True  # a served module is offline: status bit 8

    def all_attributes() -> bytes:
        payload = b""
        frames = rig.send("44C 0A 01 01 01")
        while frames:
            data = bytes.fromhex(frames[0][4:])
            payload += data[2:]
            frames = rig.send(f"44C 8A {0xC0 | data[1] & 0x3F:02X} 00")
        return payload

    reply = all_attributes()
    assert reply[0] == 0x81 and len(reply) == 1 + 14 + 3
    assert reply[9:11] == bytes([0x01, 0x01]) and reply[15:] == b"\x02fg"
    rig.slave.module_fault = False
    assert all_attributes()[9:11] == bytes([0x01, 0x00])


def test_identity_get_attributes_all_errors():
    rig = Rig()
    rig.allocate(0x01)
    assert rig.explicit("01 01 01 00") == "0A 94 15 FF"  # no request data
    assert rig.explicit("01 01 00") == "0A 94 08 FF"  # class level: not offered
    assert rig.explicit("01 01 02") == "0A 94 16 FF"  # no instance 2
    assert rig.explicit("05 01 02 00") == "0A 94 16 FF"
    assert rig.explicit("01 03 01") == "0A 94 08 FF"  # other objects: not offered


def test_every_response_fits_the_explicit_connection_and_a_larger_one_is_0x11(monkeypatch):
    rig = Rig(product_name="x" * 32)  # Get_Attributes_All: 1 + 14 + 1 + 32 = 48 bytes
    rig.allocate(0x01)
    assert rig.explicit("0E 05 01 07") == "0A 8E 30 00"  # produced size 48, not 32
    from fieldgate.plugins.devicenet.objects import IdentityObject

    original = IdentityObject.instance_attributes

    def with_a_huge_attribute(self, instance):
        table = original(self, instance)
        table[0x70] = type(table[1])(lambda: bytes(48))  # 1 + 48 > 48
        return table

    monkeypatch.setattr(IdentityObject, "instance_attributes", with_a_huge_attribute)
    assert rig.explicit("0E 01 01 70") == "0A 94 11 FF"  # reply data too large
    assert rig.explicit("05 01 01 01") == "0A 94 20 FF"  # Reset type 1: invalid parameter
