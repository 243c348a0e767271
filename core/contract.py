"""The contract between fieldgate and its plugins: what a front or back is and what it may use.

A plugin implements :class:`Front` or :class:`Back` (start, run, stop; status and metrics
optional) against a :class:`GatewayContext` (the process image, module health, master
state, events, and :meth:`GatewayContext.set_outputs` for a north-facing front's client
writes), and may offer a :class:`Simulator`, a :class:`Scanner` or an EDS writer. It
registers them in its ``fieldgate_register`` hook (``@hookimpl``) with the
:class:`~fieldgate.registry.Registry`. Plugin authors import all of it from
``fieldgate.plugin`` (docs/plugins.md).
"""

from __future__ import annotations

import argparse
import logging
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import pluggy

from .events import MASTER_BACK, MASTER_LOST, MODULE_OFFLINE, MODULE_ONLINE, EventHub
from .health import HealthEvent, HealthRegistry, ModuleHealth
from .image import ChannelSpec, ProcessImage, Value
from .masters import MasterMonitor
from .topology.model import BackConfig, FrontConfig

if TYPE_CHECKING:
    from .topology.loader import Topology

ENTRY_POINT_GROUP = "fieldgate.plugins"
PROJECT = "fieldgate"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)

log = logging.getLogger("fieldgate.plugin")


class PluginStartError(Exception):
    """A front or back cannot start (port missing, unknown CAN interface, ...).

    The message is the cause in one line; the runtime adds the component name.
    """


class CommandError(Exception):
    """A plugin's part of a command cannot do what was asked (no such front, a value the
    device cannot take); the message is the reason in one line. The command prints it and
    exits with :attr:`~fieldgate.exitcodes.ExitCode.FAILED`."""


class PortUnavailable(PluginStartError):
    """A serial port that may come later (no such device, busy, a USB adapter not plugged in):
    a serial back starts without it, its modules offline, and keeps trying to open it
    (:class:`fieldgate.polling.SerialBack`). Wrong settings are a plain PluginStartError."""


