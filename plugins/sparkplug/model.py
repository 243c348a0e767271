"""What the edge node publishes: one Sparkplug device per back module, one metric per channel.

Names and aliases are fixed here, once, from the front's channels in order: device
``<back>-m<address>``, metric ``<kind><index>`` (``di0``, ``ao3``), aliases 1, 2, 3... unique
across the whole edge node (two modules both have a ``di0``; their aliases differ). The node's
own metrics (``bdSeq``, ``Node Control/Rebirth``, ``Node Control/Next Server``) have no alias,
so a host can ask for a rebirth by name.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from fieldgate.image import Channel, DataType, Engineering, Quality, Scaling

# Sparkplug B data type numbers (sparkplug_b.proto's table)
INT16, INT32, INT64, UINT8, UINT16, UINT32, UINT64 = 2, 3, 4, 5, 6, 7, 8
FLOAT, DOUBLE, BOOLEAN, STRING = 9, 10, 11, 12

SPARKPLUG_TYPE: dict[DataType, int] = {
    DataType.BOOL: BOOLEAN,
    DataType.UINT8: UINT8,  # the bytes of special blocks (SI/SO, NA-9161 0x3000/0x3200)
    DataType.INT16: INT16,
    DataType.UINT16: UINT16,
    DataType.INT32: INT32,
    DataType.UINT32: UINT32,
    DataType.FLOAT32: FLOAT,
    DataType.INT64: INT64,
    DataType.UINT64: UINT64,
    DataType.FLOAT64: DOUBLE,
    DataType.STRING: STRING,
}

# Sparkplug quality codes (ch. 6 "Quality Codes"): 0 BAD, 192 GOOD, 500 STALE.
BAD, GOOD, STALE = 0, 192, 500
QUALITY_CODE: dict[Quality, int] = {
    Quality.GOOD: GOOD,
    Quality.STALE: STALE,  # last read failed, the value is the last good one
    Quality.COMM_FAULT: STALE,  # module offline: the value is the last good one
    Quality.NOT_READ: BAD,  # no value yet (published with is_null)
    Quality.OVER_RANGE: BAD,
    Quality.UNDER_RANGE: BAD,
    Quality.WATCHDOG: BAD,
    Quality.CONFIG_ERROR: BAD,
}

REBIRTH = "Node Control/Rebirth"
NEXT_SERVER = "Node Control/Next Server"
BDSEQ = "bdSeq"

Value = bool | int | float | str


@dataclass(frozen=True)
class MetricDef:
    channel_id: str
    device: str
    name: str
    alias: int
    dtype: DataType
    writable: bool = False
    deadband: float = 0.0
    scaling: Scaling | None = None  # display only: the host scales (rawLow.. properties)
    engineering: Engineering | None = None  # the value is in these units (engUnit, engLow..)
    label: str = ""

    @property
    def datatype(self) -> int:
        return SPARKPLUG_TYPE[self.dtype]


@dataclass
class DeviceDef:
    device_id: str
    back: str
    address: int
    metrics: list[MetricDef] = field(default_factory=list)


@dataclass(frozen=True)
class Sample:
    """One value of one channel at its acquisition time (ms since the epoch)."""

    channel_id: str
    value: Value
    quality: Quality
    ts_ms: int


def device_id(back: str, address: int) -> str:
    return f"{back}-m{address}"


class NodeModel:
    """The edge node's devices and metrics, with lookups by channel, device and alias."""

    def __init__(self, group_id: str, edge_node_id: str, devices: Iterable[DeviceDef]):
        self.group_id = group_id
        self.edge_node_id = edge_node_id
        self.devices: dict[str, DeviceDef] = {d.device_id: d for d in devices}
        self.by_channel: dict[str, MetricDef] = {}
        self.by_alias: dict[int, MetricDef] = {}
        self.by_device_name: dict[tuple[str, str], MetricDef] = {}
        for device in self.devices.values():
            for metric in device.metrics:
                if metric.alias in self.by_alias:
                    raise ValueError(f"alias {metric.alias} used twice")
                self.by_channel[metric.channel_id] = metric
                self.by_alias[metric.alias] = metric
                self.by_device_name[(device.device_id, metric.name)] = metric
        self.module_device: dict[tuple[str, int], str] = {
            (d.back, d.address): d.device_id for d in self.devices.values()
        }

    @classmethod
    def from_channels(
        cls,
        group_id: str,
        edge_node_id: str,
        channels: Iterable[Channel],
        writable: Iterable[str] = (),
        deadband: Mapping[str, float] | None = None,
    ) -> NodeModel:
        writable = list(writable)
        deadband = dict(deadband or {})
        devices: dict[str, DeviceDef] = {}
        alias = 0
        for channel in channels:
            src = channel.source
            dev_id = device_id(src.back, src.module)
            device = devices.setdefault(dev_id, DeviceDef(dev_id, src.back, src.module))
            alias += 1
            band = 0.0
            for pattern, value in deadband.items():
                if fnmatch.fnmatchcase(channel.id, pattern):
                    band = value
                    break
            device.metrics.append(
                MetricDef(
                    channel_id=channel.id,
                    device=dev_id,
                    name=channel.id.rsplit("/", 1)[-1],
                    alias=alias,
                    dtype=channel.spec.data_type,
                    writable=channel.kind.is_output
                    and any(fnmatch.fnmatchcase(channel.id, p) for p in writable),
                    deadband=band,
                    scaling=channel.spec.scaling,
                    engineering=channel.spec.engineering,
                    label=channel.spec.label,
                )
            )
        return cls(group_id, edge_node_id, devices.values())

    # -- topics ----------------------------------------------------------------------
    def node_topic(self, message_type: str) -> str:
        return f"spBv1.0/{self.group_id}/{message_type}/{self.edge_node_id}"

    def device_topic(self, message_type: str, device: str) -> str:
        return f"spBv1.0/{self.group_id}/{message_type}/{self.edge_node_id}/{device}"
