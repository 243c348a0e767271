"""The devicenet front in a Gateway on python-can's virtual bus, driven by a small master."""

from __future__ import annotations

import uuid

import pytest
from dnet_master import Master

from fieldgate import Gateway, load_registry
from fieldgate.plugins.devicenet import plugin as devicenet_plugin
from fieldgate.runtime import GatewayStartError

SLAVE = 5


@pytest.fixture(scope="module")
def registry():
    registry = load_registry()
    if registry.lookup("front", "devicenet") is None:
        registry = load_registry([devicenet_plugin])
    return registry


def topology(tmp_path, channel: str, **front) -> dict:
    return {
        "gateway": {"name": "dnet-test", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "dnet",
                "type": "devicenet",
                "interface": "virtual",
                "channel": channel,
                "mac_id": SLAVE,
                "baudrate": 500000,
                "dup_mac_timeout_ms": 50,
                "identity": {
                    "vendor_id": 803,
                    "serial": 42,
                    "product_name": "fieldgate test slave",
                },
                **front,
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 3, "digital": 8, "analog": 2, "error_mode": {"value": 0}}],
            }
        ],
    }


@pytest.fixture
async def rig(tmp_path, registry):
    channel = f"dnet-{uuid.uuid4().hex[:8]}"
    master = Master(channel, SLAVE)
    gateway = Gateway.load(topology(tmp_path, channel), registry=registry)
    await gateway.start()
    await master.wait_online()
    yield gateway, master
    await gateway.stop()
    master.close()


async def test_allocate_identity_poll_loopback_and_timeout(rig):
    gateway, master = rig
    assert await master.allocate(0x03) == bytes.fromhex("0A CB 00")
    assert await master.request(bytes.fromhex("0E 01 01 01")) == bytes.fromhex("8E 23 03")
    name = await master.request(bytes.fromhex("0E 01 01 07"))  # 22 bytes: fragmented
    assert name == b"\x8e\x14fieldgate test slave"
    assert await master.request(bytes.fromhex("0E 01 01 06")) == bytes.fromhex("8E 2A 00 00 00")
    assert await master.request(bytes.fromhex("10 05 02 09 64 00")) == bytes.fromhex(
        "90 64 00"
    )  # poll EPR 100 ms
    # outputs: DO byte + AO0 + AO1; inputs: DI byte + AI0 + AI1 (the loopback wires DO n to DI n)
    assert await master.poll(bytes.fromhex("A5 34 12 CD AB")) == bytes.fromhex("A5 34 12 CD AB")
    assert gateway.read("io/m3/do0") is True and gateway.read("io/m3/ao1") == -0x5433
    assert await master.poll(bytes.fromhex("0F 01 00 FF 7F")) == bytes.fromhex("0F 01 00 FF 7F")
    assert gateway.masters.is_ok("dnet")
    await master.frames(0.6)  # no polls for more than 4 x 100 ms
    assert not gateway.masters.is_ok("dnet")
    assert gateway.read("io/m3/do0") is False and gateway.read("io/m3/ao1") == 0  # error values
    assert gateway.component("dnet").status()["connections"]["poll"] == {
        "state": "timed_out",
        "epr_ms": 100,
        "produced": 0x69,  # all inputs: DI 0x66 + AI 0x67
        "produced_size": 5,
        "consumed": 0x68,  # all outputs: DO 0x64 + AO 0x65
        "consumed_size": 5,
    }
    assert await master.allocate(0x02) == bytes.fromhex("0A CB 00")  # re-allocation
    assert gateway.masters.is_ok("dnet")
    await master.request(bytes.fromhex("10 05 02 09 64 00"))
    assert await master.poll(bytes.fromhex("01 00 00 00 00")) == bytes.fromhex("01 00 00 00 00")


