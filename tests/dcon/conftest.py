"""The DCON tests' gateway: the test fixtures fieldgate ships (``fieldgate.testing``)."""

import pytest

from fieldgate.testing import wait_until


@pytest.fixture(scope="session")
def dcon_registry(fieldgate_registry):
    return fieldgate_registry


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


async def wait_for(predicate, timeout=3.0):
    await wait_until(predicate, timeout)


@pytest.fixture(name="wait_for")
def wait_for_fixture():
    return wait_for


@pytest.fixture
def gateway(fieldgate_gateway):
    """``async with gateway(modules, **back) as gw``: a running gateway on simulated modules."""

    def make(modules, animate=False, **back):
        return fieldgate_gateway(topology(modules, **back), animate=animate)

    return make