class GatewayContext:
    """What a front or back may use: the process image, module health, master state, events.

    ``events`` (:class:`~fieldgate.events.EventHub`) is where a component publishes what
    a person watching the gateway wants to know (NMT state change, EMCY sent, bus-off);
    module offline/online and master lost/back are published here by core.
    """

    def __init__(
        self,
        topology: Topology,
        image: ProcessImage,
        health: HealthRegistry,
        masters: MasterMonitor,
        events: EventHub | None = None,
    ):
        self.topology = topology
        self.image = image
        self.health = health
        self.masters = masters
        self.events = events if events is not None else EventHub()
        self.backs: dict[
            str, Component
        ] = {}  # running back instances by name (a front's manufacturer objects reach them)
        health.subscribe(self._health_event)
        masters.subscribe(self._master_event)

    def _health_event(self, health: ModuleHealth, event: HealthEvent) -> None:
        module = f"{health.back}/m{health.address}"
        if event is HealthEvent.OFFLINE:
            self.events.publish(
                MODULE_OFFLINE,
                module,
                f"module {module} offline: {health.last_error}",
                back=health.back,
                address=health.address,
                error=str(health.last_error_kind or ""),
            )
        elif event is HealthEvent.ONLINE:
            self.events.publish(
                MODULE_ONLINE,
                module,
                f"module {module} back online",
                back=health.back,
                address=health.address,
            )

    def _master_event(self, front: str, ok: bool, reason: str) -> None:
        if ok:
            self.events.publish(MASTER_BACK, front, f"front {front}: master back ({reason})")
        else:
            self.events.publish(MASTER_LOST, front, f"front {front} lost its master: {reason}")

    @classmethod
    def build(cls, topology: Topology, clock: Callable[[], float] | None = None) -> GatewayContext:
        """A fresh process image holding the topology's channels, with empty health and master state.

        The gateway builds its context this way; so do tools and benches that run one
        front or back on its own.
        """
        image = ProcessImage(clock) if clock is not None else ProcessImage()
        for spec in topology.channel_specs:
            image.add(spec)
        return cls(topology, image, HealthRegistry(), MasterMonitor(image))

    def add_channels(self, back: str, specs: list[ChannelSpec]) -> None:
        """A back that finds its modules at start (``BackConfig.finds_modules_at_start``) adds
        their channels: to the image (new ids only, so a restart keeps them) and to the
        topology's list, replacing what the back had there. Backs start before fronts, so
        every front builds on them."""
        self.topology.channel_specs[:] = [
            s for s in self.topology.channel_specs if s.source.back != back
        ] + list(specs)
        for spec in specs:
            if spec.id not in self.image:
                self.image.add(spec)

    async def set_outputs(self, values: Mapping[str, Value], origin: str) -> None:
        """A front writes outputs for a client (an OPC UA Write, a Modbus FC6/FC16, a Sparkplug
        DCMD) and returns once the process image has applied them; the client's answer is sent
        only then. Raises KeyError (no such channel) or ValueError (an input, a value outside
        the channel's type, an output the front may not write) with a one-line reason, and
        nothing is written.

        In the fieldbus process this is :meth:`ProcessImage.write_outputs`. A north-facing
        front runs in a child process of its own (docs/architecture.md): there the call goes
        to the fieldbus process over the child's command channel and returns when that
        process has applied the batch (``fieldgate.isolation``). Fronts that accept network
        clients write outputs only this way.
        """
        self.image.write_outputs(values, origin=origin)

    def point_locations(self) -> dict[str, list[str]]:
        """Where the backs read each channel (``rs485/m1/di0`` -> ``["Modbus RTU unit 1 ..."]``),
        for descriptions; in a north-facing child, what the fieldbus process reported."""
        places: dict[str, list[str]] = {}
        for back in self.backs.values():
            method = getattr(back, "point_locations", None)
            if method is None:
                continue
            try:
                for cid, where in method().items():
                    places.setdefault(cid, []).extend(where)
            except Exception:  # only descriptions depend on it
                log.debug("point_locations of %s failed", back.name, exc_info=True)
        return places

    @property
    def clock(self) -> Callable[[], float]:
        return self.image.clock

    @property
    def state_dir(self) -> Path:
        return self.topology.state_dir

    def state_file(self, configured: str | None, default: str) -> Path:
        """Where a component keeps a state file: ``configured`` (else ``default``), under
        ``state_dir`` unless it is absolute."""
        path = Path(configured or default)
        return path if path.is_absolute() else self.state_dir / path

    def front_backs(self, front: FrontConfig) -> list[str]:
        """The backs whose channels a front serves or would serve: every back without an
        ``expose`` list, else those an ``expose`` pattern's back part matches (a back with no
        channel yet, e.g. one that found no module, still counts)."""
        return front.served_backs([b.name for b in self.topology.backs])

    def front_channels(self, front: FrontConfig) -> list[Any]:
        """The channels a front serves, in order (its ``expose`` list, or all in the seeds' order),
        without those of a data type it cannot carry (``FrontConfig.carried_types``)."""
        from .layout import default_order

        if front.expose is not None:
            channels = self.image.match(front.expose)
        else:
            channels = default_order(self.image, [b.name for b in self.topology.backs])
        carried = front.carried_types
        return channels if carried is None else [c for c in channels if c.dtype in carried]


