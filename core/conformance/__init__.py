"""An open, device-agnostic CANopen conformance test tool.

The device is a black box: the suite talks to it on a python-can bus and reads its EDS.
See docs/conformance.md. Programmatic use::

    from fieldgate.conformance import SuiteConfig, run_suite
    results = run_suite(SuiteConfig(node_id=5, eds="dev.eds"), interface="socketcan", channel="can0")
"""

from .dnet import DnetSuiteConfig, run_devicenet_suite
from .framework import CASES, PROFILES, Case, CaseResult, Options, Timing, Verdict, select
from .runner import DeviceSilent, SuiteConfig, failed, run_suite

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
