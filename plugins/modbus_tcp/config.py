"""Topology section of the ``modbus-tcp`` front.

Loopback by default. Any other listen address needs Modbus/TCP Security (TLS with client
certificates: ``tls`` with ``client_ca_file``) or an explicit ``allowed_peers`` list, which
``fieldgate validate`` reports as unauthenticated (a source address is no authentication).
"""

from __future__ import annotations

import ipaddress
from typing import ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from fieldgate.image import DataType
from fieldgate.topology import FrontConfig
from fieldgate.topology.model import StrictModel, is_loopback, split_listen


class ServerTls(StrictModel):
    cert_file: str = Field(description="server certificate (PEM)")
    key_file: str = Field(description="its private key (PEM)")
    client_ca_file: str = Field(
        description="CA bundle that signs the client certificates; a client without one is refused"
    )


class ModbusTcpFrontConfig(FrontConfig):
    type: Literal["modbus-tcp"] = "modbus-tcp"
    listen: str = Field(
        "127.0.0.1:502",
        description="HOST:PORT; a non-loopback address needs tls or allowed_peers",
    )
    unit_id: int = Field(
        1, ge=1, le=247, description="unit id the map answers (0 and 255 too: 'this device' on TCP)"
    )
    writable: list[str] = Field(
        default_factory=list,
        description="output channels (globs) clients may write; each output has one writing front",
    )
    word_order: Literal["big", "little"] = Field(
        "big",
        description="values of two registers or more: big = high word at the lower address "
        "(ABCD), little = low word first (CDAB); order says more",
    )
    order: Literal["ABCD", "CDAB", "BADC", "DCBA"] | None = Field(
        None,
        description="values of two registers or more (32/64-bit, text): ABCD (big-endian), CDAB "
        "(word swap), BADC (byte swap), DCBA (little-endian); default: word_order's",
    )
    scaled_values: Literal["float32", "float64", "raw"] = Field(
        "float32",
        description="channels a back scaled to engineering units: float32 (two registers), "
        "float64 (four), or raw (the device's own register value; writes converted back)",
    )
    comm_fault: Literal["value", "exception"] = Field(
        "value",
        description="reading a point whose module is offline: value = the last value; exception = 0x0B (gateway target failed to respond)",
    )
    tls: ServerTls | None = Field(
        None, description="Modbus/TCP Security: TLS with client certificates"
    )
    allowed_peers: list[str] | None = Field(
        None,
        description="client addresses or networks accepted (unauthenticated); others are disconnected",
    )
    max_clients: int = Field(
        32,
        ge=1,
        le=1024,
        description="connections in all; at the cap a new one closes the longest-idle connection "
        "that has no request in progress, and is refused only when every one is busy",
    )
    max_clients_per_peer: int = Field(
        16,
        ge=1,
        le=1024,
        description="connections from one client address; a new one over it closes that "
        "address's longest-idle connection",
    )
    idle_timeout_s: float = Field(
        60.0,
        ge=1.0,
        le=86_400.0,
        description="a connection with no request for this long is closed",
    )
    request_timeout_s: float = Field(
        5.0,
        ge=0.1,
        le=60.0,
        description="a request (MBAP frame) begun must be complete within this, and a TLS "
        "handshake done; else the connection is closed",
    )
    max_pending_requests: int = Field(
        16,
        ge=1,
        le=256,
        description="pipelined requests taken from one connection ahead of their answers; "
        "more wait in the client's socket (TCP flow control)",
    )

    @field_validator("listen")
    @classmethod
    def _listen(cls, value: str) -> str:
        split_listen(value)
        return value

    @field_validator("allowed_peers")
    @classmethod
    def _networks(cls, peers: list[str] | None) -> list[str] | None:
        for peer in peers or []:
            try:
                ipaddress.ip_network(peer, strict=False)
            except ValueError:
                raise ValueError(
                    f"{peer!r} is not an address or network (e.g. 10.0.0.5 or 10.0.0.0/24)"
                ) from None
        return peers

    @model_validator(mode="after")
    def _exposed(self) -> ModbusTcpFrontConfig:
        host, _ = split_listen(self.listen)
        if not is_loopback(host) and self.tls is None and not self.allowed_peers:
            raise ValueError(
                f"listen {self.listen} is not a loopback address: Modbus TCP has no authentication; "
                "give tls (Modbus/TCP Security with client certificates) or allowed_peers "
                "(client addresses, unauthenticated), or listen on 127.0.0.1"
            )
        return self

    carried_types: ClassVar[frozenset[DataType] | None] = None  # every type (docs/modbus-tcp.md)

    @property
    def host_port(self) -> tuple[str, int]:
        return split_listen(self.listen)

    @property
    def byte_order(self) -> str:
        """The order of values wider than a register (ABCD, CDAB, BADC, DCBA)."""
        if self.order is not None:
            return self.order
        return "ABCD" if self.word_order == "big" else "CDAB"

    @model_validator(mode="after")
    def _orders_agree(self) -> ModbusTcpFrontConfig:
        if (
            self.order is not None
            and "word_order" in self.model_fields_set
            and self.order != ("ABCD" if self.word_order == "big" else "CDAB")
        ):
            raise ValueError(
                f"order {self.order} and word_order {self.word_order} disagree; give order alone"
            )
        return self

    def written_outputs(self) -> list[str]:
        return self.writable

    def validation_warnings(self) -> list[str]:
        host, _ = split_listen(self.listen)
        if not is_loopback(host) and self.tls is None:
            return [
                f"listen {self.listen} without TLS: any client at {', '.join(self.allowed_peers or [])} "
                "can read and write unauthenticated (a source address is no authentication)"
            ]
        return []
