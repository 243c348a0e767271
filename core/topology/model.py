"""Pydantic models of the topology file that core owns, and the bases plugins extend.

A plugin registers one model per front or back ``type``; it subclasses
:class:`FrontConfig` or :class:`BackConfig` (RS-485 pollers: :class:`SerialBackConfig`)
so that every section shares the same strictness (unknown keys are errors) and the
same common fields.
"""

from __future__ import annotations

from collections.abc import Sequence
from fnmatch import fnmatchcase
from typing import Annotated, Any, ClassVar, Literal, overload

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    SecretStr,
    StringConstraints,
    Tag,
    field_validator,
    model_validator,
)

from ..image import NARROW_TYPES, ChannelSpec, DataType, ErrorMode, Kind
from ..serial_timing import LineTiming, bits_per_char

Identifier = Annotated[str, StringConstraints(pattern=r"^[A-Za-z][A-Za-z0-9_-]*$")]


class StrictModel(BaseModel):
    """Every topology model forbids unknown keys; the error report suggests the closest one."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, defer_build=True)


class ValueMode(StrictModel):
    value: bool | int | float = Field(description="value the output goes to")


def _error_mode_kind(spec: Any) -> str | None:
    if spec == "hold":
        return "hold"
    if isinstance(spec, (dict, ValueMode)):
        return "ValueMode"  # a class name: the error report leaves it out of field paths
    return None


# ``hold`` or ``{value: X}``; anything else is one error saying so (not one per union member),
# and a mapping's errors name its own fields (``error_mode.valu: ... did you mean 'value'?``).
ErrorModeSpec = Annotated[
    Annotated[Literal["hold"], Tag("hold")] | Annotated[ValueMode, Tag("ValueMode")],
    Discriminator(
        _error_mode_kind,
        custom_error_type="error_mode",
        custom_error_message="expected 'hold' or {value: X}",
    ),
]


@overload
def to_error_mode(spec: ErrorModeSpec) -> ErrorMode: ...
@overload
def to_error_mode(spec: None) -> None: ...
@overload
def to_error_mode(spec: ErrorModeSpec | None) -> ErrorMode | None: ...
def to_error_mode(spec: ErrorModeSpec | None) -> ErrorMode | None:
    if spec is None:
        return None
    if spec == "hold":
        return ErrorMode.hold()
    return ErrorMode.to(spec.value)


def split_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 in brackets: ``[::1]:8400``) as (host, port); ValueError says what is wrong."""
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"expected HOST:PORT, e.g. 127.0.0.1:8400, got {text!r}")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"port must be 0..65535 (0: any free port), got {port!r}")
    return host, int(port)


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``; any other name or address counts as exposed."""
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class HttpSettings(StrictModel):
    """The read-only status server (docs/observability.md): off unless this section exists."""

    listen: str = Field(
        "127.0.0.1:8400",
        description="HOST:PORT to bind; a non-loopback address needs auth_token, token_file or token_env",
    )
    auth_token: SecretStr | None = Field(
        None,
        description="bearer token every request but /healthz must carry; prefer token_file or token_env (secrets in the YAML end up in backups)",
    )
    token_file: str | None = Field(
        None, description="file holding the token (relative to the topology file)"
    )
    token_env: str | None = Field(
        None, description="environment variable holding the token, e.g. FIELDGATE_HTTP_TOKEN"
    )
    allowed_hosts: list[str] = Field(
        default_factory=list,
        description="without a token: Host header names accepted besides loopback ones (a reverse proxy's name); "
        "others get 421, which stops DNS-rebinding pages from reading the gateway",
    )
    point_metrics: bool = Field(
        False,
        description="also export one series per point on /metrics (value, good); off: counts by quality only",
    )
    sse_max_clients: int = Field(16, ge=1, le=256, description="concurrent event-stream clients")
    metrics_max_age_ms: int = Field(
        1000,
        ge=0,
        le=60_000,
        description="/metrics is rendered at most this often; scrapes in between share the text "
        "(0: every scrape renders)",
    )
    tls_cert_file: str | None = Field(
        None,
        description="serve HTTPS: the certificate chain (PEM), relative to the topology file; "
        "with tls_key_file",
    )
    tls_key_file: str | None = Field(
        None, description="the certificate's private key (PEM), relative to the topology file"
    )
    sse_point_rate_hz: float = Field(
        4.0,
        gt=0,
        le=50,
        description="point-change batches per second and client (changes in between are merged)",
    )

    @field_validator("listen")
    @classmethod
    def _listen(cls, value: str) -> str:
        split_listen(value)
        return value

    @model_validator(mode="after")
    def _exposed_needs_token(self) -> HttpSettings:
        sources = [self.auth_token, self.token_file, self.token_env]
        if sum(s is not None for s in sources) > 1:
            raise ValueError("give one of auth_token, token_file or token_env, not several")
        if (self.tls_cert_file is None) != (self.tls_key_file is None):
            raise ValueError("give tls_cert_file and tls_key_file together (HTTPS), or neither")
        host, _ = split_listen(self.listen)
        if not is_loopback(host) and all(s is None for s in sources):
            raise ValueError(
                f"listen {self.listen} is not a loopback address: set token_file, token_env or "
                "auth_token so that only clients with the token can read the gateway "
                "(or listen on 127.0.0.1)"
            )
        return self

    @property
    def has_token(self) -> bool:
        return any(s is not None for s in (self.auth_token, self.token_file, self.token_env))


class IsolationSettings(StrictModel):
    """North-facing parts (fronts that accept network clients or talk to a broker, and the
    HTTP status server) run each in a child process of its own; these bound what one may
    cost the fieldbus process (docs/architecture.md, "Process layout")."""

    memory_limit_mb: int = Field(
        384,
        ge=32,
        le=65_536,
        description="resident memory one north-facing child may use; above it, it is killed and restarted",
    )
    nice: int = Field(
        10,
        ge=0,
        le=19,
        description="niceness the children add to their own: under CPU contention the fieldbus process runs first",
    )
    fieldbus_nice: int | None = Field(
        None,
        ge=-20,
        le=19,
        description="niceness the fieldbus process asks for at start (below 0 needs CAP_SYS_NICE; "
        "refused: one line and it runs on)",
    )
    fieldbus_cpus: list[Annotated[int, Field(ge=0, le=4095)]] | None = Field(
        None,
        min_length=1,
        description="CPUs the fieldbus process runs on (e.g. [0]); the north-facing children "
        "then run on the others, and so does the kernel's work for their connections",
    )
    north_cpus: list[Annotated[int, Field(ge=0, le=4095)]] | None = Field(
        None,
        min_length=1,
        description="CPUs the north-facing children run on; default: every CPU but fieldbus_cpus "
        "when that is set, else as inherited",
    )
    liveness_timeout_s: float = Field(
        5.0,
        ge=0.5,
        le=300,
        description="a child whose event loop has not answered a ping for this long is killed and restarted",
    )
    start_timeout_s: float = Field(
        60.0, ge=1, le=600, description="how long a child may take to start serving"
    )
    feed_buffer_kb: int = Field(
        1024,
        ge=16,
        le=1_048_576,
        description="process-image changes queued for a child that reads slowly; beyond, they are "
        "dropped and it gets a fresh snapshot (a resync)",
    )
    feed_max_lag_ms: int = Field(
        1000,
        ge=50,
        le=600_000,
        description="a child that reads a change this much later than it was sent asks for a "
        "fresh snapshot and skips what was queued before it",
    )
    writes_per_s: float = Field(
        1000.0,
        gt=0,
        le=100_000,
        description="client write batches per second the fieldbus process applies for one child; "
        "a child sending more waits (its clients' writes are answered later)",
    )
    log_lines_per_minute: int = Field(
        600,
        ge=10,
        le=1_000_000,
        description="log lines one child may write a minute; more are counted and left out",
    )

    @model_validator(mode="after")
    def _cpus_apart(self) -> IsolationSettings:
        shared = set(self.fieldbus_cpus or ()) & set(self.north_cpus or ())
        if shared:
            raise ValueError(
                f"fieldbus_cpus and north_cpus share CPU {','.join(map(str, sorted(shared)))}: "
                "give the fieldbus process CPUs the children do not use"
            )
        return self


class GatewaySection(StrictModel):
    name: Identifier
    description: str = ""
    state_dir: str = Field(
        "fieldgate-state",
        description="directory for persisted settings (relative to the topology file)",
    )
    http: HttpSettings | None = Field(
        None, description="HTTP status API, metrics and live page; off unless given"
    )
    isolation: IsolationSettings = Field(
        default_factory=IsolationSettings,
        description="limits of the child processes north-facing parts run in",
    )


class ComponentConfig(StrictModel):
    name: Identifier
    type: str
    restart_backoff_s: float = Field(
        1.0,
        gt=0,
        le=300,
        description="first delay before restarting after a run-time failure; doubles up to 60 s, back to this after a minute without failure",
    )


class FrontConfig(ComponentConfig):
    expose: list[str] | None = Field(
        None,
        description="channel ids or glob patterns this front serves, in order; default: every channel in the seeds' order",
    )

    carried_types: ClassVar[frozenset[DataType] | None] = NARROW_TYPES
    """The channel data types this front can serve (None: every type). By default those of at
    most 32 bits (:data:`~fieldgate.image.NARROW_TYPES`: a front written before 64-bit values
    and strings existed, a CAN front's 16-bit words): channels of other types are left out of
    what it serves (``GatewayContext.front_channels``) and ``validate`` says so; naming one by
    its id in ``expose`` is an error. A front that serves every type sets None."""

    def written_outputs(self) -> list[str] | None:
        """Output channels (globs) this front writes; None: every output it serves.

        One output channel has one writing front (checked when the topology loads). A front
        that writes only some of the outputs it serves (the Sparkplug front's ``writable``)
        says which here.
        """
        return self.expose

    def served_backs(self, back_names: list[str]) -> list[str]:
        """Of ``back_names``, the backs whose channels this front serves or would serve: all
        without an ``expose`` list, else those an ``expose`` pattern's back part matches (a back
        with no channel yet, e.g. one that found no module, still counts)."""
        if self.expose is None:
            return list(back_names)
        parts = [pattern.split("/", 1)[0] for pattern in self.expose]
        return [n for n in back_names if any(fnmatchcase(n, part) for part in parts)]

    def topology_warnings(self, topology: Any) -> list[str]:
        """What ``fieldgate validate`` (and the log at start) should point out about this front
        in the whole topology although it is valid: a topology the box a style replaces
        could not hold. Default: nothing."""
        return []

    def check(self, topology: Any) -> list[tuple[tuple[Any, ...], str]]:
        """What this front can only check with the whole topology (its channels known), as
        ``(path below this front, message)`` pairs: the limits ``run`` would refuse at start
        (a CANopen head's image size, its default PDOs). Called by the loader for ``validate``,
        ``run`` and every other command alike. Default: nothing."""
        return []

    def validation_warnings(self) -> list[str]:
        """What ``fieldgate validate`` should point out although the section is valid
        (a listener that accepts clients without authenticating them)."""
        return []


class ModuleConfig(StrictModel):
    """One RS-485 module. Plugins subclass it to add model presets and channel declarations."""

    address: int = Field(ge=0, le=255)
    name: str | None = None
    model: str | None = None
    poll_ms: int | None = Field(
        None, ge=1, le=3_600_000, description="poll period; default: the line's poll_ms"
    )
    error_mode: ErrorModeSpec = Field(
        "hold", description="outputs' error mode when a front loses its master"
    )
    shutdown_mode: ErrorModeSpec | None = Field(
        None, description="outputs' value on gateway shutdown; default: leave as is"
    )
    error_modes: dict[str, ErrorModeSpec] = Field(
        default_factory=dict, description="per-channel override, key e.g. do3 or ao0"
    )

    def output_modes(self, kind: Kind, index: int) -> tuple[ErrorMode, ErrorMode | None]:
        local = f"{kind.value}{index}"
        spec = self.error_modes.get(local, self.error_mode)
        return to_error_mode(spec), to_error_mode(self.shutdown_mode)


class BackConfig(ComponentConfig):
    # a Sequence, so that a plugin's model narrows it to a list of its own module model
    modules: Sequence[ModuleConfig] = Field(default_factory=list)

    def channel_specs(self) -> list[ChannelSpec]:
        """Every channel this back provides. Plugins implement it."""
        raise NotImplementedError(f"{type(self).__name__} must implement channel_specs()")

    def finds_modules_at_start(self) -> bool:
        """True for a back that finds its modules when it starts (DCON ``modules: auto``):
        the gateway's image gets its channels from :meth:`GatewayContext.add_channels`, before
        any front starts; :meth:`channel_specs` gives what offline tools use (a scan file's)."""
        return False

    def modules_note(self) -> str:
        """Where the modules come from, when not from the file (``fieldgate validate``)."""
        return ""


class PolledBackConfig(BackConfig):
    """Settings every back that polls modules with core's line scheduler shares (an RS-485
    line, a Modbus TCP host): retries, poll periods, offline and re-probe, rewrites."""

    retries: int = Field(
        0,
        ge=0,
        le=10,
        description="immediate retries of a failed transaction; each failed attempt counts toward fail_threshold and the error counter",
    )
    poll_ms: int = Field(
        100,
        ge=0,
        le=3_600_000,
        description="default poll period of each module; 0 = as fast as the line allows",
    )
    fail_threshold: int = Field(
        3, ge=0, le=100, description="a module is offline when its consecutive failures exceed this"
    )
    offline_probe_ms: int = Field(
        5000, ge=10, le=3_600_000, description="re-probe period of an offline module"
    )
    write_period_ms: int | None = Field(
        None,
        ge=10,
        description="also rewrite outputs cyclically at this period; default: on change only",
    )

    def poll_load(self) -> list[tuple[str, float, float]]:
        """What ``validate`` counts against the poll budget: per line (or host) its name, the
        share of it the polls book at their periods (1.0 = all of it: worst case, every read
        due at once) and the requests per second. Empty when the back cannot say."""
        return []

    def timing_warnings(self) -> list[str]:
        """What ``validate`` warns about: lines or hosts booked beyond their time."""
        return []

    def load_notes(self) -> list[str]:
        """One line per line (or host) for ``validate``'s summary."""
        return [
            f"{name}: {rate:.1f} requests/s, {share * 100:.0f} % booked"
            for name, share, rate in self.poll_load()
        ]


class SerialBackConfig(PolledBackConfig):
    """Settings every RS-485 poller shares; the line scheduler in core reads them."""

    port: str = Field(
        description="serial device (/dev/ttyUSB0), or a pyserial URL such as socket://127.0.0.1:5020"
    )
    baudrate: int = Field(9600, ge=300, le=4_000_000)
    bytesize: Literal[7, 8] = 8
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    timeout_ms: int = Field(
        200,
        ge=1,
        le=60_000,
        description="response timeout: from the end of a request to the first byte of its reply "
        "(a long reply that starts in time is read whole)",
    )
    byte_timeout_ms: float | None = Field(
        None,
        gt=0,
        le=10_000,
        description="silence inside a reply that ends it; default 8 character times, at least 30 ms "
        "(a USB-RS485 adapter's latency timer never trips it)",
    )
    echo: bool | Literal["auto"] = Field(
        "auto",
        description="the adapter hears its own requests (2-wire RS-485): true, false, or auto "
        "(detected at the first exchange that tells); an echo is compared and dropped, never "
        "taken for the reply",
    )

    def timing(self) -> LineTiming:
        """Response timeout, inter-byte timeout and line silence of this line
        (fieldgate.serial_timing)."""
        return LineTiming.of(
            self.baudrate,
            self.timeout_ms,
            self.byte_timeout_ms,
            bits_per_char(self.bytesize, self.parity, self.stopbits),
        )

    def poll_wire_time(self, module: ModuleConfig) -> float | None:
        """Worst-case wire time of one poll of ``module`` at this line's baud rate (requests,
        replies, inter-frame silences); None when the plugin cannot say. Plugins implement it."""
        return None

    def poll_requests(self, module: ModuleConfig) -> int | None:
        """Requests one poll of ``module`` makes (every read due); None when the plugin cannot say."""
        return None

    def _line_load(self) -> tuple[float, float, float, list[int]]:
        """(share booked, worst-case time of every module's poll, requests/s, the periods)."""
        load, total, rate, periods = 0.0, 0.0, 0.0, []
        for module in self.modules:
            wire = self.poll_wire_time(module)
            period_ms = module.poll_ms if module.poll_ms is not None else self.poll_ms
            if wire is None or not period_ms:
                continue
            load += wire / (period_ms / 1000)
            total += wire
            rate += (self.poll_requests(module) or 0) / (period_ms / 1000)
            periods.append(period_ms)
        return load, total, rate, periods

    def poll_load(self) -> list[tuple[str, float, float]]:
        load, _total, rate, periods = self._line_load()
        return [(f"line {self.port} at {self.baudrate} baud", load, rate)] if periods else []

    def timing_warnings(self) -> list[str]:
        """What ``validate`` warns about: modules that cannot be polled within their poll_ms at
        this baud rate (the sum of their worst-case wire times, each per its own period)."""
        load, total, _rate, periods = self._line_load()
        if load <= 1.0:
            return []
        shortest = min(periods)
        return [
            f"backs.{self.name}: one poll of every module takes {total * 1000:.0f} ms on the wire "
            f"at {self.baudrate} baud (worst case), more than the line has within poll_ms "
            f"({shortest} ms{' and longer' if len(set(periods)) > 1 else ''}): the line is "
            f"{load * 100:.0f} % booked, so modules are polled less often than configured; "
            "raise the baud rate or poll_ms"
        ]
