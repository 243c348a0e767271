"""Plugin host: hook specifications, entry-point discovery, front and back interfaces.

A plugin is any module listed in the entry-point group ``fieldgate.plugins``. It
implements one hook, :func:`PluginSpec.fieldgate_register`, and in it registers its
front or back types (a pydantic config model plus a factory) and, optionally, CLI
sub-commands (``fieldgate simulate NAME``, ``fieldgate scan NAME``, ...). fieldgate's
own plugins register exactly the same way as a third-party package.
"""

from __future__ import annotations

import argparse
import copy
import importlib.metadata
import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import pluggy

from .events import MASTER_BACK, MASTER_LOST, MODULE_OFFLINE, MODULE_ONLINE, EventHub
from .health import HealthEvent, HealthRegistry, ModuleHealth
from .image import ChannelSpec, ProcessImage, Value
from .masters import MasterMonitor
from .topology.model import BackConfig, FrontConfig, StrictModel

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


def _no_factory(config: Any, context: GatewayContext) -> Component:
    raise TypeError("a device model is no component")


FrontFactory = Callable[[FrontConfig, GatewayContext], Front]
BackFactory = Callable[[BackConfig, GatewayContext], Back]
# a factory gets the config its model validated: a subclass of FrontConfig / BackConfig
FrontModel = TypeVar("FrontModel", bound=FrontConfig)
BackModel = TypeVar("BackModel", bound=BackConfig)


@dataclass(frozen=True)
class ComponentType:
    role: str  # "front" or "back"
    type_name: str
    model: type[FrontConfig] | type[BackConfig] | type[StrictModel]  # a device model's
    factory: Callable[[Any, GatewayContext], Component]
    plugin: str
    description: str = ""
    north: bool = False  # accepts network clients or talks to a broker: runs in a child process


@dataclass(frozen=True)
class Command:
    """A CLI sub-command contributed by a plugin, e.g. ("simulate", "modbus")."""

    path: tuple[str, ...]
    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    plugin: str


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


@dataclass(frozen=True)
class EdsRequest:
    """What ``fieldgate eds`` hands a front type's EDS writer."""

    topology: Topology
    front: FrontConfig  # the front to describe (validated by its plugin's model)
    registry: Registry
    options: argparse.Namespace  # the command's options, this front type's own among them
    file_name: str | None  # the output's file name (an EDS names itself), None on standard output


