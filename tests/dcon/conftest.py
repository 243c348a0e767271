import asyncio

import pytest

from fieldgate import Gateway, load_registry


@pytest.fixture(scope="session")
def dcon_registry():
    return load_registry()


def topology(modules, **back):
    """A gateway: the test package's ``memory`` front, one ``dcon`` back (short timeouts for tests)."""
    settings = {"timeout_ms": 150, "poll_ms": 10, "offline_probe_ms": 100, **back}
    return {
        "gateway": {"name": "dcon-test"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {"name": "rs485", "type": "dcon", "port": "simulated", **settings, "modules": modules}
        ],
    }


async def wait_for(predicate, timeout=3.0, step=0.01):
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError("condition not reached in time")
        await asyncio.sleep(step)


@pytest.fixture(name="wait_for")
def wait_for_fixture():
    return wait_for


@pytest.fixture
def gateway(dcon_registry):
    """``async with gateway(modules, **back) as gw``: a running gateway on simulated modules."""

    def make(modules, animate=False, **back):
        return Gateway.load(
            topology(modules, **back), registry=dcon_registry, simulate=True, animate=animate
        )

    return make
