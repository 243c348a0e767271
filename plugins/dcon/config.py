"""Topology models of the ``dcon`` back and its modules."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import (
    Field,
    ModelWrapValidatorHandler,
    PrivateAttr,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from fieldgate.image import ChannelSpec, DataType, Kind, Scaling, Source, channel_id
from fieldgate.module_info import ModuleIdentity
from fieldgate.scancmd import parse_addresses as parse_addresses  # one place: core's
from fieldgate.topology import ModuleConfig, SerialBackConfig, StrictModel

from .formats import FORMAT_NAMES
from .profiles import Profile, find_profile, model_names
from .scanfile import ScanFile, ScanFileError
from .tables import TABLES, TypeRange, TypeTable

DEFAULT_SCAN_ADDRESSES = "1-15"  # the I-7241D's and I-7231D's module addresses (0x01-0x0F)


FormatName = Literal["auto", "hex", "engineering", "percent", "ohms"]
DIGITAL_TYPE_CODE = 0x40  # what $AA2 reports for a digital I/O module


class WatchdogConfig(StrictModel):
    """The module's host watchdog (``~AA3EVV``), written each time the module comes online."""

    enabled: bool = Field(True, description="enable the module's host watchdog")
    timeout_ms: int = Field(
        2000, ge=100, le=25_500, description="timeout, in steps of 100 ms (DCON: 0.1..25.5 s)"
    )


OutputValue = int | list[int]


class DconModuleConfig(ModuleConfig):
    model: str = Field(description="module model: I-7017, M-7055D, I-87024, ... (see docs/dcon.md)")
    type_code: int | None = Field(
        None,
        ge=0,
        le=0xFF,
        description="expected type code (0x08 = +/-10 V...); default: what $AA2 reports",
    )
    data_format: FormatName = Field(
        "auto", description="expected data format; default: what $AA2 reports"
    )
    watchdog: WatchdogConfig | None = Field(
        None, description="host watchdog; default: leave the module's setting alone"
    )
    safe_value: OutputValue | None = Field(
        None,
        description="output value the module's watchdog applies: DO bit pattern, or AO raw value(s)",
    )
    power_on_value: OutputValue | None = Field(
        None, description="output value after power-on: DO bit pattern, or AO raw value(s)"
    )

    @field_validator("model")
    @classmethod
    def _known_model(cls, value: str) -> str:
        if find_profile(value) is None:
            raise ValueError(f"unknown DCON module {value!r}; known: {', '.join(model_names())}")
        return value

    @model_validator(mode="after")
    def _check_against_profile(self) -> DconModuleConfig:
        profile = self.profile
        table = self.type_table
        if self.type_code is not None:
            if table is None:
                if self.type_code != 0x40:
                    raise ValueError(
                        f"{profile.model} is a digital module (type code 0x40), not 0x{self.type_code:02X}"
                    )
            elif table.get(self.type_code) is None:
                codes = ", ".join(f"0x{c:02X}" for c in table.codes())
                raise ValueError(
                    f"type code 0x{self.type_code:02X} is not one of {profile.model}'s: {codes}"
                )
        for name in ("safe_value", "power_on_value"):
            value = getattr(self, name)
            if value is not None:
                _check_output_value(profile, name, value)
        return self

    @property
    def profile(self) -> Profile:
        profile = find_profile(self.model)
        assert profile is not None
        return profile

    @property
    def type_table(self) -> TypeTable | None:
        key = self.profile.ai_table or self.profile.ao_table
        return TABLES[key] if key else None

    def expected_range(self) -> TypeRange | None:
        table = self.type_table
        if table is None:
            return None
        return table.get(self.type_code if self.type_code is not None else table.default)


def _check_output_value(profile: Profile, name: str, value: OutputValue) -> None:
    if profile.do and not profile.ao:
        if not isinstance(value, int) or not 0 <= value < (1 << profile.do):
            raise ValueError(
                f"{name} of {profile.model} is a bit pattern of its {profile.do} outputs (0..{(1 << profile.do) - 1})"
            )
    elif profile.ao:
        values = value if isinstance(value, list) else [value] * profile.ao
        if len(values) != profile.ao:
            raise ValueError(
                f"{name} of {profile.model} needs {profile.ao} values (one per AO channel), got {len(values)}"
            )
    else:
        raise ValueError(f"{profile.model} has no outputs; {name} does not apply")