async def test_change_of_state_follows_the_process_image(rig):
    gateway, master = rig
    assert await master.allocate(0x51) == bytes.fromhex("0A CB 00")  # explicit + COS, no acks
    assert await master.request(bytes.fromhex("10 05 04 09 10 27")) == bytes.fromhex(
        "90 10 27"
    )  # EPR 10 s
    assert await master.expect(0x340 | SLAVE) == bytes(5)
    gateway.write("io/m3/do2", True)  # the loopback sets DI 2: the slave produces at once
    assert await master.expect(0x340 | SLAVE, 1.0) == bytes.fromhex("04 00 00 00 00")
    gateway.write("io/m3/ao0", 300)
    assert await master.expect(0x340 | SLAVE, 1.0) == bytes.fromhex("04 2C 01 00 00")


async def test_unknown_interface_is_a_one_line_start_error(tmp_path, registry):
    gateway = Gateway.load(topology(tmp_path, "x", interface="no-such-can"), registry=registry)
    with pytest.raises(GatewayStartError) as err:
        await gateway.start()
    assert "unknown CAN interface 'no-such-can'" in str(err.value) and "\n" not in str(err.value)


async def test_missing_channel_is_a_start_error(tmp_path, registry):
    gateway = Gateway.load(
        topology(tmp_path, "fieldgate-missing0", interface="socketcan"), registry=registry
    )
    with pytest.raises(GatewayStartError) as err:
        await gateway.start()
    assert "socketcan" in str(err.value) and "\n" not in str(err.value)


async def test_mac_id_set_over_the_network_survives_a_restart_until_the_yaml_changes(
    tmp_path, registry
):
    channel = f"dnet-{uuid.uuid4().hex[:8]}"
    master = Master(channel, SLAVE)
    gateway = Gateway.load(topology(tmp_path, channel), registry=registry)
    await gateway.start()
    try:
        await master.wait_online()
        assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
        assert await master.request(bytes.fromhex("10 03 01 01 06")) == bytes.fromhex("90")
        assert await master.expect(0x42B) == bytes.fromhex(
            "0A CE 03 00 01 00 04 00"
        )  # shutdown from MAC 5
        assert await master.expect(0x437) == bytes.fromhex("00 23 03 2A 00 00 00")  # checking MAC 6
    finally:
        await gateway.stop()
    restarted = Gateway.load(topology(tmp_path, channel), registry=registry)
    await restarted.start()
    try:
        assert await master.expect(0x437) == bytes.fromhex("00 23 03 2A 00 00 00")
        assert restarted.component("dnet").status()["mac_id"] == 6
    finally:
        await restarted.stop()
    edited = Gateway.load(topology(tmp_path, channel, mac_id=7), registry=registry)
    await edited.start()
    try:
        assert await master.expect(0x43F) == bytes.fromhex("00 23 03 2A 00 00 00")  # the YAML wins
    finally:
        await edited.stop()
        master.close()


def test_mac_id_is_required_with_one_line_naming_the_two_defaults(tmp_path, registry):
    """The I-7241D ships at MAC 1, ODVA's default is 63: no silent choice between them."""
    from fieldgate.topology import TopologyError, load_topology

    source = topology(tmp_path, "x")
    del source["fronts"][0]["mac_id"]
    with pytest.raises(TopologyError) as err:
        load_topology(source, registry)
    (issue,) = err.value.issues
    assert issue.path == "fronts[0].mac_id"
    assert issue.message.startswith("required field is missing") and "I-7241D ships at 1" in (
        issue.message
    )


def test_store_ignores_corrupt_and_out_of_range_files(tmp_path):
    from fieldgate.plugins.devicenet.store import NetworkStore

    store = NetworkStore(tmp_path / "s.json", (5, 0))
    assert store.load() is None
    store.save(9, 2)
    assert store.load() == (9, 2)
    assert (
        NetworkStore(tmp_path / "s.json", (5, 1)).load() is None
    )  # written for another configuration
    (tmp_path / "s.json").write_text("{not json")
    assert store.load() is None
    (tmp_path / "s.json").write_text('{"configured": [5, 0], "mac_id": 64, "baud_code": 0}')
    assert store.load() is None


