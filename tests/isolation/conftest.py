import pytest

from fieldgate.plugin import load_registry


@pytest.fixture(scope="session")
def registry():
    return load_registry()