@dataclass(frozen=True)
class EdsWriter:
    front_type: str
    write: Callable[[EdsRequest], str]
    configure: Callable[[argparse._ArgumentGroup], None] | None
    plugin: str
    encoding: str = "utf-8"  # of the file -o writes (a DeviceNet EDS is Latin-1)


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

    @abstractmethod
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
        :class:`PluginStartError` (one line) when the port cannot be opened."""

    @abstractmethod
    def topology(self, found: list[Any], args: argparse.Namespace) -> str:
        """A ready-to-paste ``backs:`` section for what was found (every baud rate)."""

    def save(self, found: list[Any], args: argparse.Namespace, bauds: list[int]) -> None:  # noqa: B027  (optional)
        """After a complete scan: keep the result where the back's options say (DCON's
        ``-o FILE`` scan file); raise :class:`CommandError` (one line) when it cannot."""


@dataclass
class PluginInfo:
    name: str
    version: str
    distribution: str
    error: str = ""  # why the plugin failed to load or register, in one line
    provides: list[str] = field(default_factory=list)
    summary: str = ""  # the first line of the plugin module's docstring

    @property
    def failed(self) -> bool:
        return bool(self.error)


def one_line(exc: BaseException) -> str:
    """An exception as ``Type: message`` on one line (messages may span several)."""
    text = " ".join(str(exc).split())
    if len(text) > 300:
        text = text[:297] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def summary_of(module: object) -> str:
    """A plugin's summary: the first line of its module's docstring, without reST markup."""
    doc = (getattr(module, "__doc__", None) or "").strip()
    return doc.splitlines()[0].replace("``", "") if doc else ""


class Registry:
    """What the loaded plugins provide."""

    def __init__(self) -> None:
        self.types: dict[tuple[str, str], ComponentType] = {}
        self.commands: list[Command] = []
        self.simulators: dict[str, SimulatorFactory] = {}
        self.simulate_cli: dict[str, SimulateCli] = {}
        self.eds_writers: dict[str, EdsWriter] = {}
        self.scanners: dict[str, Scanner] = {}
        self.plugins: dict[str, PluginInfo] = {}
        self._current = "?"

    def add_front(
        self,
        type_name: str,
        model: type[FrontModel],
        factory: Callable[[FrontModel, GatewayContext], Front],
        description: str = "",
        *,
        north: bool = False,
    ) -> None:
        """A front type. ``north=True``: it accepts network clients (a server: OPC UA, Modbus
        TCP) or talks to a broker (Sparkplug); the gateway runs each such front in a child
        process of its own, against a mirror of the process image, so no client can stop or
        slow the fieldbus side (docs/architecture.md, "Process layout"). Its factory must be
        importable by name (a module-level function), and the front writes outputs only with
        :meth:`GatewayContext.set_outputs`."""
        self._add("front", type_name, model, factory, description, north)

    def add_back(
        self,
        type_name: str,
        model: type[BackModel],
        factory: Callable[[BackModel, GatewayContext], Back],
        description: str = "",
    ) -> None:
        self._add("back", type_name, model, factory, description)

    def add_model(self, type_name: str, model: type[StrictModel], description: str = "") -> None:
        """A device model type: the topology's ``models:`` entries of this ``type`` are validated
        with ``model`` (before the backs), and a back's config finds them by name in its
        validation context (``info.context["models"]``)."""
        self._add("model", type_name, model, _no_factory, description)

    def add_command(
        self,
        path: tuple[str, ...],
        help: str,
        configure: Callable[[argparse.ArgumentParser], None],
        run: Callable[[argparse.Namespace], int],
    ) -> None:
        path = tuple(path)
        for other in self.commands:
            if other.path == path:
                raise ValueError(
                    f"command '{' '.join(path)}' registered by both {other.plugin} and {self._current}"
                )
        self.commands.append(Command(path, help, configure, run, self._current))
        if self._current in self.plugins:
            self.plugins[self._current].provides.append("command:" + " ".join(path))

    def add_simulator(
        self, back_type: str, factory: SimulatorFactory, cli: SimulateCli | None = None
    ) -> None:
        """``factory(back_config, port, animate)`` returns a :class:`Simulator` for that back type.

        For a serial back (``SerialBackConfig``) ``port`` is the simulator's end of a
        pseudo-terminal pair whose other end is already in ``back_config.port``; for any other
        back it is None, and the factory points ``back_config`` at what its simulator serves.
        ``fieldgate run --simulate`` uses it, and ``fieldgate simulate BACK`` serves it from
        the command line (``cli``: how ``--module`` and the back's own options read).
        """
        if back_type in self.simulators:
            raise ValueError(f"a simulator for back type {back_type!r} is registered twice")
        self.simulators[back_type] = factory
        self.simulate_cli[back_type] = cli or SimulateCli()
        self._provides(f"simulator:{back_type}")

    def add_eds(
        self,
        front_type: str,
        write: Callable[[EdsRequest], str],
        configure: Callable[[argparse._ArgumentGroup], None] | None = None,
        encoding: str = "utf-8",
    ) -> None:
        """``fieldgate eds TOPOLOGY [--front NAME]`` for fronts of ``front_type``: ``write``
        returns the EDS text (raise :class:`CommandError` for a one-line refusal);
        ``configure`` adds options of this front type only; ``encoding``: the file's."""
        if front_type in self.eds_writers:
            raise ValueError(
                f"an EDS writer for front type {front_type!r} is registered by both "
                f"{self.eds_writers[front_type].plugin} and {self._current}"
            )
        self.eds_writers[front_type] = EdsWriter(
            front_type, write, configure, self._current, encoding
        )
        self._provides(f"eds:{front_type}")

    def add_scanner(self, back_type: str, scanner: Scanner) -> None:
        """``fieldgate scan BACK`` for backs of ``back_type``."""
        if back_type in self.scanners:
            raise ValueError(f"a scanner for back type {back_type!r} is registered twice")
        self.scanners[back_type] = scanner
        self._provides(f"scan:{back_type}")

    def _provides(self, what: str) -> None:
        if self._current in self.plugins:
            self.plugins[self._current].provides.append(what)

    def provider(self, what: str) -> str:
        """The plugin that provides ``what`` (``"simulator:modbus"``, ``"back:dcon"``), or "?"."""
        return next((n for n, info in self.plugins.items() if what in info.provides), "?")

    def _add(
        self,
        role: str,
        type_name: str,
        model: type[FrontConfig] | type[BackConfig] | type[StrictModel],
        factory: Callable[..., Any],
        description: str,
        north: bool = False,
    ) -> None:
        key = (role, type_name)
        if key in self.types:
            raise ValueError(
                f"{role} type {type_name!r} registered by both {self.types[key].plugin} and {self._current}"
            )
        self.types[key] = ComponentType(
            role, type_name, model, factory, self._current, description, north
        )
        if self._current in self.plugins:
            self.plugins[self._current].provides.append(f"{role}:{type_name}")

    def lookup(self, role: str, type_name: str) -> ComponentType | None:
        return self.types.get((role, type_name))

    def failed(self) -> list[PluginInfo]:
        """The plugins that failed to load or to register, by name."""
        return [info for _, info in sorted(self.plugins.items()) if info.failed]

    def why_missing(self, role: str, type_name: str) -> str:
        """What to add when no plugin provides ``type_name``: the installed plugins that failed
        (the one named like the type when there is one, else all of them); "" when none did.

        A broken plugin is reported this way only to a topology that needs a type it may
        provide; everything else keeps working without it.
        """
        failed = self.failed()
        named = [p for p in failed if type_name in (p.name, p.distribution)] or [
            p for p in failed if type_name in p.distribution
        ]
        return "".join(
            f"; plugin {p.name} ({p.distribution}) failed to load: {p.error}"
            for p in named or failed
        )

    _REGISTERED = ("types", "commands", "simulators", "simulate_cli", "eds_writers", "scanners")

    def _snapshot(self) -> dict[str, Any]:
        return {name: copy.copy(getattr(self, name)) for name in self._REGISTERED}

    def _restore(self, snapshot: dict[str, Any]) -> None:
        """Undo what a plugin registered before it failed: it provides nothing, not half."""
        for name, value in snapshot.items():
            setattr(self, name, value)
        if self._current in self.plugins:
            self.plugins[self._current].provides.clear()

    def type_names(self, role: str) -> list[str]:
        return sorted(t for (r, t) in self.types if r == role)


class PluginSpec:
    @hookspec
    def fieldgate_register(self, registry: Registry) -> None:
        """Register front/back types and CLI commands with ``registry``."""


def _make_manager() -> pluggy.PluginManager:
    pm = pluggy.PluginManager(PROJECT)
    pm.add_hookspecs(PluginSpec)
    return pm


def _dist_summary(dist: importlib.metadata.Distribution | None) -> str:
    """The distribution's one-line Summary (a plugin module without a docstring)."""
    if dist is None:
        return ""
    return str(dist.metadata.json.get("summary", ""))


def load_registry(extra_plugins: list[object] | None = None) -> Registry:
    """Discover plugins through the entry-point group and collect what they register.

    A plugin that fails to import or to register is recorded with its error in one line and
    provides nothing (what it registered before failing is undone); it never prevents the
    others from loading. ``fieldgate plugins`` lists it (and exits 1); ``validate`` and
    ``run`` name it only when the topology needs a type no working plugin provides
    (:meth:`Registry.why_missing`). ``extra_plugins`` lets tests and embedding code add
    plugin objects directly.
    """
    registry = Registry()
    pm = _make_manager()
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = ep.dist.name if ep.dist else "?"
        version = ep.dist.version if ep.dist else "?"
        info = PluginInfo(ep.name, version, dist)
        if ep.name in registry.plugins:  # two distributions chose one name: the first keeps it
            info.name = f"{ep.name}@{dist}"
            info.error = (
                f"plugin name {ep.name!r} is taken by {registry.plugins[ep.name].distribution}"
            )
            registry.plugins[info.name] = info
            continue
        registry.plugins[ep.name] = info
        try:
            module = ep.load()
            info.summary = summary_of(module) or _dist_summary(ep.dist)
            pm.register(module, name=ep.name)
        except (Exception, SystemExit) as exc:  # broken third-party plugin: report, keep going
            info.error = one_line(exc)
            log.info("plugin %s (%s) failed to load: %s", ep.name, dist, info.error)
    for i, plugin in enumerate(extra_plugins or []):
        name = getattr(plugin, "PLUGIN_NAME", f"extra{i}")
        registry.plugins[name] = PluginInfo(
            name, getattr(plugin, "__version__", "0"), "(in process)", summary=summary_of(plugin)
        )
        pm.register(plugin, name=name)
    for name, _plugin in pm.list_name_plugin():
        registry._current = name
        before = registry._snapshot()
        try:
            pm.subset_hook_caller(
                "fieldgate_register",
                remove_plugins=[p for n, p in pm.list_name_plugin() if n != name],
            )(registry=registry)
        except (Exception, SystemExit) as exc:
            registry._restore(before)
            registry.plugins[name].error = one_line(exc)
            log.info("plugin %s failed to register: %s", name, registry.plugins[name].error)
    registry._current = "?"
    return registry
