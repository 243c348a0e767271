"""The ``devicenet`` front's configuration: the bus (core's :class:`fieldgate.can.front.CanBusConfig`,
the bit rate one of DeviceNet's three), the MAC ID, the identity and the I/O connection paths."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, ModelWrapValidatorHandler, PrivateAttr, field_validator, model_validator
from pydantic_core import PydanticCustomError

from fieldgate.can.front import CanBusConfig
from fieldgate.topology import FrontConfig
from fieldgate.topology.model import StrictModel

from .paths import DEFAULT_PATHS, check_selector

I7241D_MAX_MODULES = 15  # seed-003 §1.3


class DeviceNetIdentity(StrictModel):
    vendor_id: int = Field(
        0,
        ge=0,
        le=0xFFFF,
        description="Identity attr 1 (also in the duplicate MAC check); the I-7241D uses 803",
    )
    device_type: int = Field(0, ge=0, le=0xFFFF, description="Identity attr 2 (0 = generic device)")
    product_code: int = Field(1, ge=0, le=0xFFFF, description="Identity attr 3")
    major_revision: int = Field(1, ge=1, le=127, description="Identity attr 4, major")
    minor_revision: int = Field(0, ge=0, le=255, description="Identity attr 4, minor")
    serial: int = Field(
        1,
        ge=0,
        le=0xFFFFFFFF,
        description="Identity attr 6; make it unique per gateway on one network",
    )
    product_name: str = Field(
        "fieldgate", min_length=1, max_length=32, description="Identity attr 7 (SHORT_STRING)"
    )


Selector = str | int


class ConnectionPath(StrictModel):
    """The assemblies one I/O connection type carries: ``di``, ``ai``, ``inputs`` (produce),
    ``do``, ``ao``, ``outputs`` (consume), an assembly instance number, or ``none``."""

    produce: Selector = Field("inputs", description="assembly the slave produces")
    consume: Selector = Field("none", description="assembly the slave consumes (outputs)")

    @field_validator("produce")
    @classmethod
    def _produce(cls, value: Selector) -> Selector:
        check_selector(value, output=False)
        return value

    @field_validator("consume")
    @classmethod
    def _consume(cls, value: Selector) -> Selector:
        check_selector(value, output=True)
        return value


class StrobePath(StrictModel):
    produce: Selector = Field(
        "inputs", description="assembly whose first 8 bytes answer the bit-strobe"
    )

    @field_validator("produce")
    @classmethod
    def _produce(cls, value: Selector) -> Selector:
        check_selector(value, output=False)
        return value


def _path(kind: str) -> ConnectionPath:
    produce, consume = DEFAULT_PATHS[kind]
    return ConnectionPath(produce=produce, consume=consume)


class IoPathsConfig(StrictModel):
    """Which assembly each I/O connection produces and consumes (the I-7241D utility's
    "I/O connection path"); docs/devicenet.md, "I/O connection paths"."""

    poll: ConnectionPath = Field(default_factory=lambda: _path("poll"))
    strobe: StrobePath = Field(default_factory=StrobePath)
    cos: ConnectionPath = Field(default_factory=lambda: _path("cos"))
    cyclic: ConnectionPath = Field(default_factory=lambda: _path("cyclic"))

    def selection(self) -> dict[str, tuple[Selector, Selector]]:
        return {
            "poll": (self.poll.produce, self.poll.consume),
            "strobe": (self.strobe.produce, "none"),
            "cos": (self.cos.produce, self.cos.consume),
            "cyclic": (self.cyclic.produce, self.cyclic.consume),
        }


class DeviceNetFrontConfig(FrontConfig, CanBusConfig):
    type: Literal["devicenet"] = "devicenet"
    bitrate: Literal[125_000, 250_000, 500_000] = Field(
        125_000,
        description="DeviceNet bit rate in bit/s: 125000, 250000 or 500000 ('baudrate' is its old spelling)",
    )
    mac_id: int = Field(
        ge=0,
        le=63,
        description="MAC ID 0..63, required: the I-7241D ships at 1, ODVA's default is 63",
    )
    dup_mac_timeout_ms: int = Field(
        1000,
        ge=10,
        le=5000,
        description="wait after each duplicate MAC ID request (DeviceNet: 1 s)",
    )
    store_file: str | None = Field(
        None,
        description="file keeping a MAC ID / baud rate set over the network (relative to the state dir); default <front name>.devicenet.json",
    )
    strict_lengths: bool = Field(
        False,
        description="refuse Set requests with trailing bytes (0x15); default tolerates them as the I-7241D does",
    )
    identity: DeviceNetIdentity = Field(default_factory=DeviceNetIdentity)
    io_paths: IoPathsConfig = Field(
        default_factory=IoPathsConfig,
        description="assembly each I/O connection produces and consumes: poll, strobe, cos, cyclic",
    )

    _old_spellings: list[str] = PrivateAttr(default_factory=list)

    @model_validator(mode="wrap")
    @classmethod
    def _baudrate_is_bitrate(cls, data: Any, handler: ModelWrapValidatorHandler[Any]) -> Any:
        """``baudrate`` is the old spelling of ``bitrate`` (the name every CAN front shares): taken,
        with a note."""
        old = isinstance(data, dict) and "baudrate" in data
        if old:
            if "bitrate" in data:
                raise PydanticCustomError(
                    "devicenet_config", "give bitrate only ('baudrate' is its old spelling)"
                )
            data = {("bitrate" if key == "baudrate" else key): value for key, value in data.items()}
        model = handler(data)
        if old:
            model._old_spellings.append("baudrate")
        return model

    def validation_warnings(self) -> list[str]:
        """The old spellings this section uses (``fieldgate validate``; the front logs them too)."""
        return [
            f"'{old}' is deprecated and goes away in the next release; use 'bitrate'"
            for old in self._old_spellings
        ]

    def topology_warnings(self, topology: Any) -> list[str]:
        """Where the topology goes beyond the I-7241D (audit 003 #30): more than 15 DCON modules
        behind it (seed-003 §1.3). fieldgate serves them (a superset)."""
        served = self.served_backs([b.name for b in topology.backs])
        return [
            f"back {back.name} has {len(back.modules)} DCON modules; the I-7241D holds at most "
            f"{I7241D_MAX_MODULES}: fieldgate serves them, the topology would not go back onto "
            "an I-7241D"
            for back in topology.backs
            if back.name in served
            and back.type == "dcon"
            and len(back.modules) > I7241D_MAX_MODULES
        ]
