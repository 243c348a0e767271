"""fieldgate: an open-source fieldbus gateway framework.

Public API for embedding and for plugins::

    from fieldgate import Gateway, ProcessImage, Kind, Quality, ErrorMode
"""

from .health import ErrorKind, HealthEvent, HealthRegistry, ModuleHealth
from .image import (
    Change,
    Channel,
    ChannelSpec,
    DataType,
    ErrorMode,
    Kind,
    ProcessImage,
    Quality,
    Reading,
    Scaling,
    Source,
    Value,
    channel_id,
)
from .masters import MasterMonitor
from .plugin import (
    Back,
    Front,
    GatewayContext,
    PluginStartError,
    PortUnavailable,
    Registry,
    hookimpl,
    load_registry,
)
from .runtime import Gateway, GatewayStartError
from .version import __version__

__all__ = [
    "Back",
    "Change",
    "Channel",
    "ChannelSpec",
    "DataType",
    "ErrorKind",
    "ErrorMode",
    "Front",
    "Gateway",
    "GatewayContext",
    "GatewayStartError",
    "HealthEvent",
    "HealthRegistry",
    "Kind",
    "MasterMonitor",
    "ModuleHealth",
    "PluginStartError",
    "PortUnavailable",
    "ProcessImage",
    "Quality",
    "Reading",
    "Registry",
    "Scaling",
    "Source",
    "Value",
    "channel_id",
    "hookimpl",
    "load_registry",
    "__version__",
]
