"""The ``dcon`` back: an ICP DAS DCON master (I-7000, M-7000 in DCON mode, I-87K), its scan and simulator."""

from __future__ import annotations

from fieldgate.plugin import Registry, hookimpl

from .back import DconBack
from .config import DconBackConfig, DconModuleConfig
from .scan import DconScanner
from .simulator import SIMULATE_CLI, DconSimulator, simulator_factory

__all__ = ["DconBack", "DconBackConfig", "DconModuleConfig", "DconSimulator"]


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_back(
        "dcon",
        DconBackConfig,
        DconBack,
        "ICP DAS DCON master (I-7000, M-7000 in DCON mode, I-87K) on RS-485",
    )
    registry.add_simulator("dcon", simulator_factory, SIMULATE_CLI)
    registry.add_scanner("dcon", DconScanner())
