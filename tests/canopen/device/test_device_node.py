"""The EDS device's node (plugins/canopen/device/node.py) driven frame by frame with a fake
clock, its hooks run by hand (ManualRunner): what the file configures, DCF values, hidden
engine objects, hooks deferring SDO answers, a slow hook stalling nothing else, store and
dynamic mapping as the file allows."""

from __future__ import annotations

from pathlib import Path

import pytest
from canopen_rig import Rig, show

from fieldgate.plugins.canopen.device.hooks import ManualRunner
from fieldgate.plugins.canopen.device.node import DeviceNode
from fieldgate.plugins.canopen.device.odfile import DeviceFileError, read_device_file

REPO = Path(__file__).resolve().parents[3]
BATTERY = REPO / "examples" / "canopen-device" / "battery.eds"
SECOND_SDO_CHANNEL = """
[1201]
ParameterName=SDO server parameter 2
ObjectType=0x9
SubNumber=3

[1201sub0]
ParameterName=Highest sub-index supported
ObjectType=0x7
DataType=0x0005
AccessType=const
DefaultValue=2
PDOMapping=0

[1201sub1]
ParameterName=COB-ID client to server
ObjectType=0x7
DataType=0x0007
AccessType=rw
DefaultValue=$NODEID+0x640
PDOMapping=0

[1201sub2]
ParameterName=COB-ID server to client
ObjectType=0x7
DataType=0x0007
AccessType=rw
DefaultValue=$NODEID+0x5C0
PDOMapping=0
"""


def variant(tmp_path: Path, name: str, edit=lambda text: text) -> Path:
    path = tmp_path / name
    path.write_text(edit(BATTERY.read_text()))
    return path


class Device:
    """A battery pack at node 5 with test hooks: reads of 0x2000 give 1000 + sub, writes to
    0x2100 are refused for 55 (0800 0022), writes to 0x2101 are recorded."""

    def __init__(self, path: Path = BATTERY, hooks: bool = True, **options):
        self.runner = ManualRunner()
        self.written: list[tuple[int, int, int]] = []
        self.rig: Rig | None = None
        self.dev = DeviceNode(
            read_device_file(path),
            5,
            runner=self.runner,
            setup=self.setup if hooks else None,
            clock=lambda: self.rig.now if self.rig else 0.0,
            **options,
        )
        self.api = self.dev.api
        self.dev.node.service("store").load()
        self.rig = Rig(self.dev.node)

    def setup(self, device) -> None:
        device.on_read(0x2000)(lambda index, sub: 1000 + sub)

        @device.on_write(0x2100)
        def limit(index, sub, value):
            if value == 55:
                raise device.Refuse(0x08000022)

        @device.on_write(0x2101)
        def contactor(index, sub, value):
            self.written.append((index, sub, value))

    def sdo(self, request: str, cob: int = 0x605) -> list[str]:
        return self.rig.send(f"{cob:03X} {request}")

    def flush(self) -> list[str]:
        return show(self.dev.node.flush())


@pytest.fixture
def device():
    return Device()


def test_the_file_configures_identity_cob_ids_and_hides_what_it_does_not_list(device):
    assert device.rig.boot == ["705 00"]
    assert device.sdo("40 18 10 01 00 00 00 00") == ["585 43 18 10 01 CE 0A 00 00"]
    assert device.sdo("40 14 10 00 00 00 00 00") == ["585 43 14 10 00 85 00 00 00"]  # $NODEID+0x80
    assert device.sdo("40 00 21 00 00 00 00 00") == ["585 4F 00 21 00 5A 00 00 00"]  # default 90
    hidden = device.dev.node.od.hidden
    assert 0x1012 in hidden  # the TIME consumer's object: the file has none
    assert device.sdo("40 12 10 00 00 00 00 00") == ["585 80 12 10 00 00 00 02 06"]
    # the file's limits: 20..100
    assert device.sdo("2F 00 21 00 13 00 00 00") == ["585 80 00 21 00 32 00 09 06"]


def test_a_dcf_parameter_value_replaces_the_eds_default(tmp_path):
    def configure(text: str) -> str:
        text = text.replace(
            "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\n"
            "AccessType=rw\nDefaultValue=0\n",
            "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\n"
            "AccessType=rw\nDefaultValue=0\nParameterValue=500\n",
        )
        return text + "\n[DeviceComissioning]\nNodeID=5\nBaudrate=250\n"

    dcf = variant(tmp_path, "battery.dcf", configure)
    assert "ParameterValue=500" in dcf.read_text()
    device = Device(dcf, hooks=False)
    assert device.rig.advance(0.5) == ["705 7F"]  # heartbeat every 500 ms from the DCF


