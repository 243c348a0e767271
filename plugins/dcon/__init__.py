"""DCON back end (ICP DAS I-7000, M-7000 in DCON mode, I-87K) and DCON module simulator."""

from __future__ import annotations

from fieldgate.plugin import hookimpl

from .back import DconBack
from .cli import configure_scan, configure_simulate, run_scan, run_simulate
from .config import DconBackConfig, DconModuleConfig
from .simulator import DconSimulator, simulator_factory

__all__ = ["DconBack", "DconBackConfig", "DconModuleConfig", "DconSimulator"]


@hookimpl
def fieldgate_register(registry) -> None:
    registry.add_back(
        "dcon",
        DconBackConfig,
        DconBack,
        "ICP DAS DCON master (I-7000, M-7000 in DCON mode, I-87K) on RS-485",
    )
    registry.add_simulator("dcon", simulator_factory)
    registry.add_command(
        ("scan", "dcon"),
        "find DCON modules on a line and print a topology section",
        configure_scan,
        run_scan,
    )
    registry.add_command(
        ("simulate", "dcon"),
        "simulated DCON modules on a serial port or pty",
        configure_simulate,
        run_simulate,
    )
