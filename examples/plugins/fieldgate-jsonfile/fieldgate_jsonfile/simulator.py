"""Simulated modules of a ``jsonfile`` back: ``fieldgate run --simulate`` and the tests.

The back is not serial, so core gives the factory no port: it points the back's config at
files of its own, in a folder of its own (removed at stop), writes the inputs there and
reads the outputs the back writes.
"""

import asyncio
import json
import shutil
import tempfile
from pathlib import Path

from fieldgate import ChannelSpec
from fieldgate.plugin import Simulator

from .config import JsonFileConfig

Value = bool | int | float


class JsonFileSimulator(Simulator):
    def __init__(self, config: JsonFileConfig, animate: bool = False):
        self.folder = Path(tempfile.mkdtemp(prefix=f"fieldgate-{config.name}-"))
        config.path = str(self.folder / "inputs.json")  # the back reads what we write
        config.outputs_path = str(self.folder / "outputs.json")
        self.inputs_path, self.outputs_path = Path(config.path), Path(config.outputs_path)
        self.animate = animate
        self.where = {s.id: s for s in config.channel_specs()}  # channel id -> module, kind, index
        self.inputs: dict[str, dict[str, list[Value]]] = {
            str(m.address): {"di": [False] * m.di, "ai": [0] * m.ai} for m in config.modules
        }
        self._task: asyncio.Task[None] | None = None

    async def start(self) -> None:
        self._write()
        if self.animate:
            self._task = asyncio.create_task(self._count())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
        shutil.rmtree(self.folder, ignore_errors=True)

    def set_input(self, channel_id: str, value: Value) -> None:
        spec = self._spec(channel_id, output=False)
        self.inputs[str(spec.source.module)][spec.kind.value][spec.source.index] = value
        self._write()

    def get_output(self, channel_id: str) -> Value:
        spec = self._spec(channel_id, output=True)
        try:
            modules = json.loads(self.outputs_path.read_text())["modules"]
            value = modules[str(spec.source.module)][spec.kind.value][spec.source.index]
        except (OSError, ValueError, KeyError, IndexError):
            value = None  # not written yet
        return value if value is not None else (False if spec.kind.is_digital else 0)

    def get(self, channel_id: str) -> Value:
        spec = self.where[channel_id]
        if spec.kind.is_output:
            return self.get_output(channel_id)
        return self.inputs[str(spec.source.module)][spec.kind.value][spec.source.index]

    def remove_inputs(self) -> None:
        """The other program stops: the inputs file disappears."""
        self.inputs_path.unlink(missing_ok=True)

    def _spec(self, channel_id: str, output: bool) -> ChannelSpec:
        spec = self.where.get(channel_id)
        if spec is None or spec.kind.is_output != output:
            raise KeyError(f"no simulated {'output' if output else 'input'} {channel_id!r}")
        return spec

    def _write(self) -> None:
        data = json.dumps({"modules": self.inputs}).encode()
        partial = self.inputs_path.with_suffix(".tmp")
        partial.write_bytes(data)
        partial.replace(self.inputs_path)  # the back never reads half a file

    async def _count(self) -> None:
        """Inputs that change by themselves: DI count in binary, AI ramp."""
        tick = 0
        while True:
            await asyncio.sleep(0.5)
            tick += 1
            for module in self.inputs.values():
                module["di"] = [bool(tick >> i & 1) for i in range(len(module["di"]))]
                module["ai"] = [(tick * 100 + i) % 32768 for i in range(len(module["ai"]))]
            self._write()


def simulator(config: JsonFileConfig, port: str | None, animate: bool) -> JsonFileSimulator:
    """``registry.add_simulator``'s factory; ``port`` is None: not a serial back."""
    return JsonFileSimulator(config, animate)
