"""The ``jsonfile`` back's section of a topology, and the channels it declares."""

from typing import Literal

from pydantic import Field, model_validator

from fieldgate import ChannelSpec, ErrorMode, Kind, Source, channel_id
from fieldgate.topology import BackConfig, ModuleConfig

KINDS = (Kind.DI, Kind.AI, Kind.DO, Kind.AO)


class FileModule(ModuleConfig):
    """One module: an entry ``"modules": {"<address>": {...}}`` of the files."""

    di: int = Field(0, ge=0, le=64, description="digital inputs, a list of booleans")
    ai: int = Field(0, ge=0, le=64, description="analog inputs, a list of int16 values")
    do: int = Field(0, ge=0, le=64, description="digital outputs")
    ao: int = Field(0, ge=0, le=64, description="analog outputs")

    @model_validator(mode="after")
    def _has_channels(self) -> "FileModule":
        if not any(getattr(self, kind.value) for kind in KINDS):
            raise ValueError("a module needs channels: give di, ai, do or ao")
        return self


class JsonFileConfig(BackConfig):
    type: Literal["jsonfile"] = "jsonfile"
    path: str = Field(description="the file the other program writes the inputs to")
    outputs_path: str = Field(
        "outputs.json", description="the file fieldgate writes the outputs to"
    )
    poll_ms: int = Field(200, ge=10, le=60_000, description="how often the inputs are read")
    fail_threshold: int = Field(
        3, ge=0, le=100, description="a module is offline after more failed reads than this"
    )
    modules: list[FileModule] = Field(min_length=1)

    def channel_specs(self) -> list[ChannelSpec]:
        specs = []
        for m in self.modules:
            for kind in KINDS:
                for i in range(getattr(m, kind.value)):
                    # outputs: what to do when a front loses its master, and at shutdown
                    error_mode, shutdown_mode = (
                        m.output_modes(kind, i) if kind.is_output else (ErrorMode(), None)
                    )
                    specs.append(
                        ChannelSpec(
                            channel_id(self.name, m.address, kind, i),
                            kind,
                            Source(self.name, m.address, i),
                            error_mode=error_mode,
                            shutdown_mode=shutdown_mode,
                        )
                    )
        return specs
