"""Topology section of the ``sparkplug`` front (pydantic, strict like every section)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from fieldgate.image import DataType
from fieldgate.topology import FrontConfig
from fieldgate.topology.model import StrictModel, is_loopback

# Sparkplug topic elements: UTF-8 without the MQTT separators and wildcards.
TOPIC_ELEMENT = r"^[^/+#]+$"


class TlsSettings(StrictModel):
    ca_file: str | None = Field(
        None, description="CA bundle that verifies the broker; default: the system's trust store"
    )
    cert_file: str | None = Field(None, description="client certificate (PEM) for mutual TLS")
    key_file: str | None = Field(None, description="private key of cert_file (PEM)")

    @model_validator(mode="after")
    def _key_with_cert(self) -> TlsSettings:
        if (self.cert_file is None) != (self.key_file is None):
            raise ValueError("cert_file and key_file go together")
        return self


class BrokerSettings(StrictModel):
    host: str = Field(description="broker host name or address")
    port: int | None = Field(None, ge=1, le=65535, description="default 1883, or 8883 with tls")
    tls: TlsSettings | None = Field(
        None, description="connect with TLS (the broker certificate is always verified)"
    )
    username: str | None = None
    password_file: str | None = Field(
        None, description="file holding the password (first line); never put it in the YAML"
    )
    password_env: str | None = Field(None, description="environment variable holding the password")

    @property
    def effective_port(self) -> int:
        if self.port is not None:
            return self.port
        return 8883 if self.tls is not None else 1883

    @property
    def label(self) -> str:
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.effective_port}"

    @property
    def is_loopback(self) -> bool:
        return is_loopback(self.host)

    @model_validator(mode="after")
    def _one_password_source(self) -> BrokerSettings:
        if self.password_file is not None and self.password_env is not None:
            raise ValueError("give password_file or password_env, not both")
        if (self.password_file or self.password_env) and self.username is None:
            raise ValueError("a password needs a username")
        return self

    def password(self, base_dir: Path) -> str | None:
        """The password from its file or variable; ValueError with a one-line cause (never the secret)."""
        if self.password_file is not None:
            path = Path(self.password_file)
            path = path if path.is_absolute() else base_dir / path
            try:
                return (
                    path.read_text(encoding="utf-8").splitlines()[0] if path.stat().st_size else ""
                )
            except OSError as exc:
                raise ValueError(f"password_file {path}: {exc.strerror or exc}") from None
        if self.password_env is not None:
            value = os.environ.get(self.password_env)
            if value is None:
                raise ValueError(f"environment variable {self.password_env} is not set")
            return value
        return None


class SparkplugFrontConfig(FrontConfig):
    type: Literal["sparkplug"] = "sparkplug"
    carried_types: ClassVar[frozenset[DataType] | None] = None  # Int64, UInt64, Double, String too
    brokers: list[BrokerSettings] = Field(
        min_length=1,
        description="MQTT servers in order; the session moves to the next on failure, NCMD Next Server or an offline primary host",
    )
    group_id: str = Field(pattern=TOPIC_ELEMENT, description="Sparkplug group id")
    edge_node_id: str | None = Field(
        None, pattern=TOPIC_ELEMENT, description="Sparkplug edge node id; default: the gateway name"
    )
    primary_host_id: str | None = Field(
        None,
        pattern=TOPIC_ELEMENT,
        description="publish only while this host application's STATE is online",
    )
    primary_host_wait_s: float = Field(
        10.0,
        gt=0,
        le=3600,
        description="with primary_host_id and several brokers: move to the next broker when the host's STATE has not said online within this long (an offline STATE moves at once)",
    )
    client_id: str | None = Field(
        None, description="MQTT client id; default fieldgate-<group>-<edge node>"
    )
    keepalive_s: int = Field(30, ge=5, le=3600)
    writable: list[str] = Field(
        default_factory=list,
        description="output channels (globs) a DCMD may write; each output has one writing front",
    )
    deadband: dict[str, float] = Field(
        default_factory=dict,
        description="glob -> absolute deadband on the raw value; a change smaller than it is not published",
    )
    data_qos: Literal[0, 1] = Field(
        0,
        description="QoS of DDATA, live and historical: 0 = Sparkplug 3.0 (tck-id-payloads-ddata-qos); 1 = at-least-once delivery to QoS 1 subscribers, also those offline with a persistent session (not Sparkplug conformant)",
    )
    journal_file: str | None = Field(
        None,
        description="store-and-forward journal (SQLite) relative to the state dir; default <front name>.journal.sqlite",
    )
    journal_max_samples: int = Field(
        1_000_000,
        ge=100,
        description="journal capacity; when full the oldest samples are dropped and counted",
    )
    journal_sync: Literal["normal", "full"] = Field(
        "normal",
        description="normal: survives a crash of the process (kill -9); full: also a power cut, fsync per commit",
    )
    replay_messages_per_s: float = Field(
        20.0, gt=0, le=10_000, description="rate cap of historical DDATA replayed after a reconnect"
    )
    replay_batch: int = Field(
        500, ge=1, le=10_000, description="samples per historical DDATA message"
    )
    replay_window: int = Field(
        8, ge=1, le=1000, description="historical messages awaiting PUBACK at once"
    )
    reconnect_min_s: float = Field(0.5, gt=0, le=60, description="first reconnect delay")
    reconnect_max_s: float = Field(
        8.0, gt=0, le=600, description="reconnect delay cap (doubles up to it)"
    )
    max_command_bytes: int = Field(
        65536,
        ge=64,
        le=16 * 1024 * 1024,
        description="larger NCMD/DCMD payloads are counted and dropped (STATE: 4 KiB)",
    )
    rebirth_min_interval_ms: int = Field(
        1000,
        ge=0,
        le=600_000,
        description="at most one NCMD rebirth this often; requests in between are coalesced into one",
    )

    @field_validator("brokers")
    @classmethod
    def _distinct_brokers(cls, brokers: list[BrokerSettings]) -> list[BrokerSettings]:
        seen = set()
        for broker in brokers:
            if broker.label in seen:
                raise ValueError(f"{broker.label} is listed twice")
            seen.add(broker.label)
        return brokers

    @model_validator(mode="after")
    def _reconnect_order(self) -> SparkplugFrontConfig:
        if self.reconnect_max_s < self.reconnect_min_s:
            raise ValueError("reconnect_max_s must not be below reconnect_min_s")
        return self

    def validation_warnings(self) -> list[str]:
        if self.data_qos == 1:
            return [
                "data_qos: 1 publishes DDATA at QoS 1 (at-least-once delivery): not Sparkplug B 3.0"
                " conformant, which requires QoS 0 (tck-id-payloads-ddata-qos); a strict host or"
                " the Eclipse Sparkplug TCK reports it as a failure (docs/sparkplug.md)"
            ]
        return []

    def written_outputs(self) -> list[str]:
        """Only the outputs listed as writable: a DCMD can write nothing else."""
        return self.writable