def test_a_broken_file_is_one_line_naming_it(tmp_path):
    bad = tmp_path / "bad.eds"
    bad.write_text("[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007\n")
    with pytest.raises(DeviceFileError, match="bad.eds"):
        read_device_file(bad)


def test_an_upload_waits_for_its_read_hook_and_the_value_stays_for_tpdos(device):
    assert device.sdo("40 00 20 01 00 00 00 00") == []  # the hook runs first
    assert len(device.runner.jobs) == 1
    device.runner.run()
    assert device.flush() == ["585 4B 00 20 01 E9 03 00 00"]  # 1001
    device.rig.send("000 01 05")
    # TPDO1 (SYNC) maps 0x2000:1..4: the value the hook gave, the file's defaults for the rest
    assert device.rig.send("080") == ["185 E9 03 00 00 50 FA 00"]
    # the receive thread never runs a hook: it leaves hooked entries to the loop
    assert device.dev.node.quick_answer(0x605, bytes.fromhex("4000200100000000"), 0.0) is None


def test_a_write_hook_refuses_with_its_abort_code_and_the_value_stays(device):
    assert device.sdo("2F 00 21 00 37 00 00 00") == []
    device.runner.run()
    assert device.flush() == ["585 80 00 21 00 22 00 00 08"]
    assert device.dev.node.od.get(0x2100) == 90
    assert device.sdo("2F 00 21 00 3C 00 00 00") == []
    device.runner.run()
    assert device.flush() == ["585 60 00 21 00 00 00 00 00"]
    assert device.dev.node.od.get(0x2100) == 60


def test_a_hook_past_its_timeout_aborts_and_its_late_outcome_is_dropped(device):
    assert device.sdo("2F 00 21 00 3D 00 00 00") == []
    assert device.rig.advance(0.49) == []
    assert device.rig.advance(0.02) == ["585 80 00 21 00 20 00 00 08"]  # 0800 0020
    device.runner.run()  # the hook returns at last
    assert device.flush() == []
    assert device.dev.node.od.get(0x2100) == 90
    assert device.sdo("40 00 20 02 00 00 00 00") == []
    assert device.rig.advance(0.51) == ["585 80 00 20 02 24 00 00 08"]  # 0800 0024: no data


def test_a_slow_hook_stalls_no_other_sdo_channel_pdo_or_heartbeat(tmp_path):
    device = Device(variant(tmp_path, "two-channels.eds", lambda t: t + SECOND_SDO_CHANNEL))
    device.rig.send("000 01 05")
    assert device.sdo("2B 17 10 00 64 00 00 00") == ["585 60 17 10 00 00 00 00 00"]
    assert device.sdo("2F 00 21 00 3C 00 00 00") == []  # the hook is busy (never run yet)
    assert device.rig.send("080") == ["185 80 BB 00 00 50 FA 00"]  # TPDO1 at once
    assert device.sdo("40 18 10 02 00 00 00 00", cob=0x645) == ["5C5 43 18 10 02 48 42 00 00"]
    assert device.rig.advance(0.1) == ["705 05"]  # heartbeat on time
    device.api.set(0x2000, 3, 42)  # the application's own value, from outside the bus path
    assert device.rig.send("080") == ["185 80 BB 00 00 2A FA 00"]
    device.runner.run()  # the slow hook returns: its answer now
    assert device.flush() == ["585 60 00 21 00 00 00 00 00"]


def test_a_new_request_of_the_client_ends_its_wait_and_is_served(device):
    assert device.sdo("2F 00 21 00 3C 00 00 00") == []
    assert device.sdo("40 00 21 00 00 00 00 00") == ["585 4F 00 21 00 5A 00 00 00"]
    device.runner.run()
    assert device.flush() == []  # nobody waits for it any more
    assert device.dev.node.service("sdo").status()["deferred_dropped"] == 1


def test_an_rpdo_is_taken_at_once_and_its_write_hook_learns_of_it_after(device):
    device.rig.send("000 01 05")
    assert device.rig.send("205 01") == []
    assert device.dev.node.od.get(0x2101) == 1
    assert device.written == []
    device.runner.run_all()
    assert device.written == [(0x2101, 0, 1)]


