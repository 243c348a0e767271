"""Cases, profiles, the case registry and the loop that runs cases.

A case is a function ``fn(ctx)`` registered with :func:`case`. It passes by returning,
fails by raising :class:`Fail` (say what was expected and what was seen, and the clause),
skips by raising :class:`Skip` (say why: "EDS lists no 0x1016"), gives no verdict by raising
:class:`Inconclusive` (a precondition is not met) and reports :class:`Info` where the device
meets every requirement but not the case's reading of a clause that leaves room. The runner
gives every case a fresh frame log, runs its clean-ups, puts the device back in
Pre-operational and checks that it is idle and answering before the next case
(:meth:`.device.Device.restore`).

Case modules register themselves here with :func:`case`; this module imports none of them
(:mod:`.catalog` lists them and selects from the registry).
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum

from .device import Device
from .dnet import DnetDevice
from .outcome import STOPPED_ANSWERING, Fail, Inconclusive, Info, Skip, Timing

__all__ = [
    "CASES",
    "Case",
    "CaseResult",
    "Context",
    "Fail",
    "Inconclusive",
    "Info",
    "Options",
    "Skip",
    "Timing",
    "Verdict",
    "case",
    "run_case",
    "run_cases",
]

PROFILES = (
    "od",
    "sdo",
    "nmt",
    "errctl",
    "emcy",
    "sync-pdo",
    "lss",
    "store",
    "cia401",
    "seed",
    "icpdas",
    "na9161",
    "delta-as300",
)
# the CiA profiles: CiA 301 (od .. sync-pdo, store), CiA 305 (lss), CiA 401 (cia401)
CIA_PROFILES = ("od", "sdo", "nmt", "errctl", "emcy", "sync-pdo", "lss", "store", "cia401")
# device-specific: they run when named, or under "all" when the device's identity matches
# (.identity): the seed vectors and icpdas concern devices that claim I-7232D / I-7231D
# compatibility, na9161 those that claim CREVIS NA-9161 compatibility, delta-as300 slaves meant
# to run under a Delta AS300 master without extra set-up
OPT_IN = ("seed", "icpdas", "na9161", "delta-as300")
# not even in "all": whether a slave fits one master is not conformance; named alone it runs
MASTER_PROFILES = ("delta-as300",)
# DeviceNet devices get their own profiles, selected with protocol="devicenet" (no EDS needed)
DEVICENET_PROFILES = ("devicenet",)
PROTOCOL_PROFILES = {"canopen": PROFILES, "devicenet": DEVICENET_PROFILES}


class Verdict(StrEnum):
    PASS = "PASS"  # every requirement met
    FAIL = "FAIL"  # a requirement not met: the clause and the frames say which
    SKIP = "SKIP"  # the case does not apply (an optional service or object is absent)
    INCONCLUSIVE = "INCONCLUSIVE"  # a precondition not met: neither pass nor fail
    INFO = "INFO"  # every requirement met; the device reads a clause that leaves room otherwise


@dataclass(frozen=True)
class Case:
    id: str
    profile: str
    title: str
    fn: Callable[[Context], None]


CASES: dict[str, Case] = {}


CaseFn = Callable[["Context"], None]


def case(profile: str, name: str, title: str) -> Callable[[CaseFn], CaseFn]:
    """Register ``fn`` as case ``<profile>.<name>``; the docstring explains the check."""
    if profile not in PROFILES + DEVICENET_PROFILES:
        raise ValueError(f"unknown profile {profile!r}")

    def register(fn: CaseFn) -> CaseFn:
        cid = f"{profile}.{name}"
        if cid in CASES:
            raise ValueError(f"duplicate case {cid}")
        CASES[cid] = Case(cid, profile, title, fn)
        return fn

    return register


@dataclass
class Options:
    loopback: bool = (
        False  # the device's outputs are wired to its inputs (DO n → DI n, AO n → AI n)
    )
    lss_spare_node_id: int | None = None  # node-ID the LSS cases may configure temporarily
    # restarts the device as at power-on (a bench's relay, a service restart): the cases that
    # need a power-on (na9161.hw_config_emcy) run only with it
    power_cycle: Callable[[], None] | None = None


@dataclass
class CaseResult:
    case: Case
    verdict: Verdict
    reason: str = ""
    expected: str | None = None
    seen: str | None = None
    frames: list[str] = field(default_factory=list)
    duration: float = 0.0
    clause: str | None = None
    notes: list[str] = field(default_factory=list)  # what the runner did after the case


class Context:
    """What a case gets: the device, the timing knobs, options, and clean-up registration."""

    def __init__(self, device: Device | DnetDevice, timing: Timing, options: Options):
        self._device = device
        self.timing = timing
        self.options = options
        self._cleanups: list[Callable[[], object]] = []
        self.error_checked = False  # the case checked the device shows no error (cases.common)

    @property
    def under_test(self) -> Device | DnetDevice:
        """The device, whatever its protocol (its link, settle())."""
        return self._device

    @property
    def device(self) -> Device:
        """The CANopen device under test (a CANopen case's)."""
        assert isinstance(self._device, Device), "a CANopen case run against a DeviceNet device"
        return self._device

    @property
    def dnet(self) -> DnetDevice:
        """The DeviceNet device under test (a DeviceNet case's)."""
        assert isinstance(self._device, DnetDevice), "a DeviceNet case run against a CANopen device"
        return self._device

    def cleanup(self, fn: Callable[[], object]) -> None:
        self._cleanups.append(fn)

    def run_cleanups(self) -> list[str]:
        errors: list[str] = []
        while self._cleanups:
            fn = self._cleanups.pop()
            try:
                fn()
            except Exception as exc:  # clean-up must not hide the verdict
                errors.append(f"could not restore: {exc}")
        return errors


def run_cases(
    selected: list[Case], ctx: Context, progress: Callable[[CaseResult], None] | None = None
) -> list[CaseResult]:
    results = []
    silent_since: str | None = None
    for c in selected:
        if silent_since is not None:
            result = CaseResult(
                c,
                Verdict.INCONCLUSIVE,
                f"not run: the device stopped answering after {silent_since}, even after reset communication",
            )
        else:
            result = run_case(c, ctx)
            if result.notes and result.notes[-1].startswith(STOPPED_ANSWERING):
                silent_since = c.id
        results.append(result)
        if progress:
            progress(result)
    return results


def run_case(c: Case, ctx: Context) -> CaseResult:
    link = ctx.under_test.link
    ctx.under_test.begin()
    link.flush()
    link.start_log()
    ctx.error_checked = False
    t0 = time.monotonic()
    try:
        c.fn(ctx)
        result = CaseResult(c, Verdict.PASS)
    except Skip as exc:
        result = CaseResult(c, Verdict.SKIP, str(exc))
    except Inconclusive as exc:
        result = CaseResult(c, Verdict.INCONCLUSIVE, str(exc))
    except Info as exc:
        result = CaseResult(c, Verdict.INFO, exc.message, seen=exc.seen)
    except Fail as exc:
        result = CaseResult(c, Verdict.FAIL, exc.message, exc.expected, exc.seen, clause=exc.clause)
    except Exception as exc:  # a case error is reported as a FAIL of that case, with the trace
        tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
        result = CaseResult(c, Verdict.FAIL, f"tester error: {tb}")
    ctx.under_test.settle()
    errors = ctx.run_cleanups()
    # the next case must find the device as this one found it: idle and answering; a case
    # that could not restore what it changed gets communication reset (CiA 301 §7.3.2)
    result.notes = errors + ctx.under_test.restore(reset=bool(errors))
    result.duration = time.monotonic() - t0
    if result.verdict in (Verdict.FAIL, Verdict.INFO, Verdict.INCONCLUSIVE) or result.notes:
        result.frames = link.log_lines()
    return result
