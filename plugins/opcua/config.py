"""Topology section of the ``opcua`` front (pydantic, strict like every section).

The listener rules are checked here, so ``fieldgate validate`` refuses an exposed server
without security: security mode ``None`` only on a loopback address; any other address
needs Basic256Sha256 (``Sign``/``SignAndEncrypt``) and user names with passwords.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

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
    max_sessions: int = Field(32, ge=1, le=1000, description="concurrent client connections")

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
