"""The OPC UA tests share one process: the asyncua log budget (one per process, as in a
front's child, plugins/opcua/logs.py) starts empty for each test, so no test's log lines
depend on what the tests before it logged."""

import pytest

from fieldgate.plugins.opcua import logs


@pytest.fixture(autouse=True)
def fresh_log_budget():
    logs._FILTER.budget = logs.LogBudget()
    yield
