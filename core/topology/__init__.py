"""The YAML topology: models, loader, error reporting."""

from .errors import ConfigIssue, TopologyError
from .loader import Topology, load_topology, read_yaml, validate
from .model import (
    BackConfig,
    ComponentConfig,
    ErrorModeSpec,
    FrontConfig,
    GatewaySection,
    ModuleConfig,
    PolledBackConfig,
    SerialBackConfig,
    StrictModel,
    ValueMode,
    to_error_mode,
)

__all__ = [
    "BackConfig",
    "ComponentConfig",
    "ConfigIssue",
    "ErrorModeSpec",
    "FrontConfig",
    "GatewaySection",
    "ModuleConfig",
    "PolledBackConfig",
    "SerialBackConfig",
    "StrictModel",
    "Topology",
    "TopologyError",
    "ValueMode",
    "load_topology",
    "read_yaml",
    "to_error_mode",
    "validate",
]
