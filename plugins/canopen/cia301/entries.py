"""Object-dictionary entries of the I/O device layer, bound to live data.

The PDO engine, the CiA 401 profile and the manufacturer objects each describe the
objects they serve as :class:`ObjectDef` records whose :class:`Entry` items carry a
getter and (when writable) a setter. A :class:`Directory` collects them, encodes and
decodes values by CiA 301 data type, and answers the questions PDO mapping asks
(does the entry exist, is it mappable, how many bits). The CANopen node binds the
same entries into its SDO-served object dictionary, and the EDS writer prints them,
so the dictionary that is served and the EDS that describes it come from one place.

Setters validate and raise :class:`Abort` with a CiA 301 abort code; they never let
another exception escape for bad input.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from .abort import (
    LENGTH_TOO_HIGH,
    LENGTH_TOO_LOW,
    NO_OBJECT,
    NO_SUBINDEX,
    READ_ONLY,
    VALUE_TOO_HIGH,
    VALUE_TOO_LOW,
    WRITE_ONLY,
    SdoAbort,
)

if TYPE_CHECKING:
    from .od import Dictionary

# CiA 301 data type indices
BOOLEAN, INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32 = (
    0x01,
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
    0x07,
)
VISIBLE_STRING = 0x09
DOMAIN = 0x0F  # a block of bytes of any length (the NA-9161's slot memory and parameters)
REAL32, REAL64, INTEGER64, UNSIGNED64 = 0x08, 0x11, 0x15, 0x1B  # (an EDS device's objects)
REAL_TYPES = (REAL32, REAL64)
Value = int | float | str | bytes

_FORMATS = {
    BOOLEAN: "<?",
    INTEGER8: "<b",
    INTEGER16: "<h",
    INTEGER32: "<i",
    UNSIGNED8: "<B",
    UNSIGNED16: "<H",
    UNSIGNED32: "<I",
    REAL32: "<f",
    REAL64: "<d",
    INTEGER64: "<q",
    UNSIGNED64: "<Q",
}
RANGES = {
    BOOLEAN: (0, 1),
    INTEGER8: (-0x80, 0x7F),
    INTEGER16: (-0x8000, 0x7FFF),
    INTEGER32: (-0x8000_0000, 0x7FFF_FFFF),
    UNSIGNED8: (0, 0xFF),
    UNSIGNED16: (0, 0xFFFF),
    UNSIGNED32: (0, 0xFFFF_FFFF),
}

# Abort codes (CiA 301) and the exception are the node's own, see .abort.
Abort = SdoAbort  # an SDO or mapping request refused with a CiA 301 abort code


def bits_of(dtype: int) -> int:
    return 8 * struct.calcsize(_FORMATS[dtype]) if dtype in _FORMATS else 0


def encode(dtype: int, value: Value) -> bytes:
    if dtype == VISIBLE_STRING:
        return str(value).encode("latin-1", "replace")
    if dtype == DOMAIN:
        return bytes(value) if isinstance(value, (bytes, bytearray)) else b""
    return struct.pack(_FORMATS[dtype], value)


def decode(dtype: int, data: bytes) -> Value:
    if dtype == VISIBLE_STRING:
        return data.decode("latin-1")
    if dtype == DOMAIN:
        return bytes(data)
    size = struct.calcsize(_FORMATS[dtype])
    if len(data) > size:
        raise Abort(LENGTH_TOO_HIGH, "data too long")
    if len(data) < size:
        raise Abort(LENGTH_TOO_LOW, "data too short")
    value = struct.unpack(_FORMATS[dtype], data)[0]
    return float(value) if dtype in REAL_TYPES else int(value)


def check_range(dtype: int, value: int, low: int | None = None, high: int | None = None) -> int:
    lo, hi = RANGES.get(dtype, (None, None))
    low = lo if low is None else low
    high = hi if high is None else high
    if low is not None and value < low:
        raise Abort(VALUE_TOO_LOW, f"{value} < {low}")
    if high is not None and value > high:
        raise Abort(VALUE_TOO_HIGH, f"{value} > {high}")
    return value


@dataclass
class Entry:
    """One sub-index. ``access``: ro, rw, wo or const (CiA 306 AccessType)."""

    sub: int
    name: str
    dtype: int
    access: str
    get: Callable[[], Value]
    set: Callable[[Any], None] | None = None
    default: Value | None = None  # EDS DefaultValue; None: the value at build time
    default_expr: str | None = None  # e.g. "$NODEID+0x180"
    mappable: bool = False
    low: int | None = None
    high: int | None = None

    @property
    def readable(self) -> bool:
        return self.access in ("ro", "rw", "const")

    @property
    def writable(self) -> bool:
        return self.access in ("rw", "wo")

    @property
    def bits(self) -> int:
        return bits_of(self.dtype)

    def write(self, value: int) -> None:
        self.store(value)

    def store(self, value: Value) -> None:
        """Take a written value of any type: integers are range-checked, blocks (DOMAIN) and
        strings go to the setter, which checks their length."""
        if not self.writable or self.set is None:
            raise Abort(READ_ONLY, f"{self.name} is read-only")
        if isinstance(value, int):
            check_range(self.dtype, value, self.low, self.high)
        self.set(value)


@dataclass
class ObjectDef:
    """An object: a VAR (one entry, sub 0), an ARRAY or a RECORD (sub 0 = highest sub)."""

    index: int
    name: str
    kind: str  # "var", "array", "record"
    entries: list[Entry] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.by_sub = {e.sub: e for e in self.entries}


def const(value: int) -> Callable[[], int]:
    return lambda: value


def count_entry(n: int, name: str = "Highest sub-index supported") -> Entry:
    return Entry(0, name, UNSIGNED8, "const", const(n), default=n)


def array(index: int, name: str, items: Iterable[Entry]) -> ObjectDef:
    items = list(items)
    return ObjectDef(index, name, "array", [count_entry(len(items), "Number of entries")] + items)


Owner = TypeVar("Owner")  # the object that serves the entries (a profile, the manufacturer objects)


@dataclass(frozen=True)
class ObjectSpec(Generic[Owner]):
    """One object as data, served by an owner of type ``Owner``.

    ``over`` names a sequence of the owner (:func:`build_objects` asks ``items(over)``): the
    object is an ARRAY with sub-index k + 1 for item k, and is left out when the sequence is
    empty; ``over`` None makes a VAR (``get``/``put`` receive None as the item). ``get(owner,
    item)`` reads an entry, ``put(owner, item, value)`` writes it (None: read-only).
    ``entry`` names each entry: ``{n}`` is its sub-index, ``{i}`` the item's position, or a
    function of (sub-index, item). ``default`` is the EDS default; None: the value ``get``
    gives when the object is built.
    """

    index: int
    name: str
    entry: str | Callable[[int, Any], str]
    dtype: int
    access: str
    over: str | None
    get: Callable[[Owner, Any], Value]
    put: Callable[[Owner, Any, Any], None] | None = None
    default: Value | None = None
    mappable: bool = False
    high: int | None = None

    def entry_for(self, owner: Owner, sub: int, item: Any) -> Entry:
        name = (
            self.entry(sub, item) if callable(self.entry) else self.entry.format(n=sub, i=sub - 1)
        )
        return Entry(
            sub,
            name,
            self.dtype,
            self.access,
            partial(self.get, owner, item),
            partial(self.put, owner, item) if self.put is not None else None,
            default=self.get(owner, item) if self.default is None else self.default,
            mappable=self.mappable,
            high=self.high,
        )


def build_objects(
    owner: Owner, specs: Iterable[ObjectSpec[Owner]], items: Callable[[str], Sequence[Any]]
) -> list[ObjectDef]:
    """The objects of ``specs`` bound to ``owner``: the one builder of every object table."""
    objects: list[ObjectDef] = []
    for spec in specs:
        if spec.over is None:
            objects.append(
                ObjectDef(spec.index, spec.name, "var", [spec.entry_for(owner, 0, None)])
            )
            continue
        sequence = items(spec.over)
        if sequence:
            objects.append(
                array(
                    spec.index,
                    spec.name,
                    (spec.entry_for(owner, k + 1, item) for k, item in enumerate(sequence)),
                )
            )
    return objects


def item(name: str) -> tuple[Callable[[Any, int], Any], Callable[[Any, int, Any], None]]:
    """``get`` and ``put`` of an :class:`ObjectSpec` over a plain list attribute of the owner."""

    def get(owner: Any, n: int) -> Any:
        return getattr(owner, name)[n]

    def put(owner: Any, n: int, value: Any) -> None:
        getattr(owner, name)[n] = value

    return get, put


class Directory:
    """All objects of one node's I/O layer, by index and sub-index.

    ``batch`` makes the context the PDO engine writes one message's entries in (an RPDO,
    or the RPDOs applied at one SYNC): the CiA 401 objects collect their process-image
    writes inside it and write them as one batch when it ends. Default: no batching.
    """

    def __init__(
        self,
        objects: Iterable[ObjectDef] = (),
        batch: Callable[[], AbstractContextManager[object]] = nullcontext,
    ):
        self._objects: dict[int, ObjectDef] = {}
        self.batch = batch
        for obj in objects:
            self.add(obj)

    def add(self, obj: ObjectDef) -> None:
        if obj.index in self._objects:
            raise ValueError(f"object 0x{obj.index:04X} defined twice")
        self._objects[obj.index] = obj

    def __iter__(self) -> Iterator[ObjectDef]:
        return iter(sorted(self._objects.values(), key=lambda o: o.index))

    def __contains__(self, index: int) -> bool:
        return index in self._objects

    def object(self, index: int) -> ObjectDef:
        try:
            return self._objects[index]
        except KeyError:
            raise Abort(NO_OBJECT, f"no object 0x{index:04X}") from None

    def entry(self, index: int, sub: int) -> Entry:
        obj = self.object(index)
        try:
            return obj.by_sub[sub]
        except KeyError:
            raise Abort(NO_SUBINDEX, f"no sub-index {sub} in 0x{index:04X}") from None

    def read(self, index: int, sub: int) -> bytes:
        entry = self.entry(index, sub)
        if not entry.readable:
            raise Abort(WRITE_ONLY, f"0x{index:04X}:{sub} is write-only")
        return encode(entry.dtype, entry.get())

    def write(self, index: int, sub: int, data: bytes) -> None:
        entry = self.entry(index, sub)
        if not entry.writable:
            raise Abort(READ_ONLY, f"0x{index:04X}:{sub} is read-only")
        entry.store(decode(entry.dtype, data))

    def value(self, index: int, sub: int) -> Value:
        return self.entry(index, sub).get()


def bind_object(od: Dictionary, obj: ObjectDef) -> None:
    """Add one :class:`ObjectDef` to the node's dictionary with its getters and setters."""
    if obj.kind == "var":
        e = obj.entries[0]
        od.add_variable(
            obj.index,
            obj.name,
            e.dtype,
            e.access,
            _model_default(e),
            minimum=e.low,
            maximum=e.high,
            mappable=e.mappable,
        )
    else:
        members = [
            (
                e.sub,
                e.name,
                e.dtype,
                e.access,
                _model_default(e),
                {
                    "minimum": e.low,
                    "maximum": e.high,
                    "mappable": e.mappable,
                    "relative": e.default_expr is not None,
                },
            )
            for e in obj.entries
            if e.sub != 0
        ]
        od.add_record(obj.index, obj.name, members, array=obj.kind == "array")
        sub0 = obj.by_sub.get(0)
        if sub0 is not None and sub0.writable:
            var = od.variable(obj.index, 0)
            var.access_type = sub0.access
            var.default = int(_model_default(sub0))  # sub 0: UNSIGNED8, the highest sub-index
    for e in obj.entries:
        if e.sub == 0 and obj.kind != "var" and not e.writable:
            continue  # the dictionary's own "highest sub-index" entry
        od.bind(obj.index, e.sub, getter=e.get, setter=e.store if e.writable else None)


def _model_default(e: Entry) -> Value:
    """The EDS default: relative COB-IDs keep their base (the dictionary adds the node-ID)."""
    if e.default_expr is not None:
        return int(e.default_expr.split("+", 1)[1], 0)
    if e.default is not None:
        return e.default
    value = e.get()
    return int(value) if e.dtype == BOOLEAN else value
