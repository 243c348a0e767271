"""An open, device-agnostic CANopen and DeviceNet conformance test tool.

The device is a black box: the suite talks to it on a python-can bus and reads its EDS.
See docs/conformance.md. Programmatic use::

    from fieldgate.conformance import SuiteConfig, run_suite
    results = run_suite(SuiteConfig(node_id=5, eds="dev.eds"), interface="socketcan", channel="can0")
"""

from .catalog import select
from .framework import CASES, PROFILES, Case, CaseResult, Options, Timing, Verdict
from .outcome import DeviceSilent
from .runner import DnetSuiteConfig, SuiteConfig, failed, run_devicenet_suite, run_suite

__all__ = [
    "CASES",
    "DeviceSilent",
    "DnetSuiteConfig",
    "run_devicenet_suite",
    "PROFILES",
    "Case",
    "CaseResult",
    "Options",
    "SuiteConfig",
    "Timing",
    "Verdict",
    "failed",
    "run_suite",
    "select",
]
