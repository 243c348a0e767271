"""The node's object dictionary: canopen's ``ObjectDictionary`` model plus live values.

The *model* (names, data types, access types, limits, defaults, EDS export) is
canopen's :class:`canopen.ObjectDictionary`; :class:`Dictionary` adds what a slave
needs on top of it:

* current values, kept per ``(index, subindex)`` and separate from the model's
  defaults, with *stored* values (0x1010) that reset communication / reset node
  reload: the communication area (0x1000-0x1FFF) on reset communication, everything on
  reset node;
* bindings: an entry can be served by a getter (process image inputs) and/or a
  setter (outputs), so SDO answers never wait on a back end; a getter bound with
  ``thread_safe=True`` may also be called from the CAN receive thread
  (:meth:`read_quick`), any other getter only from the event loop;
* validators per index (``add_validator``) that veto a write with an abort code, and
  write listeners (``on_write``) that react after a write took effect (an SDO write or
  :meth:`set`; reloads at a reset do not call them);
* :meth:`write` checks existence, access, length, type and range (0609 0031/0032)
  and runs the validators *before* the value changes; it raises :class:`SdoAbort`;
* for a device read from an EDS/DCF (:mod:`..device`, whose objects
  :class:`~.od_file.FileDictionary` adds as canopen's import made them): *readers*
  (:meth:`add_reader`) that serve SDO uploads of an entry (and may raise
  :class:`~.abort.Deferred`, as validators may), objects the node keeps for its services but
  does not serve (``hidden``: 0602 0000, not in the EDS) and entries a store does not save
  (``volatile``: StorageLocation=RAM).

Other services (PDO engine, CiA 401 objects, LSS) add their entries with
:meth:`add_variable` / :meth:`add_record` / :meth:`add_array` and hook in with
validators, listeners and bindings.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable, Iterator
from typing import Any

from canopen import objectdictionary as cod
from canopen.objectdictionary import datatypes as dt

from . import abort
from .abort import Deferred, SdoAbort

Value = int | float | str | bytes
Getter = Callable[[], Value]
Reader = Callable[[], Value]  # an SDO upload's value; may raise SdoAbort or Deferred
# Setters, validators and write listeners get a value of their entry's data type (encode()
# checked it): an int for an integer entry. That type is known per entry, at run time, so the
# value parameter is Any and each callback annotates the type of the entries it is bound to.
Setter = Callable[[Any], None]
Validator = Callable[[int, Any], None]  # (subindex, new value); raise SdoAbort to refuse
WriteListener = Callable[[int, int, Any], None]  # (index, subindex, value) after the write

COMMUNICATION_AREA = range(0x1000, 0x2000)
STRING_TYPES = (dt.VISIBLE_STRING, dt.OCTET_STRING, dt.UNICODE_STRING, dt.DOMAIN)
DEFAULT_MAX_SIZE = 1024  # bytes accepted for a writable string/domain without its own limit

_TYPE_RANGES = {
    dt.BOOLEAN: (0, 1),
    **{
        t: (-(1 << (8 * s - 1)), (1 << (8 * s - 1)) - 1)
        for t, s in (
            (dt.INTEGER8, 1),
            (dt.INTEGER16, 2),
            (dt.INTEGER24, 3),
            (dt.INTEGER32, 4),
            (dt.INTEGER64, 8),
        )
    },
    **{
        t: (0, (1 << (8 * s)) - 1)
        for t, s in (
            (dt.UNSIGNED8, 1),
            (dt.UNSIGNED16, 2),
            (dt.UNSIGNED24, 3),
            (dt.UNSIGNED32, 4),
            (dt.UNSIGNED64, 8),
        )
    },
}


def size_of(var: cod.ODVariable) -> int | None:
    """Encoded size in bytes of a fixed-size variable, None for strings and domains."""
    dtype = var.data_type
    st = cod.ODVariable.STRUCT_TYPES.get(dtype) if dtype is not None else None
    return st.size if st is not None else None


def in_communication_area(index: int) -> bool:
    return index in COMMUNICATION_AREA


class Dictionary:
    """Object dictionary of one node: model (canopen) + values + hooks."""

    def __init__(self, model: cod.ObjectDictionary | None = None, node_id: int = 0):
        self.model = model if model is not None else cod.ObjectDictionary()
        self.node_id = node_id
        self._values: dict[tuple[int, int], Value] = {}
        self._stored: dict[tuple[int, int], Value] = {}
        self._getters: dict[tuple[int, int], Getter] = {}
        self._setters: dict[tuple[int, int], Setter] = {}
        self._thread_safe: set[tuple[int, int]] = set()  # getters read_quick may call
        self._validators: dict[int, list[Validator]] = {}
        # index -> (length, converter): writes of that length taken in the device's own width
        self._short_writes: dict[int, tuple[int, Callable[[bytes], bytes]]] = {}
        self._listeners: dict[int, list[WriteListener]] = {}
        self._readers: dict[tuple[int, int], Reader] = {}
        self._hidden: set[int] = set()
        self.volatile: set[tuple[int, int]] = set()  # writable entries a store does not save
        self.defers = (
            False  # a reader or validator may raise Deferred (the SDO server then saves its state)
        )
        self.generation = 0  # +1 on every change of entries, bindings or values: caches compare it
        self._sources: dict[
            tuple[int, int], tuple[cod.ODVariable, Getter | None, bool]
        ] = {}  # read()'s cache
        self._sources_generation = -1
        for var in self.variables():
            self._values[(var.index, var.subindex)] = self.default(var)

    # -- building ----------------------------------------------------------------
    def add_variable(
        self,
        index: int,
        name: str,
        data_type: int,
        access: str = "rw",
        default: Value = 0,
        *,
        minimum: int | None = None,
        maximum: int | None = None,
        relative: bool = False,
        mappable: bool = False,
        max_size: int | None = None,
    ) -> cod.ODVariable:
        var = _make_var(
            name,
            index,
            0,
            data_type,
            access,
            default,
            minimum,
            maximum,
            relative,
            mappable,
            max_size,
        )
        self.model.add_object(var)
        self._values[(index, 0)] = self.default(var)
        self.generation += 1
        return var

    def add_record(
        self, index: int, name: str, members: list[tuple[Any, ...]], *, array: bool = False
    ) -> cod.ODRecord | cod.ODArray:
        """A record (or array) with sub 0 = highest sub-index and ``members``.

        Each member is ``(subindex, name, data_type, access, default[, options dict])``;
        options are ``minimum``, ``maximum``, ``relative``, ``mappable``, ``max_size``.
        """
        obj = cod.ODArray(name, index) if array else cod.ODRecord(name, index)
        highest = max((m[0] for m in members), default=0)
        sub0 = _make_var(
            "Highest sub-index supported",
            index,
            0,
            dt.UNSIGNED8,
            "ro",
            highest,
            None,
            None,
            False,
            False,
            None,
        )
        obj.add_member(sub0)
        for member in members:
            sub, mname, dtype, access, default = member[:5]
            opts = member[5] if len(member) > 5 else {}
            obj.add_member(
                _make_var(
                    mname,
                    index,
                    sub,
                    dtype,
                    access,
                    default,
                    opts.get("minimum"),
                    opts.get("maximum"),
                    opts.get("relative", False),
                    opts.get("mappable", False),
                    opts.get("max_size"),
                )
            )
        self.model.add_object(obj)
        for var in obj.subindices.values():
            self._values[(index, var.subindex)] = self.default(var)
        self.generation += 1
        return obj

    def add_array(self, index: int, name: str, members: list[tuple[Any, ...]]) -> cod.ODArray:
        array = self.add_record(index, name, members, array=True)
        assert isinstance(array, cod.ODArray)
        return array

    @property
    def hidden(self) -> frozenset[int]:
        return frozenset(self._hidden)

    def remove(self, index: int) -> None:
        if index in self.model.indices:
            obj = self.model.indices.pop(index)
            self.model.names.pop(obj.name, None)
        for key in [k for k in self._values if k[0] == index]:
            del self._values[key]
        self.generation += 1

    # -- lookup --------------------------------------------------------------------
    def __contains__(self, key: int | tuple[int, int]) -> bool:
        if (key[0] if isinstance(key, tuple) else key) in self._hidden:
            return False
        if isinstance(key, tuple):
            try:
                self.variable(*key)
                return True
            except SdoAbort:
                return False
        return key in self.model.indices

    def variable(self, index: int, subindex: int) -> cod.ODVariable:
        """The model entry; SdoAbort 0602 0000 / 0609 0011 when it does not exist."""
        obj = self.model.indices.get(index)
        if obj is None:
            raise SdoAbort(abort.NO_OBJECT, f"0x{index:04X}")
        if isinstance(obj, cod.ODVariable):
            if subindex != 0:
                raise SdoAbort(abort.NO_SUBINDEX, f"0x{index:04X}:{subindex}")
            return obj
        var: cod.ODVariable | None = obj.subindices.get(
            subindex
        )  # never ODArray.__getitem__: it invents subs
        if var is None:
            raise SdoAbort(abort.NO_SUBINDEX, f"0x{index:04X}:{subindex}")
        return var

    def variables(self) -> Iterator[cod.ODVariable]:
        for index in sorted(self.model.indices):
            obj = self.model.indices[index]
            if isinstance(obj, cod.ODVariable):
                yield obj
            else:
                for sub in sorted(obj.subindices):
                    yield obj.subindices[sub]

    def default(self, var: cod.ODVariable) -> Value:
        """The default for the current node-ID (``$NODEID+base`` for relative entries)."""
        raw = getattr(var, "default_raw", None)
        if var.relative and isinstance(raw, str) and "$NODEID" in raw:
            base = int(re.sub(r"\+?\$NODEID\+?", "", raw) or "0", 0)
            return base + (self.node_id if 1 <= self.node_id <= 127 else 0)
        return var.default if var.default is not None else _zero(var)

    # -- hooks ---------------------------------------------------------------------
    def bind(
        self,
        index: int,
        subindex: int,
        getter: Getter | None = None,
        setter: Setter | None = None,
        *,
        thread_safe: bool = False,
    ) -> None:
        """Serve (index, subindex) from ``getter`` and/or pass accepted writes to ``setter``.

        ``thread_safe``: the getter gives a consistent value when called from another
        thread while the event loop runs (it reads one attribute, or a constant), so
        :meth:`read_quick` may call it. Process-image getters are not: they may read
        several channels, or clear what they read.
        """
        self.variable(index, subindex)
        if getter is not None:
            self._getters[(index, subindex)] = getter
            if thread_safe:
                self._thread_safe.add((index, subindex))
            else:
                self._thread_safe.discard((index, subindex))
        if setter is not None:
            self._setters[(index, subindex)] = setter
        self.generation += 1

    def accept_short_writes(
        self, index: int, length: int, convert: Callable[[bytes], bytes]
    ) -> None:
        """Take downloads of ``length`` bytes to the sub-indices 1.. of ``index`` (where a
        device manual prints a narrower type than CiA 401, e.g. the ICP DAS manuals' U16
        0x6443/0x6444): ``convert`` turns them into the entry's own width (or raises
        :class:`SdoAbort`); every other length is checked as usual."""
        self._short_writes[index] = (length, convert)

    def add_reader(self, index: int, subindex: int, reader: Reader) -> None:
        """Serve SDO uploads of (index, subindex) from ``reader`` (only those: :meth:`get`, and
        so TPDOs, keep the stored value); never from the receive thread."""
        self.variable(index, subindex)
        self._readers[(index, subindex)] = reader
        self.generation += 1

    def add_validator(self, index: int, validator: Validator) -> None:
        self._validators.setdefault(index, []).append(validator)

    def on_write(self, index: int, listener: WriteListener) -> None:
        self._listeners.setdefault(index, []).append(listener)

    # -- values --------------------------------------------------------------------
    def get(self, index: int, subindex: int = 0) -> Value:
        key = (index, subindex)
        getter = self._getters.get(key)
        if getter is not None:
            return getter()
        if key not in self._values:
            self.variable(index, subindex)  # raises the right abort
        return self._values[key]

    def integer(self, index: int, subindex: int = 0) -> int:
        """:meth:`get` for an entry of an integer type (COB-IDs, times, counters), typed so."""
        value = self.get(index, subindex)
        if not isinstance(value, int):
            raise TypeError(
                f"0x{index:04X}:{subindex} holds a {type(value).__name__}, not an integer"
            )
        return value

    def set(self, index: int, subindex: int, value: Value, *, notify: bool = True) -> None:
        """Local (application-side) write: type-checked, no access/range/validator checks."""
        var = self.variable(index, subindex)
        encode(var, value)
        self._store_value(var, value, notify)

    def _source(self, key: tuple[int, int]) -> tuple[cod.ODVariable, Getter | None, bool]:
        """The entry, its getter and whether read_quick may serve it, looked up once per dictionary change."""
        if self._sources_generation != self.generation:
            self._sources.clear()
            self._sources_generation = self.generation
        source = self._sources.get(key)
        if source is None:
            if key[0] in self._hidden:
                raise SdoAbort(abort.NO_OBJECT, f"0x{key[0]:04X}")
            getter = self._getters.get(key)
            reader = self._readers.get(key)
            source = self._sources[key] = (
                self.variable(*key),
                getter if reader is None else reader,
                reader is None and (getter is None or key in self._thread_safe),
            )
        return source

    def read_quick(self, index: int, subindex: int) -> bytes | None:
        """:meth:`read` for a thread other than the event loop's: the encoded value, or None
        where it cannot answer (a getter not bound ``thread_safe``, any abort, any error)."""
        try:
            var, getter, quick = self._source((index, subindex))
            if not quick or not var.readable:
                return None
            return encode(var, getter() if getter is not None else self._values[(index, subindex)])
        except Exception:  # the event loop's read() answers it (with its abort)
            return None

    def read(self, index: int, subindex: int) -> bytes:
        """SDO upload: the encoded value, or SdoAbort."""
        key = (index, subindex)
        var, getter, _ = self._source(key)
        if not var.readable:
            raise SdoAbort(abort.WRITE_ONLY)
        try:
            return encode(var, getter() if getter is not None else self._values[key])
        except (SdoAbort, Deferred):
            raise
        except Exception as exc:  # a broken getter must not stop the node
            raise SdoAbort(abort.HARDWARE_ERROR, str(exc)) from exc

    def check_download(self, index: int, subindex: int, size: int | None = None) -> cod.ODVariable:
        """What a download initiate can check before any data arrive."""
        if index in self._hidden:
            raise SdoAbort(abort.NO_OBJECT, f"0x{index:04X}")
        var = self.variable(index, subindex)
        if not var.writable:
            raise SdoAbort(abort.READ_ONLY)
        if size is not None:
            _check_size(var, size)
        return var

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """SDO download: check everything, then take effect, then notify."""
        short = self._short_writes.get(index)
        if short is not None and subindex and len(data) == short[0]:
            self.variable(index, subindex)  # 0602 0000 / 0609 0011 before the conversion
            data = short[1](data)
        var = self.check_download(index, subindex, len(data))
        value = decode(var, data)
        check_range(var, value)
        for validator in self._validators.get(index, ()):
            validator(subindex, value)
        self._store_value(var, value, True)

    def _store_value(self, var: cod.ODVariable, value: Value, notify: bool) -> None:
        self.generation += 1  # tells caches (the node's frame routes) that something changed
        key = (var.index, var.subindex)
        setter = self._setters.get(key)
        if setter is not None:
            setter(value)
        if key not in self._getters:
            self._values[key] = value
        if notify:
            for listener in self._listeners.get(var.index, ()):
                listener(var.index, var.subindex, value)

    # -- stored values (0x1010 / 0x1011) and resets -------------------------------------
    def storable(self) -> Iterator[cod.ODVariable]:
        """Entries whose value a store (0x1010) saves: writable and not bound to a getter."""
        for var in self.variables():
            if (
                var.writable
                and (var.index, var.subindex) not in self._getters
                and (var.index, var.subindex) not in self.volatile
                and var.index not in (0x1010, 0x1011)
            ):
                yield var

    def snapshot(
        self, communication: bool = True, application: bool = True
    ) -> dict[tuple[int, int], Value]:
        return {
            (v.index, v.subindex): self._values[(v.index, v.subindex)]
            for v in self.storable()
            if (in_communication_area(v.index) and communication)
            or (not in_communication_area(v.index) and application)
        }

    @property
    def stored(self) -> dict[tuple[int, int], Value]:
        return dict(self._stored)

    def set_stored(self, values: dict[tuple[int, int], Value]) -> None:
        """Values reloaded by the next reset instead of the defaults (unknown keys dropped)."""
        self._stored = {}
        for key, value in values.items():
            try:
                var = self.variable(*key)
                encode(var, value)
            except (SdoAbort, ValueError, TypeError, struct.error, AttributeError):
                continue
            self._stored[key] = value

    def reload(self, communication: bool = True, application: bool = True) -> None:
        """Reset communication (``application=False``) or reset node: stored or default values.

        Setters see the reloaded values (they take effect); write listeners do not: a reset
        is not a write, and services learn of it from ``on_reset_communication`` /
        ``on_reset_application``.
        """
        for var in self.variables():
            if in_communication_area(var.index) and not communication:
                continue
            if not in_communication_area(var.index) and not application:
                continue
            key = (var.index, var.subindex)
            if key in self._getters:
                continue
            value = self._stored.get(key, self.default(var)) if var.writable else self.default(var)
            self._store_value(var, value, False)


# -- encoding helpers -------------------------------------------------------------------
def _zero(var: cod.ODVariable) -> Value:
    if var.data_type in (dt.REAL32, dt.REAL64):
        return 0.0
    if var.data_type == dt.VISIBLE_STRING or var.data_type == dt.UNICODE_STRING:
        return ""
    if var.data_type in (dt.OCTET_STRING, dt.DOMAIN):
        return b""
    return 0


_INTEGER_STRUCTS = {t: cod.ODVariable.STRUCT_TYPES[t] for t in dt.INTEGER_TYPES}


def encode(var: cod.ODVariable, value: Value) -> bytes:
    dtype = var.data_type
    packer = _INTEGER_STRUCTS.get(dtype) if dtype is not None else None
    if packer is not None:  # the common case, without canopen's generic encode_raw
        if not isinstance(value, int):
            raise TypeError(f"{var.qualname}: {value!r} is not an integer")
        try:
            return packer.pack(value)
        except struct.error:
            raise ValueError(f"{var.qualname}: {value!r} does not fit its type") from None
    if var.data_type == dt.VISIBLE_STRING and isinstance(value, str):
        return value.encode("latin-1")
    if var.data_type in (dt.OCTET_STRING, dt.DOMAIN) and isinstance(value, str):
        return value.encode("latin-1")
    if var.data_type in dt.INTEGER_TYPES and not isinstance(value, (int, bool)):
        raise TypeError(f"{var.qualname}: {value!r} is not an integer")
    return var.encode_raw(value)


def decode(var: cod.ODVariable, data: bytes) -> Value:
    if var.data_type == dt.VISIBLE_STRING:
        return data.decode("latin-1")
    if var.data_type in (dt.OCTET_STRING, dt.DOMAIN):
        return bytes(data)
    try:
        value = var.decode_raw(data)
    except Exception as exc:
        raise SdoAbort(abort.LENGTH_MISMATCH, str(exc)) from exc
    return bytes(value) if isinstance(value, bytearray) else value


def _check_size(var: cod.ODVariable, size: int) -> None:
    expected = size_of(var)
    if expected is None:
        limit = getattr(var, "max_size", None) or DEFAULT_MAX_SIZE
        if size > limit:
            raise SdoAbort(abort.LENGTH_TOO_HIGH)
        return
    if size > expected:
        raise SdoAbort(abort.LENGTH_TOO_HIGH)
    if size < expected:
        raise SdoAbort(abort.LENGTH_TOO_LOW)


def check_range(var: cod.ODVariable, value: Value) -> None:
    if var.data_type == dt.BOOLEAN and value not in (0, 1, True, False):
        raise SdoAbort(abort.VALUE_RANGE)
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return
    if var.min is not None and value < var.min:
        raise SdoAbort(abort.VALUE_TOO_LOW)
    if var.max is not None and value > var.max:
        raise SdoAbort(abort.VALUE_TOO_HIGH)


def _make_var(
    name: str,
    index: int,
    sub: int,
    data_type: int,
    access: str,
    default: Any,
    minimum: int | None,
    maximum: int | None,
    relative: bool,
    mappable: bool,
    max_size: int | None,
) -> cod.ODVariable:
    var = cod.ODVariable(name, index, sub)
    var.data_type = data_type
    var.access_type = access
    var.default = default
    var.min = minimum
    var.max = maximum
    var.relative = relative
    if relative:
        # as canopen's EDS import/export writes it; an attribute its ODVariable does not declare
        var.default_raw = f"$NODEID+0x{int(default):X}"  # type: ignore[attr-defined]
    var.pdo_mappable = mappable
    if max_size is not None:
        var.max_size = max_size  # type: ignore[attr-defined]  # (read by our EDS writer)
    return var
