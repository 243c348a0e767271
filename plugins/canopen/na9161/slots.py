"""The NA-9161's per-slot module objects (``na9161`` style; seed-004 §3.3, §A.6, §A.7).

One sub-index per slot (sub 0 = number of slots), slots = the front's modules in order:

| Object | Type | Access | Meaning |
|---|---|---|---|
| 0x2000 | DOMAIN | ro | read memory of slot n: its module's memory (below) |
| 0x2200 | DOMAIN | wo | write memory of slot n: its output block |
| 0x4501 | U32 | ro | range of the read memory of slot n: 20 (the module memory's length) |
| 0x4502 | DOMAIN | rw | configuration of slot n: its outputs' fault action (hold last / fault value) |
| 0x4504 | U32 | ro | catalog code of slot n |

**Slot memory (0x2000, read).** An FnIO slice's memory registers hold its parameters and
firmware data. The RS-485 module behind a slot has the like in its own memory: its address,
type code, data format, checksum setting, baud rate and the name it reports (DCON ``$AA2``,
``$AAM``). 0x2000:n returns that, as the back knows it (read from the module once it
answered, the topology's values before; ``fieldgate.module_info``), in a fixed layout of
:data:`MODULE_MEMORY_SIZE` bytes (0x4501:n), never waiting for the line:

| Offset | Size | What |
|---|---|---|
| 0 | 1 | RS-485 address |
| 1 | 1 | type code (0 where the back has none: a Modbus module) |
| 2 | 1 | data format (DCON: 0 engineering, 1 %FSR, 2 hex, 3 ohms) |
| 3 | 1 | flags: bit 0 checksum on, bit 7 read from the module (not only configured) |
| 4 | 4 | baud rate, bit/s (U32, low byte first; 0 unknown) |
| 8 | 4 | module ID: the model number as hex digits ("7017R" -> 0x00007017) |
| 12 | 8 | the name the module reports, else the model, ASCII, NUL-padded |

**Slot memory (0x2200, write).** Writing an RS-485 module's memory (its configuration)
needs its line and, for DCON, the module's INIT* pin: not something a CAN write can wait
for. 0x2200:n therefore keeps writing the slot's output block in one transfer: analog
words (INTEGER16, low byte first), then its digital outputs packed 8 per byte (channel 0 in
bit 0, the last byte padded), then its special bytes, exactly the block's length (else 0607
0012/0013), e.g. every channel of one slot in one SDO. A slot without outputs refuses
writes (0609 0030).

**Slot configuration (0x4502).** The seed's §A.7 writes ``FF 00`` to an 8-DO slot to hold
the last state on every channel; its parameter lengths (2 bytes for 2-, 4- and 8-DO
modules, 4 for 16-DO, 6 for a 2-AO) fit this layout, which fieldgate uses for the modules
it knows (outputs): digital outputs: a hold mask byte per 8 channels (bit n = channel n
holds its value on a fault), then a fault-value byte per 8 channels; analog outputs: a
hold mask byte per 8 channels, one reserved byte (0; the module's range on an FnIO AO),
then each channel's fault value (INTEGER16, low byte first). A hold bit is the inverse of
the channel's 0x6206/0x6443 error-mode bit and a fault value is its 0x6207/0x6444 error
value: [AMBIG-36] is settled by making both views of the one per-channel error mode in the
process image, so neither can contradict the other. A slot with no outputs has no
parameters fieldgate knows: reading or writing its 0x4502 aborts 0800 0024.

**Catalog codes (0x4504).** Synthetic, like the product codes of 0x4503 (no CREVIS module
stands behind a slot): wire bytes ``00 00 <size> <class>``: module ID 0 (not a CREVIS
module), the larger direction's size code of §2.5 (as 0x4503), class ``41`` inputs, ``81``
outputs, ``C1`` both, as the seed's catalog numbers end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

from fieldgate.image import Channel, ErrorMode, Kind, ProcessImage
from fieldgate.module_info import ModuleIdentity, ModuleInfo

from ..cia301.abort import LENGTH_TOO_HIGH, LENGTH_TOO_LOW, NO_DATA, VALUE_RANGE
from ..cia301.entries import DOMAIN, UNSIGNED32, Abort, Entry, ObjectDef, Value, array
from ..cia401.layouts import ModuleRef
from ..cia401.values import from_int16, to_int16

READ_MEMORY, WRITE_MEMORY = 0x2000, 0x2200
READ_RANGE, SLOT_CONFIGURATION, CATALOG_CODES = 0x4501, 0x4502, 0x4504
MAX_BLOCK = 256  # bytes a slot block may have (a 64-byte image per direction fits)
MODULE_MEMORY_SIZE = 20  # 0x2000:n, the module memory's fixed layout (module notes)
READ_FROM_MODULE, CHECKSUM_ON = 0x80, 0x01


def _pack_bits(values: Sequence[bool]) -> bytes:
    out = bytearray((len(values) + 7) // 8)
    for n, v in enumerate(values):
        if v:
            out[n // 8] |= 1 << (n % 8)
    return bytes(out)


def _bits(data: bytes, count: int) -> list[bool]:
    return [bool(data[n // 8] >> (n % 8) & 1) for n in range(count)]


class Slot:
    """One slot's channels by kind, in channel order."""

    def __init__(self, module: ModuleRef, channels: Sequence[Channel]):
        self.module = module
        self.of: dict[Kind, list[Channel]] = {k: [] for k in Kind}
        for ch in channels:
            self.of[ch.kind].append(ch)

    def block_size(self, analog: Kind, digital: Kind, special: Kind) -> int:
        return 2 * len(self.of[analog]) + (len(self.of[digital]) + 7) // 8 + len(self.of[special])

    @property
    def parameter_size(self) -> int:
        do, ao = len(self.of[Kind.DO]), len(self.of[Kind.AO])
        digital = 2 * ((do + 7) // 8)
        analog = ((ao + 7) // 8 + 1 + 2 * ao) if ao else 0
        return digital + analog


class SlotObjects:
    """0x2000, 0x2200, 0x4501, 0x4502 and 0x4504 of the front's slots (``origin`` labels writes)."""

    def __init__(
        self,
        image: ProcessImage,
        modules: Sequence[ModuleRef],
        channels: Sequence[Channel],
        origin: str,
        module_info: ModuleInfo | None = None,
    ):
        self.image = image
        self.origin = origin
        self.module_info = module_info or ModuleInfo()
        by_module: dict[tuple[str, int], list[Channel]] = {}
        for ch in channels:
            by_module.setdefault((ch.source.back, ch.source.module), []).append(ch)
        self.slots = [Slot(m, by_module.get((m.back, m.address), [])) for m in modules]

    # -- memory ------------------------------------------------------------------------------
    def read_memory(self, slot: Slot) -> bytes:
        """The slot's module memory (module notes), as the back knows the module now."""
        module = slot.module
        identity = self.module_info.identity(module.back, module.address)
        if identity is None:  # a back without module identities: the topology's model
            identity = ModuleIdentity(module.model)
        flags = (CHECKSUM_ON if identity.checksum else 0) | (
            READ_FROM_MODULE if identity.reported else 0
        )
        name = (identity.reported or identity.model).encode("ascii", "replace")[:8]
        return (
            bytes(
                [
                    module.address & 0xFF,
                    (identity.type_code or 0) & 0xFF,
                    (identity.data_format or 0) & 0xFF,
                    flags,
                ]
            )
            + (identity.baudrate or 0).to_bytes(4, "little")
            + (identity.module_id & 0xFFFFFFFF).to_bytes(4, "little")
            + name.ljust(8, b"\0")
        )

    def write_memory(self, slot: Slot, data: Value) -> None:
        if not isinstance(data, bytes):
            raise Abort(VALUE_RANGE, "a block of bytes")
        size = slot.block_size(Kind.AO, Kind.DO, Kind.SO)
        if not size:
            raise Abort(VALUE_RANGE, f"slot {slot.module.address} has no outputs")
        _check_length(data, size)
        values: list[tuple[str, bool | int | float]] = []
        offset = 0
        for ch in slot.of[Kind.AO]:
            raw = int.from_bytes(data[offset : offset + 2], "little", signed=True)
            values.append((ch.id, from_int16(ch, raw)))
            offset += 2
        dos = slot.of[Kind.DO]
        count = (len(dos) + 7) // 8
        values += [
            (ch.id, v)
            for ch, v in zip(dos, _bits(data[offset : offset + count], len(dos)), strict=True)
        ]
        offset += count
        values += [(ch.id, data[offset + n]) for n, ch in enumerate(slot.of[Kind.SO])]
        for cid, value in values:
            self.image.write_output(cid, value, self.origin)

    # -- configuration (fault action of the slot's outputs) -----------------------------------
    def read_configuration(self, slot: Slot) -> bytes:
        if not slot.parameter_size:
            raise Abort(NO_DATA, "this slot has no parameters (no outputs)")
        out = b""
        dos = slot.of[Kind.DO]
        if dos:
            out += _pack_bits([not ch.error_mode.use_value for ch in dos])
            out += _pack_bits([bool(ch.error_mode.value) for ch in dos])
        aos = slot.of[Kind.AO]
        if aos:
            out += _pack_bits([not ch.error_mode.use_value for ch in aos]) + b"\x00"
            out += b"".join(
                to_int16(ch, ch.error_mode.value).to_bytes(2, "little", signed=True) for ch in aos
            )
        return out

    def write_configuration(self, slot: Slot, data: Value) -> None:
        if not slot.parameter_size:
            raise Abort(NO_DATA, "this slot has no parameters (no outputs)")
        if not isinstance(data, bytes):
            raise Abort(VALUE_RANGE, "a block of bytes")
        _check_length(data, slot.parameter_size)
        modes: list[tuple[Channel, ErrorMode]] = []
        dos, aos = slot.of[Kind.DO], slot.of[Kind.AO]
        count = (len(dos) + 7) // 8
        if dos:
            holds = _bits(data[:count], len(dos))
            values = _bits(data[count : 2 * count], len(dos))
            modes += [
                (ch, ErrorMode(not h, v)) for ch, h, v in zip(dos, holds, values, strict=True)
            ]
        offset = 2 * count
        if aos:
            mask = (len(aos) + 7) // 8
            holds = _bits(data[offset : offset + mask], len(aos))
            offset += mask + 1  # the reserved byte
            for n, (ch, hold) in enumerate(zip(aos, holds, strict=True)):
                raw = int.from_bytes(
                    data[offset + 2 * n : offset + 2 * n + 2], "little", signed=True
                )
                modes.append((ch, ErrorMode(not hold, from_int16(ch, raw))))
        for ch, mode in modes:  # checked above: all or nothing
            try:
                self.image.set_error_mode(ch.id, mode)
            except ValueError as exc:
                raise Abort(VALUE_RANGE, str(exc)) from None

    # -- objects --------------------------------------------------------------------------------
    def objects(self) -> list[ObjectDef]:
        if not self.slots:
            return []

        def per_slot(
            index: int,
            name: str,
            dtype: int,
            access: str,
            get: Callable[[Slot], Value],
            put: Callable[[Slot, Value], None] | None = None,
            default: Callable[[Slot], Value] | None = None,
        ) -> ObjectDef:
            return array(
                index,
                name,
                (
                    Entry(
                        n,
                        f"{name} {n}",
                        dtype,
                        access,
                        partial(get, slot),
                        partial(put, slot) if put else None,
                        default=default(slot) if default else b"",  # a block: no EDS default
                    )
                    for n, slot in enumerate(self.slots, 1)
                ),
            )

        return [
            per_slot(READ_MEMORY, "Read memory slot", DOMAIN, "ro", self.read_memory),
            per_slot(
                WRITE_MEMORY, "Write memory slot", DOMAIN, "wo", lambda s: b"", self.write_memory
            ),
            per_slot(
                READ_RANGE,
                "Range of read memory slot",
                UNSIGNED32,
                "ro",
                lambda s: MODULE_MEMORY_SIZE,
                default=lambda s: MODULE_MEMORY_SIZE,
            ),
            per_slot(
                SLOT_CONFIGURATION,
                "Configuration of slot",
                DOMAIN,
                "rw",
                self.read_configuration,
                self.write_configuration,
            ),
            per_slot(
                CATALOG_CODES,
                "Slot catalog code",
                UNSIGNED32,
                "ro",
                lambda s: catalog_code(s.module),
                default=lambda s: catalog_code(s.module),
            ),
        ]


def _check_length(data: bytes, size: int) -> None:
    if len(data) > size:
        raise Abort(LENGTH_TOO_HIGH, f"{len(data)} bytes, the block has {size}")
    if len(data) < size:
        raise Abort(LENGTH_TOO_LOW, f"{len(data)} bytes, the block has {size}")


def _catalog_size(bits: int, words: int, raw_bytes: int) -> int:
    """Byte 2 of the seed's catalog numbers: 00 up to 8 digital points, 01 for 16 (ST-121F
    ``00 13 01 41``), 40|n-1 for n words (ST-3114 ``43``), n-1 for n special bytes."""
    if words:
        return 0x40 | (words - 1)
    if bits:
        return (bits + 7) // 8 - 1
    return max(raw_bytes - 1, 0)


def catalog_code(m: ModuleRef) -> int:
    """0x4504: wire bytes 00 00 <size> <class> (see the module notes)."""
    has_in, has_out = bool(m.di or m.ai or m.si), bool(m.do or m.ao or m.so)
    klass = (0x40 if has_in else 0) | (0x80 if has_out else 0) | (0x01 if has_in or has_out else 0)
    size = max(_catalog_size(m.di, m.ai, m.si), _catalog_size(m.do, m.ao, m.so))
    return int.from_bytes(bytes([0x00, 0x00, size & 0xFF, klass]), "little")
