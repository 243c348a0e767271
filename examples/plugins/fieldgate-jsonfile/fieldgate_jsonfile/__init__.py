"""The ``jsonfile`` back: process data exchanged with another program through JSON files."""

from fieldgate import hookimpl
from fieldgate.plugin import Registry

from .back import JsonFileBack
from .config import JsonFileConfig
from .simulator import simulator


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_back(
        "jsonfile",
        JsonFileConfig,
        JsonFileBack,
        "inputs from a JSON file another program writes, outputs to one it reads",
    )
    registry.add_simulator("jsonfile", simulator)
