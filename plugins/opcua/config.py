"""Topology section of the ``opcua`` front (pydantic, strict like every section).

The listener rules are checked here, so ``fieldgate validate`` refuses an exposed server
without security: security mode ``None`` only on a loopback address; any other address
needs Basic256Sha256 (``Sign``/``SignAndEncrypt``) and user names with passwords.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from fieldgate.image import DataType
from fieldgate.topology import FrontConfig
from fieldgate.topology.model import StrictModel, is_loopback, split_listen

SecurityMode = Literal["None", "Sign", "SignAndEncrypt"]


class OpcUaUser(StrictModel):
    name: str = Field(min_length=1, description="user name a client logs in with")
    password_file: str | None = Field(
        None, description="file holding the password (first line), relative to the topology file"
    )
    password_env: str | None = Field(None, description="environment variable holding the password")

    @model_validator(mode="after")
    def _one_source(self) -> OpcUaUser:
        if (self.password_file is None) == (self.password_env is None):
            raise ValueError("give password_file or password_env (one of them)")
        return self

    def password(self, base_dir: Path) -> str:
        """The password; ValueError with a one-line cause that never contains the secret."""
        if self.password_file is not None:
            path = Path(self.password_file)
            path = path if path.is_absolute() else base_dir / path
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except OSError as exc:
                raise ValueError(f"password_file {path}: {exc.strerror or exc}") from None
            if not lines or not lines[0]:
                raise ValueError(f"password_file {path} is empty")
            return lines[0]
        assert self.password_env is not None
        value = os.environ.get(self.password_env)
        if not value:
            raise ValueError(f"environment variable {self.password_env} is not set or empty")
        return value


class OpcUaFrontConfig(FrontConfig):
    type: Literal["opcua"] = "opcua"
    carried_types: ClassVar[frozenset[DataType] | None] = None  # Int64, UInt64, Double, String too
    listen: str = Field(
        "127.0.0.1:4840",
        description="HOST:PORT of the endpoint; a non-loopback address needs Sign/SignAndEncrypt and users",
    )
    security: list[SecurityMode] = Field(
        default_factory=lambda: list[SecurityMode](["None"]),
        min_length=1,
        description="endpoint security modes (policy Basic256Sha256 for Sign and SignAndEncrypt); None only on loopback",
    )
    certificate_file: str | None = Field(
        None,
        description="server certificate (DER or PEM); default: generated on first start into the state directory",
    )
    private_key_file: str | None = Field(None, description="private key of certificate_file (PEM)")
    trusted_clients_dir: str | None = Field(
        None,
        description="client application certificates trusted for Sign/SignAndEncrypt; default <state_dir>/<front>.opcua-pki/trusted",
    )
    users: list[OpcUaUser] = Field(
        default_factory=list,
        description="user names and where their passwords come from; with users, anonymous sessions are refused",
    )
    namespace_uri: str | None = Field(
        None, description="namespace of the gateway's nodes; default urn:fieldgate:<gateway name>"
    )
    writable: list[str] = Field(
        default_factory=list,
        description="output channels (globs) a client may write; each output has one writing front",
    )
    # -- what a client can make the server hold (docs/opcua.md, "Limits") --------------------
    max_connections: int = Field(
        64, ge=1, le=10_000, description="TCP connections in all; more: the least useful gives way"
    )
    max_connections_per_peer: int = Field(
        16, ge=1, le=10_000, description="TCP connections from one address"
    )
    max_sessions: int = Field(
        32, ge=1, le=1000, description="sessions in all (those waiting for their client included)"
    )
    max_sessions_per_peer: int = Field(8, ge=1, le=1000, description="sessions from one address")
    hello_timeout_s: float = Field(
        5.0, gt=0, le=300, description="seconds a new connection has to send its Hello"
    )
    activation_timeout_s: float = Field(
        15.0, gt=0, le=600, description="seconds a new connection has to activate a session"
    )
    max_session_timeout_ms: float = Field(
        60_000, ge=5_000, le=3_600_000, description="the longest session timeout granted"
    )
    max_chunk_size: int = Field(
        65_535,
        ge=8_192,
        le=16_777_216,
        description="the largest message chunk taken or sent (negotiated buffer sizes at most this)",
    )
    max_message_size: int = Field(
        4_194_304, ge=8_192, le=268_435_456, description="the largest request, its chunks added up"
    )
    max_chunk_count: int = Field(64, ge=1, le=65_536, description="chunks of one request")
    min_publishing_interval_ms: float = Field(
        100, ge=10, le=60_000, description="the fastest publishing interval granted"
    )
    min_sampling_interval_ms: float = Field(
        100,
        ge=0,
        le=60_000,
        description="the fastest sampling interval granted (0: every change is a sample)",
    )
    max_subscriptions_per_session: int = Field(10, ge=1, le=1000)
    max_monitored_items_per_subscription: int = Field(5_000, ge=1, le=1_000_000)
    max_monitored_items_per_session: int = Field(10_000, ge=1, le=1_000_000)
    max_queue_size: int = Field(
        100, ge=1, le=10_000, description="values a monitored item keeps between two publishes"
    )
    max_retransmission_queue: int = Field(
        16, ge=1, le=5_000, description="unacknowledged notifications kept per subscription"
    )

    @field_validator("listen")
    @classmethod
    def _listen(cls, value: str) -> str:
        split_listen(value)
        return value

    @field_validator("security")
    @classmethod
    def _distinct(cls, modes: list[str]) -> list[str]:
        if len(set(modes)) != len(modes):
            raise ValueError("a security mode is listed twice")
        return modes

    @model_validator(mode="after")
    def _exposed_needs_security(self) -> OpcUaFrontConfig:
        if (self.certificate_file is None) != (self.private_key_file is None):
            raise ValueError("certificate_file and private_key_file go together")
        host, _ = split_listen(self.listen)
        if is_loopback(host):
            return self
        if "None" in self.security:
            raise ValueError(
                f"listen {self.listen} is not a loopback address: security None would let anyone on "
                "the network read and write in clear; use security: [SignAndEncrypt] (or Sign) "
                "with users, or listen on 127.0.0.1"
            )
        if not self.users:
            raise ValueError(
                f"listen {self.listen} is not a loopback address: give users (name with "
                "password_file or password_env); anonymous sessions are refused off loopback"
            )
        return self

    @model_validator(mode="after")
    def _per_peer_within_total(self) -> OpcUaFrontConfig:
        for per, total in (
            ("max_connections_per_peer", "max_connections"),
            ("max_sessions_per_peer", "max_sessions"),
            ("max_monitored_items_per_subscription", "max_monitored_items_per_session"),
        ):
            if getattr(self, per) > getattr(self, total):
                raise ValueError(
                    f"{per} ({getattr(self, per)}) is above {total} ({getattr(self, total)})"
                )
        return self

    @property
    def host_port(self) -> tuple[str, int]:
        return split_listen(self.listen)

    @property
    def anonymous_allowed(self) -> bool:
        """Anonymous sessions: only on loopback and only when no users are configured."""
        return is_loopback(self.host_port[0]) and not self.users

    def written_outputs(self) -> list[str]:
        """Only the outputs listed as writable: a client can write nothing else."""
        return self.writable
