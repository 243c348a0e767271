"""Client writes acknowledged only once applied (plugins/opcua/writes.py; issue 29 item 3).

The front writes through ``context.set_outputs``, which in a north-facing child is a round
trip to the fieldbus process; here it is wrapped to hold, refuse or fail the way that
process can, and the Write response is watched from a client (asyncua's, in the test)."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from typing import Any

import pytest
import pytest_asyncio
from asyncua import Client, ua
from netkit import free_port, wait_until

from fieldgate import Gateway, Quality, load_registry
from fieldgate.image import DataType
from fieldgate.plugins.opcua.writes import WriteTarget, _checked
from fieldgate.testing import in_this_process

# the tests stand in for the fieldbus side (a context whose set_outputs they control): the
# front is built in this process (every gateway runs it in a child process of its own; the
# cross-process write path: tests/isolation, tests/opcua/test_opcua_client.py)
REGISTRY = in_this_process(load_registry(), "opcua")
pytestmark = pytest.mark.asyncio(loop_scope="module")


class FieldbusSide:
    """``set_outputs`` as the front sees it: applies (or not), holds, refuses, fails."""

    def __init__(self, real: Any):
        self.real = real
        self.calls: list[dict[str, Any]] = []
        self.gate: asyncio.Event | None = None
        self.refuse: set[str] = set()
        self.fail: BaseException | None = None
        self.apply = True

    async def __call__(self, values: Mapping[str, Any], origin: str) -> None:
        self.calls.append(dict(values))
        if self.gate is not None:
            await self.gate.wait()
        if self.fail is not None:
            raise self.fail
        bad = self.refuse & set(values)
        if bad:
            raise ValueError(f"{sorted(bad)[0]} is an output the front may not write")
        if self.apply:
            await self.real(values, origin)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def gateway(tmp_path_factory):
    port = free_port()
    topology = {
        "gateway": {"name": "cell", "state_dir": str(tmp_path_factory.mktemp("state"))},
        "fronts": [
            {
                "name": "ua",
                "type": "opcua",
                "listen": f"127.0.0.1:{port}",
                "writable": ["rs485/m4/ao0", "rs485/m4/ao1", "rs485/m3/do0"],
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 50,
                "timeout_ms": 50,
                "modules": [
                    {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
                    {"address": 4, "model": "M-7024", "counts": {"ao": 2}},
                ],
            }
        ],
    }
    gw = Gateway.load(topology, registry=REGISTRY, simulate=True)
    side = FieldbusSide(gw.context.set_outputs)
    gw.context.set_outputs = side  # type: ignore[method-assign]
    gw.port = port  # type: ignore[attr-defined]
    gw.side = side  # type: ignore[attr-defined]
    await gw.start()
    await wait_until(lambda: gw.image["rs485/m4/ao0"].quality is Quality.GOOD)
    try:
        yield gw
    finally:
        await gw.stop()


@pytest_asyncio.fixture(loop_scope="module")
async def client(gateway):
    side: FieldbusSide = gateway.side
    side.calls.clear()
    side.gate, side.refuse, side.fail, side.apply = None, set(), None, True
    ua_client = Client(f"opc.tcp://127.0.0.1:{gateway.port}/", timeout=10)
    await ua_client.connect()
    ua_client.idx = await ua_client.get_namespace_index("urn:fieldgate:cell")  # type: ignore[attr-defined]
    try:
        yield ua_client
    finally:
        await ua_client.disconnect()


def node(client: Client, cid: str) -> Any:
    return client.get_node(ua.NodeId(cid, client.idx))  # type: ignore[attr-defined]


def int16(value: int) -> ua.DataValue:
    return ua.DataValue(ua.Variant(value, ua.VariantType.Int16))


async def write(client: Client, values: dict[str, ua.DataValue]) -> list[int]:
    params = ua.WriteParameters()
    for cid, dv in values.items():
        params.NodesToWrite.append(
            ua.WriteValue(
                NodeId=node(client, cid).nodeid, AttributeId=ua.AttributeIds.Value, Value=dv
            )
        )
    return [s.value for s in await client.uaclient.write(params)]


async def test_the_write_is_answered_only_once_the_fieldbus_side_applied_it(gateway, client):
    side: FieldbusSide = gateway.side
    side.gate = asyncio.Event()
    answer = asyncio.ensure_future(write(client, {"rs485/m4/ao0": int16(321)}))
    await asyncio.sleep(0.3)
    assert not answer.done() and side.calls == [{"rs485/m4/ao0": 321}]
    assert gateway.read("rs485/m4/ao0") != 321
    side.gate.set()
    assert await answer == [0]
    assert gateway.read("rs485/m4/ao0") == 321 and gateway.image["rs485/m4/ao0"].written_by == "ua"


async def test_one_write_request_is_one_batch(gateway, client):
    assert await write(
        client,
        {
            "rs485/m4/ao0": int16(11),
            "rs485/m4/ao1": int16(22),
            "rs485/m3/do0": ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)),
        },
    ) == [0, 0, 0]
    assert gateway.side.calls == [{"rs485/m4/ao0": 11, "rs485/m4/ao1": 22, "rs485/m3/do0": True}]


async def test_a_value_the_fieldbus_side_refuses_costs_only_itself(gateway, client):
    side: FieldbusSide = gateway.side
    side.refuse = {"rs485/m4/ao1"}
    before = gateway.component("ua").counters["write_errors"]
    codes = await write(client, {"rs485/m4/ao0": int16(5), "rs485/m4/ao1": int16(6)})
    assert codes == [0, ua.StatusCodes.BadNotWritable]
    assert gateway.read("rs485/m4/ao0") == 5 and gateway.read("rs485/m4/ao1") != 6
    assert gateway.component("ua").counters["write_errors"] == before + 1


async def test_the_fieldbus_side_unreachable_is_a_communication_error(gateway, client):
    gateway.side.fail = ConnectionError("the fieldbus process is gone")
    codes = await write(client, {"rs485/m4/ao0": int16(77)})
    assert codes == [ua.StatusCodes.BadCommunicationError] and gateway.read("rs485/m4/ao0") != 77


async def test_the_node_shows_an_applied_value_at_once(gateway, client):
    """In a child, the image change comes back later; a Read right after the Write response
    already sees the value the fieldbus side applied."""
    gateway.side.apply = False  # the mirror has not caught up yet
    assert await write(client, {"rs485/m4/ao1": int16(-999)}) == [0]
    assert await node(client, "rs485/m4/ao1").read_value() == -999


@pytest.mark.parametrize(
    ("dv", "code"),
    [
        (ua.DataValue(ua.Variant(1.5, ua.VariantType.Double)), ua.StatusCodes.BadTypeMismatch),
        (ua.DataValue(ua.Variant([1, 2], ua.VariantType.Int16)), ua.StatusCodes.BadTypeMismatch),
        (
            ua.DataValue(
                ua.Variant(1, ua.VariantType.Int16),
                ua.StatusCode(ua.StatusCodes.BadNoCommunication),
            ),
            ua.StatusCodes.BadWriteNotSupported,
        ),
    ],
)
async def test_values_refused_before_the_fieldbus_side(gateway, client, dv, code):
    assert await write(client, {"rs485/m4/ao0": dv}) == [code]
    assert gateway.side.calls == []


async def test_other_writes_keep_asyncuas_answers(gateway, client):
    params = ua.WriteParameters()
    params.NodesToWrite.append(
        ua.WriteValue(
            NodeId=node(client, "rs485/m4/ao0").nodeid,
            AttributeId=ua.AttributeIds.Description,
            Value=ua.DataValue(ua.Variant(ua.LocalizedText("x"))),
        )
    )
    assert [s.value for s in await client.uaclient.write(params)] == [
        ua.StatusCodes.BadUserAccessDenied
    ]
    assert await write(client, {"rs485/m3/do1": ua.DataValue(ua.Variant(True))}) == [
        ua.StatusCodes.BadUserAccessDenied
    ]
    assert gateway.side.calls == []


async def test_a_value_outside_the_channels_type_is_out_of_range():
    target = WriteTarget("rs485/m4/ao0", ua.VariantType.Int16, DataType.INT16)
    wv = ua.WriteValue(Value=ua.DataValue(ua.Variant(40_000, ua.VariantType.Int16)))
    assert _checked(wv, target) == (ua.StatusCodes.BadOutOfRange, False)
    wv = ua.WriteValue(Value=ua.DataValue(ua.Variant(-5, ua.VariantType.Int16)), IndexRange="1")
    assert _checked(wv, target)[0] == ua.StatusCodes.BadIndexRangeInvalid
    bool_target = WriteTarget("rs485/m3/do0", ua.VariantType.Boolean, DataType.BOOL)
    ok = ua.WriteValue(Value=ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
    assert _checked(ok, bool_target) == (None, True)