def test_hooks_send_event_tpdos_and_emcys(device):
    device.rig.send("000 01 05")
    device.api.set(0x2101, 0, 1)  # TPDO2 (type 254) maps 0x2101 and 0x1001
    assert device.rig.advance(0) == ["285 01 00"]  # (the node's next run: the adapter's wake-up)
    device.api.raise_emcy(0x4210, 0x09)
    frames = device.flush()
    assert frames[0] == "085 10 42 09 00 00 00 00 00"
    device.api.clear_emcy(0x4210)
    assert device.flush()[0] == "085 00 00 00 00 00 00 00 00"


def test_store_keeps_communication_and_application_values_over_a_reset(tmp_path):
    device = Device(hooks=False, store_path=tmp_path / "store.json")
    assert device.sdo("2B 17 10 00 C8 00 00 00") == ["585 60 17 10 00 00 00 00 00"]
    assert device.sdo("2F 00 21 00 4D 00 00 00") == ["585 60 00 21 00 00 00 00 00"]
    assert device.sdo("2F 00 18 02 FE 00 00 00") == ["585 60 00 18 02 00 00 00 00"]
    assert device.sdo("23 10 10 01 73 61 76 65") == ["585 60 10 10 01 00 00 00 00"]
    again = Device(hooks=False, store_path=tmp_path / "store.json")  # a power cycle
    assert again.sdo("40 00 21 00 00 00 00 00") == ["585 4F 00 21 00 4D 00 00 00"]
    assert again.sdo("40 17 10 00 00 00 00 00") == ["585 4B 17 10 00 C8 00 00 00"]
    assert again.sdo("40 00 18 02 00 00 00 00") == ["585 4F 00 18 02 FE 00 00 00"]


def test_ram_entries_are_not_stored(tmp_path):
    def ram(text: str) -> str:
        return text.replace(
            "[2100]\nParameterName=Charge limit percent\n",
            "[2100]\nParameterName=Charge limit percent\nStorageLocation=RAM\n",
        )

    path = variant(tmp_path, "ram.eds", ram)
    device = Device(path, hooks=False, store_path=tmp_path / "store.json")
    assert device.sdo("2F 00 21 00 4D 00 00 00") == ["585 60 00 21 00 00 00 00 00"]
    assert device.sdo("23 10 10 01 73 61 76 65") == ["585 60 10 10 01 00 00 00 00"]
    again = Device(path, hooks=False, store_path=tmp_path / "store.json")
    assert again.sdo("40 00 21 00 00 00 00 00") == ["585 4F 00 21 00 5A 00 00 00"]


def test_mapping_is_dynamic_where_the_file_allows_it(tmp_path):
    device = Device(hooks=False)
    assert device.sdo("2F 00 1A 00 00 00 00 00") == ["585 60 00 1A 00 00 00 00 00"]
    assert device.sdo("23 00 1A 01 08 00 00 21") == ["585 80 00 1A 01 41 00 04 06"]  # not mappable
    assert device.sdo("23 00 1A 01 08 00 01 21") == ["585 60 00 1A 01 00 00 00 00"]
    assert device.sdo("2F 00 1A 00 01 00 00 00") == ["585 60 00 1A 00 00 00 00 00"]

    def static(text: str) -> str:
        head = "[1A00sub0]\nParameterName=Highest sub-index supported\nObjectType=0x7\nDataType=0x0005\n"
        return text.replace(head + "AccessType=rw\n", head + "AccessType=const\n")

    fixed = Device(variant(tmp_path, "static.eds", static), hooks=False)
    assert fixed.sdo("2F 00 1A 00 00 00 00 00") == ["585 80 00 1A 00 02 00 01 06"]  # read-only


def test_an_unconfigured_device_waits_for_lss_and_answers_with_the_files_identity():
    runner = ManualRunner()
    dev = DeviceNode(read_device_file(BATTERY), None, runner=runner, serial=0xBEEF)
    dev.node.service("store").load()
    rig = Rig(dev.node)
    assert rig.boot == []  # silent until it has a node-ID
    rig.send("7E5 04 01 00 00 00 00 00 00")  # switch state global: configuration
    assert rig.send("7E5 5A 00 00 00 00 00 00 00") == ["7E4 5A CE 0A 00 00 00 00 00"]  # vendor
    assert rig.send("7E5 5D 00 00 00 00 00 00 00") == ["7E4 5D EF BE 00 00 00 00 00"]  # serial
    assert rig.send("7E5 11 07 00 00 00 00 00 00") == ["7E4 11 00 00 00 00 00 00 00"]
    assert rig.send("7E5 04 00 00 00 00 00 00 00") == ["707 00"]  # boots up as node 7
    assert rig.send("607 40 14 10 00 00 00 00 00") == ["587 43 14 10 00 87 00 00 00"]
