"""The NA-9161's per-slot objects in the na9161 style (0x2000/0x2200 slot memory, 0x4501,
0x4502 slot configuration, 0x4504 catalog codes), and ``validate`` applying ``run``'s limits.

examples/na9161-style.yaml's slots: 1 = M-7050D (7 DI, 8 DO), 2 = M-7060D (4 DI, 4 relays),
3 = M-7017R (8 AI), 4 = M-7024 (4 AO, error_mode value 0), 5 = counter (6 + 2 special bytes).
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from ruamel.yaml import YAML
from test_canopen_profiles import Dut

from fieldgate import load_registry
from fieldgate.topology import TopologyError, load_topology

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "na9161-style.yaml"


class SlotDut(Dut):
    def __init__(self, **front):
        topo = YAML(typ="safe").load(EXAMPLE.read_text())
        cfg = {k: v for k, v in topo["fronts"][0].items() if k not in ("name", "type")}
        super().__init__({**cfg, **front}, backs=topo["backs"])

    def upload(self, index: int, sub: int) -> bytes:
        """Expedited or segmented SDO upload (CiA 301), raw bytes; an abort raises."""
        mux = f"{index & 0xFF:02X} {index >> 8:02X} {sub:02X}"
        first = bytes.fromhex(self.sdo(f"40 {mux} 00 00 00 00"))
        if first[0] == 0x80:
            raise AssertionError(f"abort {struct.unpack_from('<I', first, 4)[0]:08X}")
        if first[0] & 0x02:  # expedited
            return first[4 : 8 - ((first[0] >> 2) & 3)] if first[0] & 1 else first[4:8]
        size, data, toggle = struct.unpack_from("<I", first, 4)[0], b"", 0
        while True:
            seg = bytes.fromhex(self.sdo(f"{0x60 | toggle << 4:02X} 00 00 00 00 00 00 00"))
            data += seg[1 : 8 - ((seg[0] >> 1) & 7)]
            toggle ^= 1
            if seg[0] & 1:
                assert len(data) == size
                return data

    def download(self, index: int, sub: int, data: bytes) -> str:
        """SDO download (expedited up to 4 bytes, else segmented); the last answer."""
        mux = f"{index & 0xFF:02X} {index >> 8:02X} {sub:02X}"
        if len(data) <= 4:
            cs = 0x23 | (4 - len(data)) << 2
            return self.sdo(f"{cs:02X} {mux} {data.ljust(4, bytes(1)).hex(' ')}")
        answer = self.sdo(f"21 {mux} {struct.pack('<I', len(data)).hex(' ')}")
        if not answer.startswith("60"):
            return answer
        toggle = 0
        for n in range(0, len(data), 7):
            chunk = data[n : n + 7]
            last = n + 7 >= len(data)
            cs = toggle << 4 | (7 - len(chunk)) << 1 | int(last)
            answer = self.sdo(f"{cs:02X} {chunk.ljust(7, bytes(1)).hex(' ')}")
            if answer.startswith("80"):
                return answer
            toggle ^= 1
        return answer


@pytest.fixture
def dut():
    return SlotDut()


def test_every_slot_has_a_sub_index(dut):
    for index in (0x2000, 0x2200, 0x4501, 0x4502, 0x4503, 0x4504):
        assert dut.read(index, 0) == f"4F {index & 0xFF:02X} {index >> 8:02X} 00 05 00 00 00"
    assert dut.read(0x2030, 0) == "4F 30 20 00 05 00 00 00"  # the error counters moved here


def test_read_memory_is_the_slot_modules_memory(dut):
    """0x2000:n is the RS-485 module's memory as its back knows it (audit 004 #34): a Modbus
    module has its address, the model as module ID and name, nothing else; 0x4501:n its size."""
    assert dut.upload(0x2000, 3) == (
        bytes([3, 0, 0, 0]) + bytes(4) + struct.pack("<I", 0x7017) + b"M-7017R\0"
    )
    assert dut.upload(0x4501, 3) == struct.pack("<I", 20)
    assert [len(dut.upload(0x2000, n)) for n in range(1, 6)] == [20] * 5
    dut.image.update_input("rs485/m3/ai0", 0x1234)  # the I/O values are not the memory
    assert dut.upload(0x2000, 3)[:4] == bytes([3, 0, 0, 0])


def test_read_memory_of_a_dcon_module_has_its_configuration():
    backs = [
        {
            "name": "rs485",
            "type": "dcon",
            "port": "/dev/ttyUSB0",
            "baudrate": 19200,
            "checksum": True,
            "modules": [{"address": 2, "model": "I-7017", "type_code": 0x08, "data_format": "hex"}],
        }
    ]
    dut = Dut({"node_id": 5, "style": "na9161"}, backs=backs)
    memory = SlotDut.upload(dut, 0x2000, 1)  # type: ignore[arg-type]
    assert memory[:4] == bytes([2, 0x08, 2, 0x01])  # address, type code, hex format, checksum
    assert memory[4:8] == struct.pack("<I", 19200)
    assert memory[8:12] == struct.pack("<I", 0x7017) and memory[12:] == b"I-7017\0\0"


def test_write_memory_sets_a_slots_outputs_at_once(dut):
    assert dut.read(0x2200, 1) == "80 00 22 01 01 00 01 06"  # write-only: 0601 0001
    assert dut.download(0x2200, 1, bytes([0xA5])) == "60 00 22 01 00 00 00 00"
    assert [dut.image.value(f"rs485/m1/do{n}") for n in range(8)] == [
        bool(0xA5 >> n & 1) for n in range(8)
    ]
    values = [100, -100, 0x7FFF, 0]
    answer = dut.download(0x2200, 4, b"".join(struct.pack("<h", v) for v in values))
    assert answer[:2] in ("20", "30")  # segmented (8 bytes), last segment confirmed
    assert [dut.image.value(f"rs485/m4/ao{n}") for n in range(4)] == values
    assert dut.download(0x2200, 4, bytes(6))[:2] == "80"  # 6 of 8 bytes: 0607 0013
    assert dut.download(0x2200, 3, bytes(1)) == "80 00 22 03 30 00 09 06"  # no outputs


def test_slot_configuration_is_the_outputs_fault_action(dut):
    # slot 1 (8 DO, na9161 default: every output to 0) reads hold mask 00, fault values 00
    assert dut.upload(0x4502, 1) == bytes([0x00, 0x00])
    # TV-13: FF 00 = hold the last state on every channel (the 2-byte expedited write)
    assert dut.sdo("2B 02 45 01 FF 00 00 00") == "60 02 45 01 00 00 00 00"
    assert dut.read(0x6206, 1) == "4F 06 62 01 00 00 00 00"  # the same fact as 0x6206
    assert dut.upload(0x4502, 1) == bytes([0xFF, 0x00])
    assert dut.sdo("2F 06 62 01 0F 00 00 00") == "60 06 62 01 00 00 00 00"
    assert dut.sdo("2F 07 62 01 05 00 00 00") == "60 07 62 01 00 00 00 00"
    assert dut.upload(0x4502, 1) == bytes([0xF0, 0x05])
    # slot 4 (4 AO): hold mask, reserved byte, four fault values
    assert dut.upload(0x4502, 4) == bytes([0x00, 0x00]) + bytes(8)
    block = bytes([0b0010, 0]) + b"".join(struct.pack("<h", v) for v in (10, 20, 30, -40))
    assert dut.download(0x4502, 4, block)[:2] in ("20", "30")
    assert dut.read(0x6443, 2) == "4F 43 64 02 00 00 00 00"  # channel 1 holds
    assert dut.read(0x6444, 4) == "43 44 64 04 D8 FF FF FF"  # -40
    assert dut.download(0x4502, 4, block[:-1])[:2] == "80"  # length checked
    assert dut.read(0x4502, 3) == "80 02 45 03 24 00 00 08"  # AI slot: no parameters


def test_catalog_codes(dut):
    codes = [dut.upload(0x4504, n) for n in range(1, 6)]
    assert codes == [
        bytes([0, 0, 0x00, 0xC1]),  # 7 DI + 8 DO: a byte each way
        bytes([0, 0, 0x00, 0xC1]),  # 4 DI + 4 relays
        bytes([0, 0, 0x47, 0x41]),  # 8 AI words
        bytes([0, 0, 0x43, 0x81]),  # 4 AO words
        bytes([0, 0, 0x05, 0xC1]),  # 6 + 2 special bytes
    ]


def test_the_icpdas_style_keeps_0x2000_as_error_counters():
    dut = Dut({"node_id": 2})
    assert dut.read(0x2000, 1) == "4B 00 20 01 00 00 00 00"  # UNSIGNED16 counter
    assert dut.read(0x4504, 0)[:2] == "80"


# -- validate applies run's limits ---------------------------------------------------------
def test_validate_refuses_an_image_run_would_refuse():
    registry = load_registry()
    topo = {
        "gateway": {"name": "big"},
        "fronts": [{"name": "can", "type": "canopen", "node_id": 5, "style": "na9161"}],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": a, "analog": 8} for a in range(1, 6)],  # 80 bytes
            }
        ],
    }
    with pytest.raises(TopologyError) as err:
        load_topology(topo, registry)
    (issue,) = err.value.issues
    assert issue.path == "fronts[0]"
    assert "80 bytes" in issue.message and "64 per direction" in issue.message
    topo["backs"][0]["modules"] = [{"address": a, "digital": 1} for a in range(1, 34)]
    with pytest.raises(TopologyError) as err:
        load_topology(topo, registry)
    assert "33 modules exceed the 32 slots" in err.value.issues[0].message
    topo["fronts"][0]["style"] = "icpdas"  # the I-7232D has no such limit
    assert load_topology(topo, registry).fronts[0].style == "icpdas"
