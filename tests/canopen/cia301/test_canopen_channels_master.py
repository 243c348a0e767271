"""The canopen library as master on a second SDO channel (0x1201) and as TIME producer.

Two clients on one bus, as with a PLC plus a configuration tool: the first configures
0x1201 over 0x1200, then both transfer at the same time, each on its own channel.
"""

from __future__ import annotations

import struct
import threading
from datetime import UTC, datetime

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from canopen_dut import BOOT_TIMEOUT, FRONT, bus_under_test, make_dut, topology

NODE = 5
RX, TX = 0x680 + NODE, 0x6A0 + NODE  # outside the restricted CAN-IDs


@pytest.fixture
def master(tmp_path):
    interface, channel, external = bus_under_test()
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface=interface, channel=channel)
    booted = threading.Event()
    network.subscribe(0x700 + NODE, lambda *_: booted.set())
    dut = make_dut(
        topology(tmp_path / "state", NODE, sdo_servers=2, heartbeat_ms=0),
        interface,
        channel,
        external,
        tmp_path,
    )
    dut.start()
    assert booted.wait(BOOT_TIMEOUT), "no boot-up"
    node = network.add_node(canopen.RemoteNode(NODE, canopen.ObjectDictionary()))
    node.sdo.RESPONSE_TIMEOUT = 1.0
    yield network, node, dut, external
    dut.stop()
    network.disconnect()


def test_second_sdo_channel_with_the_canopen_master(master):
    network, node, dut, _ = master
    second = node.add_sdo(RX, TX)
    second.network = (
        network  # canopen 2.4.1's add_sdo subscribes the channel but does not give it the network
    )
    second.RESPONSE_TIMEOUT = 0.2
    with pytest.raises(SdoCommunicationError):  # not configured yet: silent, the client times out
        second.upload(0x1000, 0)
    second.RESPONSE_TIMEOUT = 1.0
    node.sdo.download(0x1201, 1, struct.pack("<I", RX))
    node.sdo.download(0x1201, 2, struct.pack("<I", TX))
    with pytest.raises(SdoAbortedError) as err:  # valid: the CAN-ID cannot change
        node.sdo.download(0x1201, 1, struct.pack("<I", RX + 1))
    assert err.value.code == 0x06090030

    assert second.upload(0x1018, 1) == struct.pack("<I", 0xABCD)  # expedited
    assert second.upload(0x1008, 0) == b"fieldgate test node"  # segmented
    with second.open(0x1008, 0, "rb", block_transfer=True, request_crc_support=True) as f:
        assert f.read() == b"fieldgate test node"
    second.download(0x1017, 0, struct.pack("<H", 0))

    errors: list[BaseException] = []

    def hammer(client, guard_time: int | None) -> None:
        try:
            for _ in range(25):
                if guard_time is not None:
                    client.download(0x100C, 0, struct.pack("<H", guard_time))
                assert client.upload(0x1018, 4) == struct.pack("<I", 42)
                assert client.upload(0x1008, 0) == b"fieldgate test node"
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [
        threading.Thread(target=hammer, args=(node.sdo, None)),
        threading.Thread(target=hammer, args=(second, 300)),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors, errors
    assert struct.unpack("<H", node.sdo.upload(0x100C, 0))[0] == 300

    second.download(0x1201, 1, struct.pack("<I", 0x80000000 | RX))  # switches itself off, confirmed
    second.RESPONSE_TIMEOUT = 0.2
    with pytest.raises(SdoCommunicationError):
        second.upload(0x1000, 0)
    assert node.sdo.upload(0x1201, 1) == struct.pack("<I", 0x80000000 | RX)


def test_time_from_the_canopen_time_producer(master):
    network, node, dut, external = master
    if external:
        pytest.skip("reads the TIME service inside the gateway process")
    when = datetime(2026, 11, 22, 7, 38, 54, 250000, tzinfo=UTC)
    received = threading.Event()
    dut.call(
        lambda: dut.gateway.component(FRONT).node.service("time").on_time(lambda _: received.set())
    )
    network.time.transmit(when.timestamp())
    assert received.wait(3)
    status = dut.call(lambda: dut.gateway.status()["fronts"][FRONT]["services"]["time"])
    assert status["last"] == when and status["received"] == 1