async def test_offline_module_shows_in_the_identity_status(rig):
    from fieldgate.health import ErrorKind, ModuleHealth

    gateway, master = rig
    assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
    try:
        health = gateway.health.get("io", 3)
    except KeyError:
        health = gateway.health.add(ModuleHealth("io", 3))
    assert await master.request(bytes.fromhex("0E 01 01 05")) == bytes.fromhex("8E 01 00")
    for _ in range(5):
        health.record_failure(ErrorKind.TIMEOUT, "no answer")
    assert not health.online
    assert await master.request(bytes.fromhex("0E 01 01 05")) == bytes.fromhex("8E 01 01")
    health.record_success()
    assert await master.request(bytes.fromhex("0E 01 01 05")) == bytes.fromhex("8E 01 00")


async def test_a_baud_change_at_reset_answers_at_the_old_rate_and_checks_the_mac_at_the_new(rig):
    """Identity Reset with a new baud rate pending: the answers leave on the old bus, the duplicate
    MAC ID check on the reopened one (the adapter switches before the check's first request)."""
    gateway, master = rig
    adapter = gateway.component("dnet").adapter
    sent = []  # (bit rate of the bus in use, CAN-ID)
    real_send = adapter.send

    def recording_send(frames, now=None):
        sent.extend((adapter.bus_bitrate, f.can_id) for f in frames)
        real_send(frames, now)

    adapter.bus_bitrate = 500_000
    real_reopen = adapter.reopen

    def reopen(rate):
        adapter.bus_bitrate = rate
        return real_reopen(rate)

    adapter.reopen, adapter.send = reopen, recording_send
    assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
    assert await master.request(bytes.fromhex("10 03 01 02 00")) == bytes.fromhex(
        "90"
    )  # baud 125k, pending
    assert await master.request(bytes.fromhex("05 01 01 00")) == bytes.fromhex(
        "85"
    )  # Identity Reset
    await master.frames(0.1)
    dup_mac = 0x400 | SLAVE << 3 | 7
    explicit_response = 0x400 | SLAVE << 3 | 3
    assert (500_000, explicit_response) in sent
    dup_mac_rates = [rate for rate, can_id in sent if can_id == dup_mac]
    assert dup_mac_rates and set(dup_mac_rates) == {125_000}, sent
    assert adapter.counters["bit_timing_switches"] == 1


async def test_a_poll_request_is_one_image_batch(rig):
    """The outputs of one poll request reach the image (and the back) as one batch."""
    gateway, master = rig
    batches = []
    gateway.image.subscribe_batch(batches.append, ids=[f"io/m3/do{i}" for i in range(8)])
    assert await master.allocate(0x03) == bytes.fromhex("0A CB 00")
    await master.request(bytes.fromhex("10 05 02 09 64 00"))  # poll EPR 100 ms
    assert await master.poll(bytes.fromhex("81 00 00 00 00")) == bytes.fromhex("81 00 00 00 00")
    assert [[(c.id, c.value, c.origin) for c in b] for b in batches] == [
        [("io/m3/do0", True, "dnet:devicenet"), ("io/m3/do7", True, "dnet:devicenet")]
    ]


async def test_a_reply_changing_many_inputs_gives_one_change_of_state_message(rig):
    """A back's reply that changes several inputs is one batch: one COS message carries
    them all (per-channel writes produced one message per bit, the first with one bit)."""
    gateway, master = rig
    assert await master.allocate(0x51) == bytes.fromhex("0A CB 00")  # explicit + COS, no acks
    await master.request(bytes.fromhex("10 05 04 09 10 27"))  # EPR 10 s, no inhibit time
    assert await master.expect(0x340 | SLAVE) == bytes(5)
    gateway.image.update_inputs({f"io/m3/di{i}": True for i in range(1, 7)})
    cos = [m for m in await master.frames(0.3) if m.arbitration_id == 0x340 | SLAVE]
    assert [bytes(m.data) for m in cos] == [bytes.fromhex("7E 00 00 00 00")]
