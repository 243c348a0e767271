"""Topology models of the ``modbus-tcp-client`` back: Modbus TCP devices by host and unit id.

A device is a Modbus module (the same channel groups, types, orders, scaling and models as
the RTU back) at a ``host`` (HOST or HOST:PORT, port 502 by default) and a ``unit`` id.
Devices on one host share its connections; ``hosts`` sets a host's own limits
(``max_connections``, ``pipeline``, ``timeout_ms``, ``rtt_ms``). docs/modbus-tcp-client.md.
"""

from __future__ import annotations

import ipaddress
from typing import Literal

from pydantic import Field, model_validator

from fieldgate.image import ChannelSpec
from fieldgate.topology import ModuleConfig, PolledBackConfig, StrictModel

from .config import ModbusModuleConfig, device_specs, module_points, poll_blocks
from .groups import _invalid
from .points import Point

DEFAULT_PORT = 502


def parse_host(text: str, default_port: int = DEFAULT_PORT) -> tuple[str, int]:
    """``HOST``, ``HOST:PORT``, ``[IPv6]:PORT`` or a bare IPv6 address as (host, port);
    ValueError says what is wrong."""
    text = text.strip()
    if not text:
        raise ValueError("an empty host")
    if text.startswith("["):
        host, sep, rest = text[1:].partition("]")
        if not sep or (rest and not rest.startswith(":")):
            raise ValueError(f"expected [IPv6]:PORT, got {text!r}")
        port_text = rest[1:]
    elif text.count(":") > 1:  # a bare IPv6 address
        ipaddress.IPv6Address(text)
        host, port_text = text, ""
    else:
        host, _, port_text = text.partition(":")
    if not port_text:
        return host, default_port
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"port must be 1..65535, got {port_text!r}")
    return host, int(port_text)