class ScanSettings(StrictModel):
    """What ``modules: auto`` probes at start, and the scan file standing in for the line."""

    addresses: str = Field(
        DEFAULT_SCAN_ADDRESSES, description="addresses to probe, e.g. 1-15 or 1,2,8 (0..255)"
    )
    baudrates: list[int] | None = Field(
        None, description="baud rates to try in order; default: the line's baudrate"
    )
    checksums: list[bool] | None = Field(
        None, description="checksum settings to try in order; default: the line's checksum"
    )
    file: str | None = Field(
        None,
        description="scan file (fieldgate scan dcon --output) giving the modules where the line is not there: validate, EDS, --simulate; relative to the topology file",
    )
    from_previous: bool = Field(
        True,
        description="modules: auto: start at once with the previous start's scan (in the state directory, made with these scan settings) and verify the line in the background; false: probe the line before starting, every start",
    )
    survey: bool = Field(
        False,
        description="with listed modules: probe the other addresses once after start (one a second, not while a host watchdog is on) and warn about modules the topology does not list",
    )

    @field_validator("addresses")
    @classmethod
    def _addresses(cls, value: str) -> str:
        try:
            if not parse_addresses(value):
                raise ValueError("no address")
        except ValueError as exc:
            raise ValueError(f"{exc} (expected e.g. 1-15 or 1,2,8)") from None
        return value

    @field_validator("baudrates")
    @classmethod
    def _baudrates(cls, value: list[int] | None) -> list[int] | None:
        from .codec import BAUD_TO_CODE

        for baud in value or []:
            if baud not in BAUD_TO_CODE:
                raise ValueError(
                    f"{baud} is not a DCON baud rate ({', '.join(map(str, BAUD_TO_CODE))})"
                )
        if value is not None and not value:
            raise ValueError("give at least one baud rate")
        return value