class Component(ABC):
    """Common life cycle of fronts and backs.

    * ``start()`` acquires resources (ports, buses). Raise :class:`PluginStartError`
      with a one-line cause when that fails.
    * ``run()`` does the work until cancelled. If it raises, the runtime logs one line,
      marks the component's channels comm fault, calls ``stop()`` and starts it again
      with back-off.
    * ``stop()`` releases everything; it must be safe to call after a failed start.
    """

    kind: str = "component"

    def __init__(self, config: Any, context: GatewayContext):
        self.config = config
        self.context = context
        self.name: str = config.name
        self.log = logging.getLogger(f"fieldgate.{self.kind}.{self.name}")

    @abstractmethod
    async def start(self) -> None: ...

    @abstractmethod
    async def run(self) -> None: ...

    @abstractmethod
    async def stop(self) -> None: ...

    def status(self) -> dict[str, Any]:
        return {}

    def channel_ids(self) -> list[str]:
        """Channels to mark comm fault while this component is down."""
        return []


class Front(Component):
    """A fieldbus slave a PLC talks to. Reads inputs, writes outputs, reports master state."""

    kind = "front"


class Back(Component):
    """A poller of I/O modules. Writes inputs, reads outputs, keeps module health."""

    kind = "back"

    def channel_ids(self) -> list[str]:
        return [c.id for c in self.context.image.channels(back=self.name)]


FrontFactory = Callable[[FrontConfig, GatewayContext], Front]
BackFactory = Callable[[BackConfig, GatewayContext], Back]
# a factory gets the config its model validated: a subclass of FrontConfig / BackConfig
FrontModel = TypeVar("FrontModel", bound=FrontConfig)
BackModel = TypeVar("BackModel", bound=BackConfig)


class Simulator(ABC):
    """Simulated modules of one back: the far end of its serial port, or whatever else the
    back talks to (a file, a socket).

    Registered per back type with :meth:`Registry.add_simulator`; used by
    ``fieldgate run --simulate`` (the demo), ``fieldgate simulate BACK`` and by tests.
    ``start()`` raises :class:`PluginStartError` with a one-line cause when it cannot serve.
    """

    @abstractmethod
    async def start(self) -> None: ...

    @abstractmethod
    async def stop(self) -> None: ...

    @abstractmethod
    def set_input(self, channel_id: str, value: bool | int | float) -> None:
        """Drive a simulated module input (it shows up in the gateway after the next poll); a
        simulator that serves text channels takes a str there too."""

    @abstractmethod
    def get_output(self, channel_id: str) -> bool | int | float | str:
        """What the gateway last wrote to a simulated module output."""

    # optional, for ``fieldgate simulate BACK`` (its stdin commands and its banner)
    def get(self, channel_id: str) -> bool | int | float | str:
        """Any channel's value in the simulated module (``get`` and ``show``); by default
        outputs only (KeyError for an input)."""
        return self.get_output(channel_id)

    def command(self, words: list[str]) -> str | None:
        """A command of this simulator's own (the Modbus ``fault``): its answer, or None when
        ``words`` is not one of them. Raise KeyError/ValueError for a one-line error."""
        return None

    def commands_help(self) -> str:
        """The syntax of this simulator's own commands, for ``help`` ("" when none)."""
        return ""

    def describe(self) -> list[str]:
        """Lines about the simulated modules, printed before ``fieldgate simulate``'s banner."""
        return []


# (back_config, port, animate) -> Simulator; port: the simulator's end of a pty for a serial
# back (core put the other end in back_config.port), None for any other back (core.simulation)
SimulatorFactory = Callable[..., Simulator]


def module_address_model(spec: str) -> dict[str, Any]:
    """``3:M-7055D`` as a module mapping (``fieldgate simulate BACK --module``'s default form)."""
    address, sep, model = spec.partition(":")
    if not sep or not model or not address.strip().isdigit():
        raise ValueError(f"--module expects ADDRESS:MODEL, got {spec!r}")
    return {"address": int(address), "model": model}


@dataclass(frozen=True)
class SimulateCli:
    """How ``fieldgate simulate BACK`` builds a back from the command line (optional: without
    it, ``--module ADDRESS:MODEL`` makes ``{address, model}`` modules).

    ``module`` turns one ``--module`` value into a module mapping (ValueError: a one-line
    reason); ``configure`` adds the options of this back only to its argument group, and
    ``fields`` turns them into fields of the back's config (``checksum: true``).
    """

    module_metavar: str = "ADDRESS:MODEL"
    module_example: str = "3:M-7055D"
    module: Callable[[str], dict[str, Any]] = module_address_model
    configure: Callable[[argparse._ArgumentGroup], None] | None = None
    fields: Callable[[argparse.Namespace], dict[str, Any]] | None = None


