"""What a front may learn of a polled module beyond its channels, and the few module
commands a gateway's fieldbus side offers, for every front and every back.

The I-7241D publishes each DCON module's identity as its Application object (0x64)
attributes (module ID, address, checksum, baud rate, type code, data format), the RS-485
reply timeout as a class attribute, and a command that makes the module's current
outputs its safe values (``~AA5S`` and friends). None of it depends on the front's
protocol: it lives here so that fronts ask backs without importing a plugin (as
:mod:`fieldgate.host_watchdog` does for the host watchdog). A back joins by implementing
the protocols below; its config may implement :class:`IdentityBackConfig` so that the
identity is known before the back runs (EDS generation).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable


@dataclass(frozen=True)
class ModuleIdentity:
    """One module as its back knows it; None where the back has no such notion."""

    model: str  # the model the topology (or the start scan) gives, e.g. "I-7017"
    reported: str = ""  # what the module itself says (DCON ``$AAM``: "7017R"); "" not read yet
    baudrate: int | None = None  # bit/s the module is set to
    checksum: bool | None = None  # the module adds and expects a checksum
    type_code: int | None = None  # range / type code (DCON ``$AA2``)
    data_format: int | None = None  # data format code (DCON: 0 engineering, 1 %FSR, 2 hex, 3 ohms)

    @property
    def module_id(self) -> int:
        """The model number as hex digits: "7017R" and "I-7017" give 0x7017, "87024" 0x87024
        (so a configurator showing hex reads the model), 0 when there is no number."""
        digits = re.search(r"\d+", self.reported or self.model)
        return int(digits[0][:8], 16) if digits else 0


@runtime_checkable
class IdentityBackConfig(Protocol):
    name: str

    def module_identities(self) -> dict[int, ModuleIdentity]:
        """Every module address of the back -> what its configuration says of it."""


@runtime_checkable
class IdentityBack(Protocol):
    def module_identity(self, address: int) -> ModuleIdentity:
        """The module as the running back knows it now; KeyError for an unknown module."""


@runtime_checkable
class ReplyTimeoutBack(Protocol):
    reply_timeout_ms: int

    def set_reply_timeout_ms(self, ms: int) -> None:
        """Change the line's reply timeout at run time; ValueError outside the back's range."""


@runtime_checkable
class SafeValueBack(Protocol):
    def can_latch_safe_value(self, address: int) -> bool:
        """Whether the module has outputs whose current values can become its safe values."""

    def request_latch_safe_value(self, address: int) -> Any:
        """Queue the command on the line (fire and forget; KeyError for an unknown module)."""


class ModuleUnavailable(RuntimeError):
    """The back cannot answer or act now (not running, module unknown)."""


class ModuleInfo:
    """Identities, reply timeouts and safe-value latches of the modules of every back.

    ``backs`` maps names to running back objects (``GatewayContext.backs``, looked up at each
    call); ``configured`` holds what the configs say, answered while a back does not run.
    """

    def __init__(
        self,
        backs: Mapping[str, Any] | None = None,
        configured: Mapping[tuple[str, int], ModuleIdentity] | None = None,
        timeouts: Mapping[str, int] | None = None,
    ):
        self.backs = backs if backs is not None else {}
        self.configured = dict(configured or {})
        self.timeouts = dict(timeouts or {})  # configured reply timeouts (ms) by back

    @classmethod
    def from_context(cls, context: Any) -> ModuleInfo:
        configured: dict[tuple[str, int], ModuleIdentity] = {}
        timeouts: dict[str, int] = {}
        for config in context.topology.backs:
            if isinstance(config, IdentityBackConfig):
                configured.update(
                    {(config.name, a): i for a, i in config.module_identities().items()}
                )
                timeout = getattr(config, "timeout_ms", None)
                if isinstance(timeout, int):
                    timeouts[config.name] = timeout
        return cls(context.backs, configured, timeouts)

    def has_identity(self, back: str, address: int) -> bool:
        """Whether the module's back knows identities at all (configured or running)."""
        return (back, address) in self.configured or isinstance(self.backs.get(back), IdentityBack)

    def identity(self, back: str, address: int) -> ModuleIdentity | None:
        """The running back's view, else the configured one; None for a back without identities."""
        running = self.backs.get(back)
        if isinstance(running, IdentityBack):
            try:
                return running.module_identity(address)
            except KeyError:
                pass
        return self.configured.get((back, address))

    def _timeout_backs(self, names: set[str]) -> list[Any]:
        return [
            b for name in sorted(names) if isinstance(b := self.backs.get(name), ReplyTimeoutBack)
        ]

    def reply_timeout_ms(self, backs: set[str]) -> int | None:
        """The reply timeout of the first back among ``backs`` that has one (running, else
        configured); None when none has."""
        running = self._timeout_backs(backs)
        if running:
            return int(running[0].reply_timeout_ms)
        configured = [self.timeouts[name] for name in sorted(backs) if name in self.timeouts]
        return configured[0] if configured else None

    def set_reply_timeout_ms(self, backs: set[str], ms: int) -> None:
        """Every running back among ``backs``; ModuleUnavailable when none runs."""
        running = self._timeout_backs(backs)
        if not running:
            raise ModuleUnavailable("no back with a reply timeout is running")
        for b in running:
            b.set_reply_timeout_ms(ms)

    def can_latch(self, back: str, address: int) -> bool:
        running = self.backs.get(back)
        if isinstance(running, SafeValueBack):
            try:
                return running.can_latch_safe_value(address)
            except KeyError:
                return False
        return False

    def latch_safe_value(self, back: str, address: int) -> None:
        running = self.backs.get(back)
        if not isinstance(running, SafeValueBack):
            raise ModuleUnavailable(f"back {back} is not running")
        try:
            running.request_latch_safe_value(address)
        except Exception as exc:  # module unknown, line closed
            raise ModuleUnavailable(str(exc)) from None
