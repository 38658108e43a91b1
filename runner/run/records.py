"""The native core's records, read by field name from the table the C code exports.

runner/run/records.h declares the slot header and the sample, lock wait, event and phase
records once, as lists of fields that give both the C structs and a table of each field's
name, offset, size and struct format (`_probe.records()`).  A `Record` is built from that
table once, at import: one `struct.Struct` for the whole record (so a record is still read
in one unpack) and each field's place in it by name.  Python never mirrors a record by
position, so a field moved or retyped in C moves here with it, and a field read under the
wrong name fails at once (KeyError) instead of reading its neighbour.
"""

from __future__ import annotations

import mmap
import operator
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Union

from runner.run import _probe

Buffer = Union[bytes, bytearray, memoryview, mmap.mmap]


@dataclass(frozen=True)
class Field:
    """One field of a native record: where it is, its struct format ("q", "4q"), where its values are in the record's unpacked tuple."""

    name: str
    offset: int
    size: int
    format: str
    index: Union[int, slice]  # an array field's values are a slice of the tuple
    struct: struct.Struct  # the field alone, to read it in place


class Record:
    """A native record: its size (reserved tail included) and fields by name, read in one unpack."""

    def __init__(self, name: str, size: int, fields: Sequence[tuple[str, int, int, str]]):
        self.name = name
        self.size = size
        parts, by_name, position, end = ["<"], {}, 0, 0
        for field, offset, nbytes, fmt in fields:
            if field in by_name or offset < end:
                raise ValueError(f"native record {name}: field {field} at {offset} repeats a name or overlaps the field before it")
            if offset > end:
                parts.append(f"{offset - end}x")  # padding the C compiler put in: skipped by name, never read
            alone = struct.Struct("<" + fmt)
            if alone.size != nbytes:
                raise ValueError(f"native record {name}: field {field} is {nbytes} bytes in C, format {fmt!r} reads {alone.size}")
            count = len(alone.unpack(bytes(nbytes)))
            index: Union[int, slice] = position if count == 1 and not fmt[0].isdigit() else slice(position, position + count)
            by_name[field] = Field(field, offset, nbytes, fmt, index, alone)
            parts.append(fmt)
            position += count
            end = offset + nbytes
        if end > size:
            raise ValueError(f"native record {name}: fields end at {end}, after its {size} bytes")
        self.fields: Mapping[str, Field] = MappingProxyType(by_name)
        self.names = tuple(by_name)
        self.struct = struct.Struct("".join(parts))  # its fields, without the reserved tail
        getter = operator.itemgetter(*(f.index for f in by_name.values()))  # each field's value(s), in one C call
        self._values: Callable[[tuple[Any, ...]], tuple[Any, ...]] = getter if len(by_name) > 1 else lambda values: (getter(values),)

    def unpack(self, buf: Buffer, at: int = 0) -> dict[str, Any]:
        """The record at `at` of `buf`, its values by field name (an array field's as a tuple)."""
        return dict(zip(self.names, self._values(self.struct.unpack_from(buf, at))))

    def get(self, buf: Buffer, at: int, name: str) -> Any:
        """One field of the record at `at`, read in place (an array's as a tuple)."""
        f = self.fields[name]
        values = f.struct.unpack_from(buf, at + f.offset)
        return values if isinstance(f.index, slice) else values[0]

    def pack(self, values: Mapping[str, Any]) -> bytes:
        """The record's bytes with these values (the others zero): for tests and fakes of the native core."""
        unknown = set(values) - set(self.fields)
        if unknown:
            raise KeyError(f"native record {self.name} has no field {sorted(unknown)}")
        out = bytearray(self.size)
        for name, value in values.items():
            f = self.fields[name]
            f.struct.pack_into(out, f.offset, *(value if isinstance(f.index, slice) else (value,)))
        return bytes(out)


def _load() -> Mapping[str, Record]:
    return MappingProxyType({name: Record(name, size, fields) for name, (size, fields) in _probe.records().items()})


RECORDS = _load()
SLOT_HEADER = RECORDS["slot_header"]
SAMPLE = RECORDS["sample"]
LOCK_WAIT = RECORDS["lock_wait"]
EVENT_STATS = RECORDS["event_stats"]
PHASE_STATS = RECORDS["phase_stats"]


def require_order(record: Record, names: Sequence[str]) -> None:
    """Raise unless `names` are the record's fields in order: for a class made from a record's values in one step
    (the ring's samples, read by the thousand), the check that its positions are the record's names."""
    if tuple(names) != record.names:
        raise ImportError(f"native record {record.name} has fields {record.names}, Python reads {tuple(names)}")
