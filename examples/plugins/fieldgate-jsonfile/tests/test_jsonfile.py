"""The jsonfile back, tested with the fixtures fieldgate installs (fieldgate.testing)."""

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from fieldgate_jsonfile.simulator import JsonFileSimulator

from fieldgate import Gateway, Quality, Registry
from fieldgate.testing import wait_for_channel, wait_until
from fieldgate.topology import TopologyError, load_topology

LAB = Path(__file__).resolve().parents[1] / "lab.yaml"
GatewayFactory = Callable[..., Gateway]  # the fieldgate_gateway fixture


def simulator(gw: Gateway) -> JsonFileSimulator:
    """The simulator serving the bench (the fixture's gateways run with simulate=True)."""
    assert gw.bench is not None
    served = gw.bench.simulator("bench")
    assert isinstance(served, JsonFileSimulator)
    return served


async def test_inputs_in_the_file_reach_the_process_image(
    fieldgate_gateway: GatewayFactory,
) -> None:
    async with fieldgate_gateway(LAB) as gw:  # simulate=True: the back reads the simulator's file
        simulator(gw).set_input("bench/m1/ai1", -1234)
        simulator(gw).set_input("bench/m1/di2", True)
        await wait_for_channel(gw.image, "bench/m1/ai1", -1234)
        await wait_for_channel(gw.image, "bench/m1/di2", True)


async def test_outputs_a_front_writes_are_written_to_the_outputs_file(
    fieldgate_gateway: GatewayFactory,
) -> None:
    async with fieldgate_gateway(LAB) as gw:
        gw.write("bench/m2/do1", True)  # as a front would
        await wait_until(lambda: simulator(gw).get_output("bench/m2/do1") is True)
        written = json.loads(simulator(gw).outputs_path.read_text())["modules"]["2"]["do"]
        assert written == [None, True]  # do0: no front has set it, so no value is invented


async def test_a_missing_file_is_stale_then_comm_fault_and_an_outside_value_over_range(
    fieldgate_gateway: GatewayFactory,
) -> None:
    async with fieldgate_gateway(LAB) as gw:
        simulator(gw).set_input("bench/m1/ai0", 70000)  # more than an int16 holds
        await wait_for_channel(gw.image, "bench/m1/ai0", 32767, Quality.OVER_RANGE)
        simulator(gw).remove_inputs()
        await wait_for_channel(gw.image, "bench/m1/ai0", 32767, Quality.COMM_FAULT)
        assert not gw.health.get("bench", 1).online


def test_a_module_without_channels_is_one_error_with_its_line(fieldgate_registry: Registry) -> None:
    no_channels = {"backs.bench.modules.0.di": 0, "backs.bench.modules.0.ai": 0}  # as --set does
    with pytest.raises(TopologyError) as error:
        load_topology(LAB, fieldgate_registry, no_channels)
    (issue,) = error.value.issues
    assert (
        str(issue)
        == f"{LAB}:21:9: backs[0].modules[0]: a module needs channels: give di, ai, do or ao"
    )
