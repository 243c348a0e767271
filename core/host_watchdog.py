"""Host watchdogs of polled modules, as a front sees them: one API for every front.

Many RS-485 I/O modules have a *host watchdog*: when the host stays silent for a
timeout, the module puts its outputs to safe values and remembers that it did until
the host clears it. ICP DAS DCON modules do it with ``~AA3EVV`` / ``~**`` / ``~AA0`` /
``~AA1``; the same modules in Modbus mode (M-7000) have the same feature behind
registers. Gateways publish it per module on their fieldbus side: the I-7231D as
CANopen objects 0x2001-0x2003, the I-7241D as DeviceNet Application (0x64) attributes
0x08-0x0B.

Why this lives in core and not in the dcon plugin: what a front needs (does this module
have a host watchdog, its enable and timeout, has it expired, recover it) depends
neither on the front's protocol nor on the back's. Putting it here lets the canopen and
devicenet fronts share it without importing each other or a back plugin, and lets any
back join by implementing two small protocols:

* its config, :class:`WatchdogBackConfig`: ``host_watchdogs()`` -> the configured
  ``(enabled, timeout_ms)`` per module address (``None``: left as the module has it),
  known before the back runs (EDS generation, defaults);
* the running back, :class:`WatchdogBack`: ``watchdog_settings``, ``watchdog_status``,
  ``set_watchdog``, ``request_clear_watchdog``, and the back-wide host-OK switch
  ``host_ok_enabled`` / ``set_host_ok`` (the dcon back implements both).

**Clearing a timeout** is one sequence for every back, :func:`clear_timeout` (the back
supplies the line steps, :class:`ClearSteps`). A module's host watchdog keeps running
while the keep-alive is paused (master lost, or the master switched host OK off), and
``~AA1`` clears the flag without restarting it: sent first, the module times out again at
once. So, with host OK allowed: the keep-alive first (``~**``: the watchdog restarts),
then the clear (``~AA1``), a confirmation (``~AA0`` must show the flag gone), then the
outputs are written again. With host OK switched off by the master, the clear goes out
without it, and the result says so (the module will time out again after its timeout).

Fronts translate the exceptions into their protocol's answers: :class:`NoHostWatchdog`
(the module has none here), ``ValueError`` (a value out of range),
:class:`WatchdogUnavailable` (the back cannot do it now: not running, module unknown).
Changes are queued on the back's line and acknowledged at once (fire and forget); the
line request's outcome shows in the module's status and health.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from .health import ErrorKind
from .polling import CommError

Key = tuple[str, int]  # (back name, module address)
Setting = tuple[bool, int]  # (enabled, timeout in ms; 0 = unknown)

TENTHS_MIN, TENTHS_MAX = (
    1,
    255,
)  # the timeout in 0.1 s steps, as DCON's ~AA3EVV and both gateways carry it


@runtime_checkable
class WatchdogBackConfig(Protocol):
    name: str

    def host_watchdogs(self) -> dict[int, Setting | None]:
        """Every module address of the back -> its configured watchdog, or None when not configured."""


@runtime_checkable
class WatchdogBack(Protocol):
    def watchdog_settings(self, address: int) -> Setting:
        """The module's current (enabled, timeout ms); KeyError for a module the back does not run."""

    def watchdog_status(self, address: int) -> bool:
        """True while the module sits in watchdog timeout; KeyError for an unknown module."""

    def set_watchdog(self, address: int, enabled: bool, timeout_ms: int | None = None) -> Any:
        """Queue the new setting on the line (None: keep the timeout)."""

    def request_clear_watchdog(self, address: int) -> Any:
        """Queue the recovery (DCON ``~AA1``) on the line."""

    host_ok_enabled: bool  # the back may send its keep-alive (DCON ``~**``) to the modules

    def set_host_ok(self, enabled: bool) -> None:
        """Allow or stop the keep-alive: with it off, watchdog-enabled modules time out."""


@dataclass
class ClearSteps:
    """What :func:`clear_timeout` needs of a back's line, for one module.

    ``host_ok``: send the keep-alive now (DCON ``~**``), or None when it may not be sent,
    with ``without_host_ok`` saying why (the master switched it off, a master is lost).
    """

    clear: Callable[[], Awaitable[None]]  # reset the module's timeout flag (``~AA1``)
    expired: Callable[[], Awaitable[bool]]  # read the flag back (``~AA0`` bit 2)
    rewrite_outputs: Callable[[], None]  # queue the outputs the image holds
    host_ok: Callable[[], Awaitable[None]] | None = None
    without_host_ok: str = ""


CLEARED = "cleared"


async def clear_timeout(steps: ClearSteps) -> str:
    """Clear a module's host-watchdog timeout; the outcome for the module's status.

    Raises :class:`~fieldgate.polling.CommError` (kind ``watchdog``) when the module still
    reports the timeout after the clear, or the line's own error when a step fails.
    """
    if steps.host_ok is not None:
        await steps.host_ok()  # first: the module's watchdog restarts, the clear then holds
    await steps.clear()
    if await steps.expired():
        why = (
            f" (host OK is off: {steps.without_host_ok}; its watchdog had run out already)"
            if steps.host_ok is None
            else ""
        )
        raise CommError(
            ErrorKind.WATCHDOG,
            f"the module still reports a host-watchdog timeout after the clear{why}",
        )
    steps.rewrite_outputs()
    if steps.host_ok is None:
        return (
            f"cleared without host OK ({steps.without_host_ok}): "
            "the module times out again after its watchdog timeout"
        )
    return CLEARED