def host_key(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class HostSettings(StrictModel):
    """One host's own limits (a key of the back's ``hosts``)."""

    max_connections: int | None = Field(
        None,
        ge=1,
        le=16,
        description="connections opened to this host at most (many RTUs and meters accept 1-3 "
        "clients in all); default: the back's",
    )
    pipeline: int | None = Field(
        None,
        ge=1,
        le=32,
        description="requests in flight on one connection: 1 = wait for each answer; more only "
        "where the device answers pipelined requests (by transaction id); default: the back's",
    )
    timeout_ms: int | None = Field(
        None, ge=1, le=60_000, description="response timeout; default: the back's"
    )
    rtt_ms: float | None = Field(
        None, gt=0, le=60_000, description="time the host takes per request; default: the back's"
    )


class ModbusTcpDeviceConfig(ModbusModuleConfig):
    address: int = Field(  # a wider range than an RTU unit id
        ge=1,
        le=65535,
        description="the device's number on this back: its channel ids are <back>/m<address>/...; "
        "also its unit id unless unit is given",
    )
    host: str | None = Field(
        None, description="HOST or HOST:PORT (port 502); default: the back's host"
    )
    unit: int | None = Field(
        None,
        ge=0,
        le=255,
        description="Modbus unit id (a device behind a TCP/RTU gateway: its RTU address; a "
        "native TCP device often 1 or 255); default: the back's unit, else the address (1..247)",
    )

    @model_validator(mode="after")
    def _host_valid(self) -> ModbusTcpDeviceConfig:
        if self.host is not None:
            try:
                parse_host(self.host)
            except ValueError as exc:
                raise _invalid(str(exc), ("host",)) from None
        return self


class ModbusTcpClientBackConfig(PolledBackConfig):
    type: Literal["modbus-tcp-client"] = "modbus-tcp-client"
    host: str | None = Field(
        None, description="HOST or HOST:PORT of devices that give none (port 502)"
    )
    unit: int | None = Field(
        None,
        ge=0,
        le=255,
        description="unit id of devices that give none (meters with an address of their own: "
        "often 1); default: each device's address",
    )
    modules: list[ModbusTcpDeviceConfig] = Field(min_length=1)
    poll_ms: int = Field(
        1000,
        ge=0,
        le=3_600_000,
        description="default poll period of each device; 0 = as fast as the host answers",
    )
    timeout_ms: int = Field(
        1000,
        ge=1,
        le=60_000,
        description="response timeout of a request (an answer later than this is dropped)",
    )
    connect_timeout_ms: int = Field(
        3000, ge=1, le=60_000, description="time a connection may take to open"
    )
    max_connections: int = Field(
        1,
        ge=1,
        le=16,
        description="connections opened to one host at most (hosts: per host)",
    )
    pipeline: int = Field(
        1,
        ge=1,
        le=32,
        description="requests in flight on one connection (hosts: per host); more than 1 only "
        "where the device allows",
    )
    rtt_ms: float = Field(
        10.0,
        gt=0,
        le=60_000,
        description="time a host takes per request, for validate's poll budget (a native TCP "
        "device: a few ms; devices behind a TCP/RTU gateway: their serial time)",
    )
    hosts: dict[str, HostSettings] = Field(
        default_factory=dict, description="HOST[:PORT] -> that host's own limits"
    )

    @model_validator(mode="after")
    def _hosts_known(self) -> ModbusTcpClientBackConfig:
        if self.host is not None:
            try:
                parse_host(self.host)
            except ValueError as exc:
                raise _invalid(str(exc), ("host",)) from None
        seen: dict[tuple[str, int, int], int] = {}
        for i, device in enumerate(self.modules):
            if device.host is None and self.host is None:
                raise _invalid(
                    "no host: give the device's host, or the back's host", ("modules", i, "host")
                )
            if device.unit is None and self.unit is None and device.address > 247:
                raise _invalid(
                    f"address {device.address} is no unit id (1..247): give the device's unit "
                    "(or the back's unit)",
                    ("modules", i, "unit"),
                )
            key = (*self.endpoint(device), self.unit_of(device))
            if key in seen:
                raise _invalid(
                    f"unit {key[2]} on {host_key(*key[:2])} is already modules[{seen[key]}]",
                    ("modules", i, "unit"),
                )
            seen[key] = i
        used = {host_key(*self.endpoint(d)) for d in self.modules}
        for name in self.hosts:
            try:
                endpoint = host_key(*parse_host(name))
            except ValueError as exc:
                raise _invalid(str(exc), ("hosts", name)) from None
            if endpoint not in used:
                raise _invalid(
                    f"no device is on {endpoint} (devices are on {', '.join(sorted(used))})",
                    ("hosts", name),
                )
        return self

    def unit_of(self, device: ModbusTcpDeviceConfig) -> int:
        """The unit id a device is asked with: its own, the back's, or its address."""
        if device.unit is not None:
            return device.unit
        return self.unit if self.unit is not None else device.address

    def endpoint(self, device: ModbusTcpDeviceConfig) -> tuple[str, int]:
        host = device.host if device.host is not None else self.host
        assert host is not None  # (checked)
        return parse_host(host)

    def host_settings(self, key: str) -> tuple[int, int, float, float]:
        """(max_connections, pipeline, timeout s, rtt s) of a host ``HOST:PORT``."""
        own = HostSettings()
        for name, settings in self.hosts.items():
            if host_key(*parse_host(name)) == key:
                own = settings
        return (
            own.max_connections or self.max_connections,
            own.pipeline or self.pipeline,
            (own.timeout_ms or self.timeout_ms) / 1000,
            (own.rtt_ms or self.rtt_ms) / 1000,
        )

    def by_host(self) -> dict[str, list[ModbusTcpDeviceConfig]]:
        """Devices grouped by host (``HOST:PORT``), hosts in the order they first appear."""
        out: dict[str, list[ModbusTcpDeviceConfig]] = {}
        for device in self.modules:
            out.setdefault(host_key(*self.endpoint(device)), []).append(device)
        return out

    def channel_specs(self) -> list[ChannelSpec]:
        return device_specs(self.name, self.modules)

    def points(self) -> dict[int, list[Point]]:
        return {m.address: module_points(self.name, m) for m in self.modules}

    def lanes(self, key: str) -> int:
        """Requests a host has in flight at most: its connections x its pipeline, no more than
        it has devices (a device's requests stay in order, one at a time)."""
        connections, pipeline, _, _ = self.host_settings(key)
        return min(connections * pipeline, len(self.by_host()[key]))

    def poll_load(self) -> list[tuple[str, float, float]]:
        """Per host: requests per second at the poll periods (every read due), and the share of
        the host's time they book at ``rtt_ms`` a request, over its lanes."""
        out = []
        for key, devices in self.by_host().items():
            _, _, _, rtt = self.host_settings(key)
            rate = 0.0
            for device in devices:
                period_ms = device.poll_ms if device.poll_ms is not None else self.poll_ms
                if period_ms:
                    rate += len(poll_blocks(self.name, device)) / (period_ms / 1000)
            out.append((f"host {key}", rate * rtt / self.lanes(key), rate))
        return out

    def timing_warnings(self) -> list[str]:
        out = []
        for name, share, rate in self.poll_load():
            if share > 1.0:
                key = name.removeprefix("host ")
                _, _, _, rtt = self.host_settings(key)
                out.append(
                    f"backs.{self.name}: {name} gets {rate:.0f} requests/s at the poll periods; at "
                    f"{rtt * 1000:g} ms a request over {self.lanes(key)} lane(s) it is "
                    f"{share * 100:.0f} % booked, so its devices are polled less often than "
                    "configured; raise poll_ms, or max_connections / pipeline where the device allows"
                )
        return out

    def describe_module(self, module: ModuleConfig) -> str:
        assert isinstance(module, ModbusTcpDeviceConfig)
        return f"unit {self.unit_of(module)} on {host_key(*self.endpoint(module))}"
