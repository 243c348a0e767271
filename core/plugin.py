"""What a plugin imports: the contract (:mod:`fieldgate.contract`: fronts, backs, the
gateway context, simulators, scanners, EDS writers, the ``hookimpl`` marker) and the plugin
host (:mod:`fieldgate.registry`: the registry a plugin registers with, and
:func:`load_registry`), in one place.

A plugin is any module listed in the entry-point group ``fieldgate.plugins``. It
implements one hook, ``fieldgate_register(registry)``, and in it registers its front or
back types (a pydantic config model plus a factory) and, optionally, CLI sub-commands
(``fieldgate simulate NAME``, ``fieldgate scan NAME``, ...). fieldgate's own plugins
register exactly the same way as a third-party package (docs/plugins.md).
"""

from .contract import (
    ENTRY_POINT_GROUP,
    PROJECT,
    Back,
    BackFactory,
    BackModel,
    CommandError,
    Component,
    Front,
    FrontFactory,
    FrontModel,
    GatewayContext,
    PluginStartError,
    PortUnavailable,
    Scanner,
    ScanProgress,
    SimulateCli,
    Simulator,
    SimulatorFactory,
    hookimpl,
    hookspec,
    module_address_model,
    one_line,
    probe_each,
)
from .registry import (
    Command,
    ComponentType,
    EdsRequest,
    EdsWriter,
    PluginInfo,
    PluginSpec,
    Registry,
    load_registry,
    summary_of,
)

__all__ = [
    "ENTRY_POINT_GROUP",
    "PROJECT",
    "Back",
    "BackFactory",
    "BackModel",
    "Command",
    "CommandError",
    "Component",
    "ComponentType",
    "EdsRequest",
    "EdsWriter",
    "Front",
    "FrontFactory",
    "FrontModel",
    "GatewayContext",
    "PluginInfo",
    "PluginSpec",
    "PluginStartError",
    "PortUnavailable",
    "Registry",
    "ScanProgress",
    "Scanner",
    "SimulateCli",
    "Simulator",
    "SimulatorFactory",
    "hookimpl",
    "hookspec",
    "load_registry",
    "module_address_model",
    "one_line",
    "probe_each",
    "summary_of",
]