class NoHostWatchdog(LookupError):
    """The module has no host watchdog this gateway can reach."""


class WatchdogUnavailable(RuntimeError):
    """The back cannot change the watchdog now (not running, module unknown, line closed)."""


class HostWatchdogs:
    """The host watchdogs of the modules of every watchdog-capable back.

    ``backs`` maps back names to running back objects (``GatewayContext.backs``: looked up
    at each call, so restarts and late starts are seen); ``capable`` names the backs whose
    modules have a host watchdog; ``configured`` is the topology's setting per module,
    answered while the back does not run.
    """

    def __init__(
        self,
        backs: Mapping[str, Any] | None = None,
        capable: Iterable[str] = (),
        configured: Mapping[Key, Setting] | None = None,
    ):
        self.backs = backs if backs is not None else {}
        self.capable = set(capable)
        self.configured = dict(configured or {})

    @classmethod
    def from_context(cls, context: Any) -> HostWatchdogs:
        """Capable backs and configured settings from the topology's back configs."""
        capable: set[str] = set()
        configured: dict[Key, Setting] = {}
        for config in context.topology.backs:
            if isinstance(config, WatchdogBackConfig):
                capable.add(config.name)
                configured.update(
                    {
                        (config.name, a): s
                        for a, s in config.host_watchdogs().items()
                        if s is not None
                    }
                )
        return cls(context.backs, capable, configured)

    # -- reading ------------------------------------------------------------------------
    def has(self, back: str, address: int) -> bool:
        """Whether the module is on a watchdog-capable back (a DCON module)."""
        return back in self.capable

    def any(self, keys: Iterable[Key]) -> bool:
        return any(self.has(back, address) for back, address in keys)

    def _back(self, back: str) -> Any | None:
        return self.backs.get(back) if back in self.capable else None

    def settings(self, back: str, address: int) -> Setting:
        """(enabled, timeout ms) as the back has it, else as configured, else (False, 0)."""
        running = self._back(back)
        if running is not None:
            try:
                enabled, timeout_ms = running.watchdog_settings(address)
                return bool(enabled), int(timeout_ms or 0)
            except (KeyError, AttributeError):
                pass
        return self.configured.get((back, address), (False, 0))

    def enabled(self, back: str, address: int) -> bool:
        return self.settings(back, address)[0]

    def timeout_tenths(self, back: str, address: int) -> int:
        """The timeout in 0.1 s (0 = not known: the module keeps its own), at most 255."""
        return min(TENTHS_MAX, self.settings(back, address)[1] // 100)

    def expired(self, back: str, address: int) -> bool:
        running = self._back(back)
        try:
            return bool(running is not None and running.watchdog_status(address))
        except KeyError:
            return False

    # -- changing -----------------------------------------------------------------------
    def set_enabled(self, back: str, address: int, value: int) -> None:
        """0 = off, 1 = on (the timeout stays); ValueError for anything else."""
        if value not in (0, 1):
            raise ValueError("0 = off, 1 = on")
        self._call(back, address, lambda b: b.set_watchdog(address, bool(value)))

    def set_timeout_tenths(self, back: str, address: int, tenths: int) -> None:
        """The timeout in 0.1 s, 1..255; the enable stays."""
        if not TENTHS_MIN <= tenths <= TENTHS_MAX:
            raise ValueError(f"the watchdog time is {TENTHS_MIN}..{TENTHS_MAX} x 0.1 s")
        self._call(
            back,
            address,
            lambda b: b.set_watchdog(address, self.enabled(back, address), tenths * 100),
        )

    def recover(self, back: str, address: int) -> None:
        """Clear the module's watchdog timeout (DCON ``~AA1``); its outputs are written again."""
        self._call(back, address, lambda b: b.request_clear_watchdog(address))

    # -- the back-wide keep-alive ("host OK") --------------------------------------------------
    def _running(self) -> list[Any]:
        return [b for name in sorted(self.capable) if (b := self.backs.get(name)) is not None]

    def host_ok(self) -> bool:
        """Whether every running capable back may send its keep-alive (True when none runs)."""
        return all(getattr(b, "host_ok_enabled", True) for b in self._running())

    def set_host_ok(self, enabled: int) -> None:
        """Allow (1, the default) or stop (0) the keep-alive of every capable back; ValueError otherwise."""
        if enabled not in (0, 1):
            raise ValueError("0 = off, 1 = on")
        running = self._running()
        if not running:
            raise NoHostWatchdog("no back with host watchdogs is running")
        for b in running:
            try:
                b.set_host_ok(bool(enabled))
            except Exception as exc:
                raise WatchdogUnavailable(str(exc)) from None

    def _call(self, back: str, address: int, action: Callable[[Any], None]) -> None:
        running = self._back(back)
        if running is None:
            raise NoHostWatchdog(
                f"module {address} has no host watchdog"
                if back not in self.capable
                else f"back {back} is not running"
            )
        try:
            action(running)
        except ValueError:
            raise
        except Exception as exc:  # back not running, module unknown
            raise WatchdogUnavailable(str(exc)) from None
