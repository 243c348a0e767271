"""The plugin host: entry-point discovery and what the loaded plugins provide.

:func:`load_registry` finds every module in the entry-point group ``fieldgate.plugins``
and calls its ``fieldgate_register`` hook with a :class:`Registry`, where it registers its
front and back types (a pydantic config model and a factory), CLI sub-commands,
simulators, scanners and EDS writers. fieldgate's own plugins register exactly as a
third-party package does; one that fails to load or register is recorded with its reason
and provides nothing.
"""

from __future__ import annotations

import argparse
import copy
import importlib.metadata
import importlib.util
import logging
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import pluggy

from .contract import (
    ENTRY_POINT_GROUP,
    PROJECT,
    Back,
    BackModel,
    Component,
    Front,
    FrontModel,
    GatewayContext,
    Scanner,
    SimulateCli,
    SimulatorFactory,
    hookspec,
    one_line,
)
from .topology.model import BackConfig, FrontConfig, StrictModel

if TYPE_CHECKING:
    from .topology.loader import Topology

log = logging.getLogger("fieldgate.plugin")


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


def _no_factory(config: Any, context: GatewayContext) -> Component:
    raise TypeError("a device model is no component")


@dataclass(frozen=True)
class ComponentType:
    role: str  # "front" or "back"
    type_name: str
    model: type[FrontConfig] | type[BackConfig] | type[StrictModel]  # a device model's
    factory: Callable[[Any, GatewayContext], Component]
    plugin: str
    description: str = ""
    north: bool = False  # accepts network clients or talks to a broker: runs in a child process
    needs: tuple[str, ...] = ()  # modules its component imports (an optional dependency's)
    install: str = ""  # what installs them, e.g. "pip install 'fieldgate[opcua]'"

    def missing(self) -> str:
        """One line when a module this type needs is not installed, naming what installs it
        ("" when all are there). Checked without importing them (``find_spec``), so
        ``validate`` and ``run`` say it before anything starts."""
        absent = [name for name in self.needs if not module_installed(name)]
        if not absent:
            return ""
        what = " and ".join(absent)
        fix = f": {self.install}" if self.install else ""
        return f"{self.role} type '{self.type_name}' needs {what}, which is not installed{fix}"


def module_installed(name: str) -> bool:
    """Whether ``name`` can be imported, without importing it (a parent package is)."""
    if name in sys.modules:
        return sys.modules[name] is not None  # None: an import that is known to fail
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a parent package missing or blocked
        return False


@dataclass(frozen=True)
class Command:
    """A CLI sub-command contributed by a plugin, e.g. ("simulate", "modbus")."""

    path: tuple[str, ...]
    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    plugin: str


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
        needs: tuple[str, ...] = (),
        install: str = "",
    ) -> None:
        """A front type. ``north=True``: it accepts network clients (a server: OPC UA, Modbus
        TCP) or talks to a broker (Sparkplug); the gateway runs each such front in a child
        process of its own, against a mirror of the process image, so no client can stop or
        slow the fieldbus side (docs/architecture.md, "Process layout"). Its factory must be
        importable by name (a module-level function), and the front writes outputs only with
        :meth:`GatewayContext.set_outputs`.

        ``needs``: modules its front imports that are an optional dependency (an extra of
        the plugin's distribution), ``install``: the command that installs them; a topology
        with this front then fails ``validate`` and ``run`` with one line naming that
        command while one is missing (:meth:`ComponentType.missing`)."""
        self._add("front", type_name, model, factory, description, north, needs, install)

    def add_back(
        self,
        type_name: str,
        model: type[BackModel],
        factory: Callable[[BackModel, GatewayContext], Back],
        description: str = "",
        *,
        needs: tuple[str, ...] = (),
        install: str = "",
    ) -> None:
        """A back type; ``needs`` and ``install`` as for :meth:`add_front`."""
        self._add("back", type_name, model, factory, description, False, needs, install)

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
        needs: tuple[str, ...] = (),
        install: str = "",
    ) -> None:
        key = (role, type_name)
        if key in self.types:
            raise ValueError(
                f"{role} type {type_name!r} registered by both {self.types[key].plugin} and {self._current}"
            )
        self.types[key] = ComponentType(
            role,
            type_name,
            model,
            factory,
            self._current,
            description,
            north,
            tuple(needs),
            install,
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


def load_registry(
    extra_plugins: list[object] | None = None, *, only: Iterable[str] | None = None
) -> Registry:
    """Discover plugins through the entry-point group and collect what they register.

    ``only``: the front and back types a topology uses (``fieldgate run``): only the plugins
    of those names are loaded (a built-in plugin is named like its type), so a gateway pays
    the imports of what it runs and no other; when a type is not provided that way (a
    third-party plugin named otherwise), every plugin is loaded after all.

    A plugin that fails to import or to register is recorded with its error in one line and
    provides nothing (what it registered before failing is undone); it never prevents the
    others from loading. ``fieldgate plugins`` lists it (and exits 1); ``validate`` and
    ``run`` name it only when the topology needs a type no working plugin provides
    (:meth:`Registry.why_missing`). ``extra_plugins`` lets tests and embedding code add
    plugin objects directly.
    """
    if only is not None:
        wanted = set(only)
        entry_points = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
        if wanted <= {ep.name for ep in entry_points}:
            registry = _load(extra_plugins, wanted)
            if all(registry.lookup("front", t) or registry.lookup("back", t) for t in wanted):
                return registry
    return _load(extra_plugins, None)


def _load(extra_plugins: list[object] | None, names: set[str] | None) -> Registry:
    registry = Registry()
    pm = _make_manager()
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if names is not None and ep.name not in names:
            continue
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
