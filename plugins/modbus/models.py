"""Device models: a device's channel groups defined once (``models:`` in the topology, or a CSV
register map), named by every module of that model in one line.

```yaml
models:
  em24:                          # any name; modules say model: em24
    type: modbus                 # read by the modbus backs (RTU and TCP)
    description: Carlo Gavazzi EM24 energy meter
    map: em24.csv                # a register map (relative to this file), and/or channels:
    channels:
      - {kind: ai, table: input_registers, address: 0x0102, type: int32, order: CDAB,
         divider: 10, unit: V, label: Voltage L1-N}
    max_read_registers: 60       # what a module of this model may read at once (it may say less)
    max_write_registers: 20      # and write at once (max_write_bits for coils; write_span: false)
backs:
  - name: meters
    type: modbus-tcp-client
    modules:
      - {address: 1, host: 10.0.0.21, model: em24}
      - {address: 2, host: 10.0.0.22, model: em24}
```

The CSV map has a header row naming its columns, one channel group per row: ``kind``,
``table`` and ``address`` (decimal or 0x hex: the PDU address, 0-based) are required; the
others are the channel group fields of the same name (``count``, ``type``, ``order``,
``registers``, ``length``, ``bits``, ``first_bit``, ``gain``, ``offset``, ``divider``,
``decimals``, ``unit``, ``low``, ``high`` (the range), ``label``, ``poll_ms``,
``write_fc``); an empty cell is not given. Lines starting with ``#`` are comments. An error
names the file, its line and the column.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, ValidationInfo, model_validator
from pydantic_core import PydanticCustomError

from fieldgate.topology import StrictModel

from .codec import MAX_READ_BITS, MAX_READ_REGISTERS, MAX_WRITE_BITS, MAX_WRITE_REGISTERS
from .groups import ChannelGroup

MAX_MAP_BYTES = 2 * 1024 * 1024
MAX_MAP_ROWS = 10_000
COLUMNS = (
    "kind",
    "table",
    "address",
    "count",
    "type",
    "order",
    "word_order",
    "registers",
    "length",
    "bits",
    "first_bit",
    "byte_order",
    "gain",
    "offset",
    "divider",
    "decimals",
    "unit",
    "low",
    "high",
    "label",
    "poll_ms",
    "write_fc",
)
_NUMBERS = {"address", "count", "registers", "length", "bits", "first_bit", "poll_ms", "write_fc"}
_FLOATS = {"gain", "offset", "divider", "low", "high"}


def _invalid(message: str, loc: tuple[str | int, ...] = ()) -> PydanticCustomError:
    return PydanticCustomError(
        "modbus_model",
        message.replace("{", "{{").replace("}", "}}"),
        {"loc": loc} if loc else None,
    )


class ModbusDeviceModel(StrictModel):
    """A device model of the modbus backs (an entry of the topology's ``models:``)."""

    type: Literal["modbus"] = "modbus"
    description: str = ""
    map: str | None = Field(
        None, description="a CSV register map, relative to the topology file (its groups first)"
    )
    channels: list[ChannelGroup] = Field(
        default_factory=list, description="channel groups (after the map's)"
    )
    max_read_registers: int | None = Field(
        None, ge=1, le=MAX_READ_REGISTERS, description="largest register read of such a device"
    )
    max_read_bits: int | None = Field(None, ge=1, le=MAX_READ_BITS)
    coalesce_gap: int | None = Field(None, ge=0, le=100)
    max_write_registers: int | None = Field(
        None, ge=1, le=MAX_WRITE_REGISTERS, description="largest FC16 write of such a device"
    )
    max_write_bits: int | None = Field(None, ge=1, le=MAX_WRITE_BITS)
    write_span: bool | None = Field(
        None, description="false: such a device gets only adjacent outputs in one write"
    )

    @model_validator(mode="after")
    def _read_map(self, info: ValidationInfo) -> ModbusDeviceModel:
        if self.map is not None:
            base = Path((info.context or {}).get("base_dir") or Path.cwd())
            groups = read_map(base / self.map, self.map)
            self.__dict__["channels"] = [*groups, *self.channels]  # (no re-validation)
        if not self.channels:
            raise _invalid("a model needs channels, or a map (a CSV register map)")
        return self


def read_map(path: Path, shown: str) -> list[ChannelGroup]:
    """The channel groups of a CSV register map; a PydanticCustomError naming the file, the
    line and the column of the first error (at ``map``)."""
    try:
        if not path.is_file():
            raise _invalid(f"{shown}: no such file", ("map",))
        raw = path.read_bytes()
    except OSError as exc:
        raise _invalid(f"{shown}: {exc.strerror or exc}", ("map",)) from None
    if len(raw) > MAX_MAP_BYTES:
        raise _invalid(
            f"{shown}: over {MAX_MAP_BYTES // 1024} KiB; is it a register map?", ("map",)
        )
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise _invalid(f"{shown}: not UTF-8 text", ("map",)) from None
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(io.StringIO(text)), 1)
        if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")
    ]
    if not rows:
        raise _invalid(f"{shown}: empty (a header row, then one row per channel group)", ("map",))
    header_line, header = rows[0]
    names = [cell.strip().lower() for cell in header]
    for name in names:
        if name not in COLUMNS:
            raise _invalid(
                f"{shown}:{header_line}: unknown column {name!r}; columns: {', '.join(COLUMNS)}",
                ("map",),
            )
    missing = [c for c in ("kind", "table", "address") if c not in names]
    if missing:
        raise _invalid(f"{shown}:{header_line}: no column {', '.join(missing)}", ("map",))
    if len(rows) - 1 > MAX_MAP_ROWS:
        raise _invalid(f"{shown}: more than {MAX_MAP_ROWS} rows", ("map",))
    groups = []
    for line, row in rows[1:]:
        fields: dict[str, Any] = {}
        for name, cell in zip(names, row, strict=False):
            cell = cell.strip()
            if not cell:
                continue
            try:
                fields[name] = _cell(name, cell)
            except ValueError:
                raise _invalid(
                    f"{shown}:{line}: {name}: {cell!r} is not a number", ("map",)
                ) from None
        if len(row) > len(names) and any(c.strip() for c in row[len(names) :]):
            raise _invalid(f"{shown}:{line}: more cells than the header has columns", ("map",))
        low, high = fields.pop("low", None), fields.pop("high", None)
        if low is not None or high is not None:
            fields["range"] = (low, high)
        try:
            groups.append(ChannelGroup.model_validate(fields))
        except ValidationError as exc:
            err = exc.errors(include_url=False)[0]
            where = ".".join(str(p) for p in err["loc"])
            raise _invalid(
                f"{shown}:{line}: {where + ': ' if where else ''}{err['msg']}", ("map",)
            ) from None
    return groups


def _cell(name: str, cell: str) -> Any:
    if name in _NUMBERS:
        return int(cell, 0)
    if name in _FLOATS:
        return float(cell)
    if name == "decimals":
        return int(cell)
    return cell
