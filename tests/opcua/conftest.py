"""The OPC UA tests share one process: the asyncua log budget (one per process, as in a
front's child, plugins/opcua/logs.py) starts empty for each test, and asyncua's logger levels
are the front's, so no test's log lines depend on what the tests before it logged or set (a
fault probe run earlier in the same pytest process quieted asyncua's client)."""

import logging

import pytest

from fieldgate.plugins.opcua import logs


@pytest.fixture(autouse=True)
def fresh_log_budget():
    logs._FILTER.budget = logs.LogBudget()
    manager = logging.getLogger().manager
    names = ["asyncua"] + [n for n in manager.loggerDict if n.startswith("asyncua.")]
    levels = {name: logging.getLogger(name).level for name in names}
    logging.getLogger("asyncua").setLevel(logging.WARNING)  # as the front sets it at import
    for name in names[1:]:
        logging.getLogger(name).setLevel(logging.NOTSET)
    yield
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)