class DconBackConfig(SerialBackConfig):
    type: Literal["dcon"] = "dcon"
    checksum: bool = Field(
        False, description="DCON checksum on every frame (must match the modules' setting)"
    )
    host_ok_ms: int | None = Field(
        None,
        ge=20,
        le=12_000,
        description="period of the ~** host-OK broadcast; default: a third of the shortest watchdog timeout",
    )
    modules: list[DconModuleConfig] = Field(
        description="the modules, or auto: found on the line at start (scan)"
    )
    safe_value: Literal["module", "current"] = Field(
        "module",
        description="what a module without its own safe_value applies at a host-watchdog "
        "timeout: module = the value stored in it; current = its current outputs, as the "
        "I-7241D (seed-003 §7.2.11): latched when the host OK stops and after each output "
        "write while it is stopped",
    )
    scan: ScanSettings = Field(default_factory=ScanSettings)
    _auto: bool = PrivateAttr(False)
    _scan_file: ScanFile | None = PrivateAttr(None)

    @model_validator(mode="wrap")
    @classmethod
    def _modules_auto(
        cls, data: Any, handler: ModelWrapValidatorHandler[Any], info: ValidationInfo
    ) -> Any:
        """``modules: auto``: no list; the scan file (if any) is read here, relative to the
        topology file (the loader's ``base_dir`` context)."""
        auto = isinstance(data, dict) and data.get("modules") == "auto"
        if auto:
            data = {**data, "modules": []}
        elif isinstance(data, dict) and data.get("modules") == []:
            raise PydanticCustomError(
                "too_short",
                "give at least one module, or modules: auto (found on the line at start)",
                {"loc": ("modules",)},
            )
        config: DconBackConfig = handler(data)
        if not auto:
            return config
        config._auto = True
        if config.scan.file is not None:
            base = Path((info.context or {}).get("base_dir") or Path.cwd())
            try:
                config._scan_file = ScanFile.read(base / config.scan.file)
            except ScanFileError as exc:
                raise PydanticCustomError(
                    "scan_file", str(exc), {"loc": ("scan", "file")}
                ) from None
            try:
                config._check_modules(config.scanned_modules())
            except ValueError as exc:
                raise PydanticCustomError(
                    "scan_file", f"{config.scan.file}: {exc}", {"loc": ("scan", "file")}
                ) from None
        return config

    @property
    def auto(self) -> bool:
        """``modules: auto``: the back finds its modules on the line when it starts."""
        return self._auto

    @property
    def scan_file(self) -> ScanFile | None:
        return self._scan_file

    def finds_modules_at_start(self) -> bool:
        return self._auto

    def scanned_modules(self) -> list[DconModuleConfig]:
        """The scan file's supported modules as module configs ([] without a scan file)."""
        if self._scan_file is None:
            return []
        return [
            DconModuleConfig.model_validate(entry)
            for m in self._scan_file.supported()
            if (entry := m.module_config()) is not None
        ]

    def module_list(self) -> list[DconModuleConfig]:
        """The modules: listed, found by the start scan, else the scan file's (auto, not started)."""
        if self.modules or not self._auto:
            return list(self.modules)
        return self.scanned_modules()

    def modules_note(self) -> str:
        """How ``fieldgate validate`` describes where the modules come from."""
        if not self._auto:
            return ""
        where = f"found at start on {self.port}"
        if self._scan_file is not None:
            return f"{where}; scan file {self.scan.file} lists {len(self.scanned_modules())}"
        return where

    @model_validator(mode="after")
    def _check_line(self) -> DconBackConfig:
        self._check_modules(self.modules)
        return self

    def _check_modules(self, modules: list[DconModuleConfig]) -> None:
        seen: set[int] = set()
        for m in modules:
            if m.address in seen:
                raise ValueError(
                    f"two modules at address {m.address}; DCON addresses must be unique on a line"
                )
            seen.add(m.address)
        timeouts = [m.watchdog.timeout_ms for m in modules if m.watchdog and m.watchdog.enabled]
        if self.host_ok_ms is not None and timeouts and self.host_ok_ms * 2 >= min(timeouts):
            raise ValueError(
                f"host_ok_ms {self.host_ok_ms} must be less than half the shortest watchdog timeout ({min(timeouts)} ms)"
            )

    def host_ok_period(self) -> float | None:
        timeouts = [
            m.watchdog.timeout_ms for m in self.module_list() if m.watchdog and m.watchdog.enabled
        ]
        if self.host_ok_ms is not None:
            return self.host_ok_ms / 1000
        return min(timeouts) / 3000 if timeouts else None

    def poll_wire_time(self, module: ModuleConfig) -> float | None:
        """Worst case on the wire of one poll (``validate``'s poll budget): the digital read
        (``@AA``: up to ``!AASOOII``), the analog read (``#AA``: 7 characters a value in
        engineering units) or, for an output-only module, ``~AA0``; checksum and CR each."""
        assert isinstance(module, DconModuleConfig)
        p, extra = module.profile, (2 if self.checksum else 0) + 1
        chars = 0
        if p.digital:
            chars += 5 + 8 + 2 * extra
        if p.ai:
            chars += 3 + 1 + 7 * p.ai + 2 * extra
        if not (p.di or p.do or p.ai):
            chars += 4 + 5 + 2 * extra
        return self.timing().wire_time(chars)

    def host_watchdogs(self) -> dict[int, tuple[bool, int] | None]:
        """The configured host watchdog of every module, None where the module keeps its own
        (``fieldgate.host_watchdog.WatchdogBackConfig``: the fronts' watchdog objects)."""
        return {
            m.address: None
            if m.watchdog is None
            else (bool(m.watchdog.enabled), int(m.watchdog.timeout_ms))
            for m in self.module_list()
        }

    def module_identities(self) -> dict[int, ModuleIdentity]:
        """What the topology says of each module (``fieldgate.module_info``), before the back
        has read ``$AAM`` / ``$AA2``: the line's baud rate and checksum, the configured type
        code (digital modules: 0x40) and data format (None for ``auto``)."""
        out = {}
        for m in self.module_list():
            table = m.type_table
            type_code = (
                m.type_code
                if m.type_code is not None
                else table.default
                if table is not None
                else DIGITAL_TYPE_CODE
            )
            fmt = None if m.data_format == "auto" else int(FORMAT_NAMES[m.data_format])
            out[m.address] = ModuleIdentity(
                m.profile.model, "", self.baudrate, self.checksum, type_code, fmt
            )
        return out

    def channel_specs(self) -> list[ChannelSpec]:
        specs: list[ChannelSpec] = []
        for m in sorted(self.module_list(), key=lambda m: m.address):
            p = m.profile
            rng = m.expected_range()
            for kind, count in ((Kind.DI, p.di), (Kind.DO, p.do), (Kind.AI, p.ai), (Kind.AO, p.ao)):
                for i in range(count):
                    specs.append(self._spec(m, kind, i, rng))
        return specs

    def _spec(
        self, m: DconModuleConfig, kind: Kind, index: int, rng: TypeRange | None
    ) -> ChannelSpec:
        extra: dict[str, Any] = {}
        if kind.is_output:
            extra["error_mode"], extra["shutdown_mode"] = m.output_modes(kind, index)
        if not kind.is_digital and rng is not None:
            extra["scaling"] = Scaling(rng.hmin, rng.hmax, rng.fmin, rng.fmax, rng.unit)
            extra["dtype"] = DataType.UINT16 if rng.hmax > 0x7FFF else DataType.INT16
        return ChannelSpec(
            channel_id(self.name, m.address, kind, index),
            kind,
            Source(self.name, m.address, index),
            **extra,
        )
