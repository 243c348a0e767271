"""Sparkplug B payloads: BIRTH/DATA/DEATH encoding and NCMD/DCMD decoding (protobuf).

Values of signed integer types go into ``int_value`` (uint32) as two's complement, as the
specification says; a command may carry an integer in ``int_value`` or ``long_value``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from google.protobuf.message import DecodeError

from fieldgate.image import DataType, Quality

from . import sparkplug_b_pb2 as pb
from .model import (
    BDSEQ,
    BOOLEAN,
    DOUBLE,
    INT64,
    NEXT_SERVER,
    QUALITY_CODE,
    REBIRTH,
    STRING,
    MetricDef,
    Sample,
    Value,
)

Metric = pb.Payload.Metric  # type: ignore[attr-defined]
Payload = pb.Payload  # type: ignore[attr-defined]

INT32_PROPERTY = 3


class PayloadError(ValueError):
    """A command payload that cannot be used; the message is a short reason."""


def _set_value(metric: object, dtype: DataType, value: Value) -> None:
    if dtype is DataType.BOOL:
        metric.boolean_value = bool(value)  # type: ignore[attr-defined]
    elif dtype is DataType.FLOAT32:
        metric.float_value = float(value)  # type: ignore[attr-defined]
    elif dtype is DataType.FLOAT64:
        metric.double_value = float(value)  # type: ignore[attr-defined]
    elif dtype is DataType.STRING:
        metric.string_value = str(value)  # type: ignore[attr-defined]
    elif dtype is DataType.INT64 or dtype is DataType.UINT64:
        metric.long_value = int(value) & 0xFFFFFFFFFFFFFFFF  # type: ignore[attr-defined]
    else:
        metric.int_value = int(value) & 0xFFFFFFFF  # type: ignore[attr-defined]


def _property(props: object, key: str, kind: int, value: object) -> None:
    props.keys.append(key)  # type: ignore[attr-defined]
    entry = props.values.add()  # type: ignore[attr-defined]
    entry.type = kind
    if kind == DOUBLE:
        entry.double_value = float(value)  # type: ignore[arg-type]
    elif kind == STRING:
        entry.string_value = str(value)
    else:
        entry.int_value = int(value)  # type: ignore[call-overload]


def _properties(metric: object, quality: Quality, scaling_def: MetricDef | None) -> None:
    props = metric.properties  # type: ignore[attr-defined]
    _property(props, "Quality", INT32_PROPERTY, QUALITY_CODE[quality])
    if quality is not Quality.GOOD:
        _property(props, "qualityCause", STRING, quality.value)
    scaling = scaling_def.scaling if scaling_def is not None else None
    if scaling is not None:
        for key, number in (
            ("rawLow", scaling.raw_min),
            ("rawHigh", scaling.raw_max),
            ("engLow", scaling.eng_min),
            ("engHigh", scaling.eng_max),
        ):
            _property(props, key, DOUBLE, number)
        if scaling.unit:
            _property(props, "engUnit", STRING, scaling.unit)
    eng = scaling_def.engineering if scaling_def is not None else None
    if eng is not None:  # the value is in engineering units: its unit and range, no raw range
        for key, bound in (("engLow", eng.low), ("engHigh", eng.high)):
            if bound is not None:
                _property(props, key, DOUBLE, bound)
        if eng.unit:
            _property(props, "engUnit", STRING, eng.unit)


def _add_metric(
    payload: object, m: MetricDef, sample: Sample, *, birth: bool, historical: bool = False
) -> None:
    metric = payload.metrics.add()  # type: ignore[attr-defined]
    if birth:
        metric.name = m.name
        metric.datatype = m.datatype
    metric.alias = m.alias
    metric.timestamp = sample.ts_ms
    if historical:
        metric.is_historical = True
    if sample.quality is Quality.NOT_READ:
        metric.is_null = True
    else:
        _set_value(metric, m.dtype, sample.value)
    if birth or sample.quality is not Quality.GOOD:
        _properties(metric, sample.quality, m if birth else None)
    # a DATA metric without the Quality property means GOOD (ch. 6, "only required if not GOOD")


def node_birth(ts_ms: int, bdseq: int) -> bytes:
    payload = Payload(timestamp=ts_ms, seq=0)
    metric = payload.metrics.add()
    metric.name, metric.timestamp, metric.datatype, metric.long_value = BDSEQ, ts_ms, INT64, bdseq
    for name in (REBIRTH, NEXT_SERVER):
        metric = payload.metrics.add()
        metric.name, metric.timestamp, metric.datatype = name, ts_ms, BOOLEAN
        metric.boolean_value = False
    return bytes(payload.SerializeToString())


def node_death(ts_ms: int, bdseq: int) -> bytes:
    payload = Payload(timestamp=ts_ms)
    metric = payload.metrics.add()
    metric.name, metric.timestamp, metric.datatype, metric.long_value = BDSEQ, ts_ms, INT64, bdseq
    return bytes(payload.SerializeToString())


def device_birth(ts_ms: int, seq: int, metrics: Iterable[tuple[MetricDef, Sample]]) -> bytes:
    payload = Payload(timestamp=ts_ms, seq=seq)
    for m, sample in metrics:
        _add_metric(payload, m, sample, birth=True)
    return bytes(payload.SerializeToString())


def device_death(ts_ms: int, seq: int) -> bytes:
    return bytes(Payload(timestamp=ts_ms, seq=seq).SerializeToString())


def device_data(
    ts_ms: int, seq: int, samples: Iterable[tuple[MetricDef, Sample]], historical: bool = False
) -> bytes:
    payload = Payload(timestamp=ts_ms, seq=seq)
    for m, sample in samples:
        _add_metric(payload, m, sample, birth=False, historical=historical)
    return bytes(payload.SerializeToString())


# -- commands -------------------------------------------------------------------------------
@dataclass(frozen=True)
class CommandMetric:
    name: str | None
    alias: int | None
    field: str | None  # which value field was set, None when none was
    raw: object  # the value of that field


def decode_command(data: bytes) -> list[CommandMetric]:
    try:
        payload = Payload.FromString(data)
    except (DecodeError, ValueError, RuntimeError) as exc:
        raise PayloadError(f"not a Sparkplug B payload ({exc})") from None
    out = []
    for metric in payload.metrics:
        field_name = metric.WhichOneof("value")
        out.append(
            CommandMetric(
                metric.name if metric.HasField("name") else None,
                metric.alias if metric.HasField("alias") else None,
                field_name,
                getattr(metric, field_name) if field_name else None,
            )
        )
    return out


def _signed(raw: int, bits: int) -> int:
    raw &= (1 << bits) - 1
    return raw - (1 << bits) if raw >> (bits - 1) else raw


def command_value(cmd: CommandMetric, dtype: DataType) -> Value:
    """The value a DCMD metric carries for a channel of ``dtype``; PayloadError when unusable."""
    f, raw = cmd.field, cmd.raw
    if dtype is DataType.BOOL:
        if f == "boolean_value":
            return bool(raw)
        raise PayloadError(f"expected boolean_value for a Boolean metric, got {f}")
    if dtype.is_float:
        if f in ("float_value", "double_value") and isinstance(raw, float) and math.isfinite(raw):
            return float(raw)
        if f in ("int_value", "long_value") and isinstance(raw, int):
            return float(raw)
        raise PayloadError(f"expected a finite number for a Float or Double metric, got {f}")
    if dtype is DataType.STRING:
        if f == "string_value" and isinstance(raw, str):
            return raw
        raise PayloadError(f"expected string_value for a String metric, got {f}")
    if f not in ("int_value", "long_value") or not isinstance(raw, int):
        raise PayloadError(f"expected int_value or long_value for an integer metric, got {f}")
    if dtype in (DataType.INT16, DataType.INT32, DataType.INT64):
        # two's complement in 32 bits (int_value) or 64 bits (long_value)
        return _signed(raw, 32 if f == "int_value" else 64)
    return raw
