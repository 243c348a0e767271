import pytest

from fieldgate import load_registry


@pytest.fixture(scope="session")
def registry():
    return load_registry()


def make_topology_dict(**front):
    """A gateway with the test package's ``memory`` front and ``loopback`` back."""
    return {
        "gateway": {"name": "bench"},
        "fronts": [{"name": "plc", "type": "memory", **front}],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [
                    {
                        "address": 3,
                        "digital": 2,
                        "analog": 1,
                        "error_mode": {"value": 1},
                        "shutdown_mode": {"value": 0},
                    },
                    {"address": 1, "digital": 10},
                ],
            }
        ],
    }


@pytest.fixture
def topology_dict():
    return make_topology_dict