ScanProgress = Callable[[int, int, int], None]  # (addresses done, addresses in all, modules found)


class Scanner(ABC):
    """Finds the modules on a line for ``fieldgate scan BACK``.

    Core runs the command: the options every back shares (``--port``, ``--baudrate`` one
    or several, ``--addresses``, ``--timeout-ms``, ``--name``), one :meth:`scan` per baud
    rate, the progress bar, Ctrl-C (what was found so far is printed, exit 130) and the exit
    code (0 found, 1 none, 2 the port failed).
    """

    addresses: str = "0-255"  # the default --addresses
    address_range: tuple[int, int] = (0, 255)  # the addresses the protocol has

    def configure(self, group: argparse._ArgumentGroup) -> None:  # noqa: B027  (optional)
        """Add the options of this back only (DCON's ``--checksum``)."""

    async def scan(
        self,
        port: str,
        baudrate: int,
        addresses: list[int],
        args: argparse.Namespace,
        progress: ScanProgress,
        found: list[Any],
    ) -> None:
        """Probe ``addresses`` at one baud rate, appending each module to ``found`` as it is
        identified and calling ``progress`` after each address; raise
        :class:`PluginStartError` (one line) when the port cannot be opened.

        The usual scan, which a back gets by giving :meth:`open`, :meth:`probe` and
        :meth:`close`: open a link at the baud rate, probe each address on it in turn
        (:func:`probe_each`), close the link. A scan of another shape overrides this."""
        link = await self.open(port, baudrate, args)
        try:
            await probe_each(
                addresses, lambda address: self.probe(link, address, baudrate), found, progress
            )
        finally:
            await self.close(link)

    async def open(self, port: str, baudrate: int, args: argparse.Namespace) -> Any:
        """The link the usual :meth:`scan` probes on; raise :class:`PluginStartError` (one
        line) when it cannot be opened."""
        raise NotImplementedError(f"{type(self).__name__} gives neither scan() nor open()")

    async def probe(self, link: Any, address: int, baudrate: int) -> Any | None:
        """The module found at ``address``, or None when nothing answers."""
        raise NotImplementedError(f"{type(self).__name__} gives neither scan() nor probe()")

    async def close(self, link: Any) -> None:  # noqa: B027  (optional)
        """Release the link (also after a failed or cancelled scan)."""

    @abstractmethod
    def topology(self, found: list[Any], args: argparse.Namespace) -> str:
        """A ready-to-paste ``backs:`` section for what was found (every baud rate)."""

    def save(self, found: list[Any], args: argparse.Namespace, bauds: list[int]) -> None:  # noqa: B027  (optional)
        """After a complete scan: keep the result where the back's options say (DCON's
        ``-o FILE`` scan file); raise :class:`CommandError` (one line) when it cannot."""


async def probe_each(
    addresses: Sequence[int],
    probe: Callable[[int], Awaitable[Any | None]],
    found: list[Any],
    progress: ScanProgress | None = None,
) -> None:
    """The loop of every scan: ``probe`` each address in turn, append what answers to
    ``found`` at once (a cancelled scan keeps what it had) and call ``progress`` after each
    address with the modules this call found."""
    count = len(found)
    for done, address in enumerate(addresses, 1):
        module = await probe(address)
        if module is not None:
            found.append(module)
        if progress is not None:
            progress(done, len(addresses), len(found) - count)


def one_line(exc: BaseException) -> str:
    """An exception as ``Type: message`` on one line (messages may span several)."""
    text = " ".join(str(exc).split())
    if len(text) > 300:
        text = text[:297] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
