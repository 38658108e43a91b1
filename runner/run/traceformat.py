"""The formats tracefs describes its events in, parsed into what the native trace reader needs.

tracefs says how its binary records are laid out: `events/header_page` gives the
ring-buffer page header (timestamp, commit word, data), and each
`events/<system>/<event>/format` the id and the fields of one event with their
offsets and sizes.  Those differ between kernels (sched_migrate_task's comm became a
`__data_loc` string, prev_state grew from int to long), so nothing is hard-coded:
the reader (runner/run/_trace.c) gets offsets, sizes and kinds from here.

Pure: no I/O; the text comes from the caller (tests hold copies of real files).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Optional

# The event that serves each kind the reader knows, in order of preference
# (sched_waking, from 4.3, is traced when a wake-up starts; sched_wakeup only when it ends).
KIND_EVENTS: dict[str, tuple[str, ...]] = {
    "switch": ("sched_switch",),
    "waking": ("sched_waking", "sched_wakeup"),
    "wakeup_new": ("sched_wakeup_new",),
    "migrate": ("sched_migrate_task",),
    "fork": ("sched_process_fork",),
    "exec": ("sched_process_exec",),
    "exit": ("sched_process_exit",),
}
REQUIRED_KINDS = ("switch", "waking")

# how the reader reads a field (the FK_* constants of _trace.c)
FK_UINT, FK_INT, FK_CHARS, FK_DATA_LOC = 0, 1, 2, 3

# TASK_REPORT_MAX - 1 of kernels since 4.14 (prev_state below it is the task's state;
# TASK_REPORT_MAX itself marks a preemption, "R+"): used when the print fmt cannot be read.
DEFAULT_STATE_MASK = 0xFF

FieldSpec = tuple[int, int, int]  # (offset, size, kind) of one field
Layout = Optional[tuple[int, tuple[FieldSpec, ...]]]  # (event id, fields) of one kind; None when the kernel lacks it


class FormatError(ValueError):
    """A format file the reader cannot use; the message names the file and what is missing."""


@dataclass(frozen=True)
class Field:
    """One `field:` line: its C declaration, offset and size in bytes, signedness."""

    decl: str
    name: str
    offset: int
    size: int
    signed: bool

    @property
    def is_data_loc(self) -> bool:
        """A `__data_loc` string: a u32 holding the string's offset (low 16 bits) and length in the record."""
        return self.decl.startswith("__data_loc")

    @property
    def is_char_array(self) -> bool:
        return not self.is_data_loc and "[" in self.decl and re.match(r"(unsigned\s+|signed\s+)?char\b", self.decl) is not None


@dataclass(frozen=True)
class EventFormat:
    """An event's `format` file: its name, id, fields by name and print format."""

    name: str
    id: int
    fields: Mapping[str, Field]
    print_fmt: str


@dataclass(frozen=True)
class PageHeader:
    """`events/header_page`: where a ring-buffer page keeps its timestamp, commit word and data."""

    timestamp_offset: int
    commit_offset: int
    commit_size: int
    data_offset: int
    data_size: int

    @property
    def page_size(self) -> int:
        """Bytes of one page as trace_pipe_raw returns it (the sub-buffer size)."""
        return self.data_offset + self.data_size


_FIELD = re.compile(r"^\s*field:\s*(?P<decl>[^;]*);\s*offset:(?P<off>\d+);\s*size:(?P<size>\d+);\s*signed:(?P<signed>-?\d+);", re.M)
_NAME = re.compile(r"(\w+)\s*(\[[^\]]*\])?\s*$")


def _fields(text: str, source: str) -> dict[str, Field]:
    fields: dict[str, Field] = {}
    for m in _FIELD.finditer(text):
        decl = m["decl"].strip()
        name = _NAME.search(decl)
        if name is None:
            raise FormatError(f"{source}: cannot read the field name in {decl!r}")
        # header_page declares two fields at the commit word's offset (commit, overwrite): keep the first
        fields.setdefault(name[1], Field(decl, name[1], int(m["off"]), int(m["size"]), m["signed"] not in ("0", "")))
    return fields


def parse_format(text: str, source: str = "format") -> EventFormat:
    """An event's format file; FormatError when it has no name, id or fields."""
    name = re.search(r"^name:\s*(\S+)", text, re.M)
    ident = re.search(r"^ID:\s*(\d+)", text, re.M)
    fmt = re.search(r"^print fmt:\s*(.*)$", text, re.M)
    fields = _fields(text, source)
    if name is None or ident is None or not fields:
        missing = [what for what, found in (("name", name), ("ID", ident), ("fields", fields)) if not found]
        raise FormatError(f"{source}: not an event format (no {', '.join(missing)})")
    return EventFormat(name[1], int(ident[1]), fields, fmt[1] if fmt else "")


def parse_header_page(text: str, source: str = "header_page") -> PageHeader:
    """`events/header_page`; FormatError unless it has timestamp, commit and data where the reader can use them."""
    fields = _fields(text, source)
    missing = [n for n in ("timestamp", "commit", "data") if n not in fields]
    if missing:
        raise FormatError(f"{source}: no {', '.join(missing)} field; a ring-buffer page header has timestamp, commit and data")
    ts, commit, data = fields["timestamp"], fields["commit"], fields["data"]
    if ts.size != 8 or commit.size not in (4, 8) or data.offset < max(ts.offset + 8, commit.offset + commit.size) or data.size <= 0:
        raise FormatError(
            f"{source}: unusable page header (timestamp {ts.size} bytes at {ts.offset}, commit {commit.size} at {commit.offset}, "
            f"data {data.size} at {data.offset}); expected an 8-byte timestamp, a 4- or 8-byte commit, then the data"
        )
    return PageHeader(ts.offset, commit.offset, commit.size, data.offset, data.size)


def switch_state_mask(print_fmt: str) -> int:
    """The bits of sched_switch's prev_state that are a task state (none set: runnable, "R" or "R+").

    Read from the print format, as the kernel prints the state: `prev_state &
    ((((STATES) + 1) << 1) - 1)` since 4.14 (TASK_REPORT_MAX - 1), `prev_state &
    (N-1)` before.  DEFAULT_STATE_MASK when neither form is there.
    """
    m = re.search(r"REC->prev_state & \(\(\(\(([^()]*)\) \+ 1\) << 1\) - 1\)", print_fmt)
    if m:
        value = 0
        for part in m[1].split("|"):
            value |= int(part.strip(), 0)
        return ((value + 1) << 1) - 1
    m = re.search(r"REC->prev_state & \((\d+) ?- ?1\)", print_fmt)
    if m:
        return int(m[1]) - 1
    return DEFAULT_STATE_MASK


def field_spec(event: EventFormat, name: str, string: bool) -> FieldSpec:
    """(offset, size, kind) of one field the reader needs; FormatError when absent or of a form it cannot read."""
    f = event.fields.get(name)
    if f is None:
        raise FormatError(f"{event.name}: no field {name!r} (fields: {', '.join(event.fields)})")
    if string:
        if f.is_data_loc and f.size == 4:
            return (f.offset, f.size, FK_DATA_LOC)
        if f.is_char_array:
            return (f.offset, f.size, FK_CHARS)
        raise FormatError(f"{event.name}.{name}: {f.decl!r} is not a char array or __data_loc string")
    if f.size not in (1, 2, 4, 8) or "[" in f.decl or f.is_data_loc:
        raise FormatError(f"{event.name}.{name}: {f.decl!r} ({f.size} bytes) is not an integer of 1, 2, 4 or 8 bytes")
    return (f.offset, f.size, FK_INT if f.signed else FK_UINT)


def common_type(event: EventFormat) -> tuple[int, int]:
    """(offset, size) of common_type, the event id every record starts with."""
    offset, size, _ = field_spec(event, "common_type", string=False)
    return offset, size


def layouts(formats: Mapping[str, Optional[EventFormat]], fields: Sequence[tuple[str, Sequence[str]]]) -> tuple[Layout, ...]:
    """The reader's layouts, in the order of its FIELDS (`(kind, field names)` pairs); a kind without a format is None."""
    out: list[Layout] = []
    for kind, names in fields:
        event = formats.get(kind)
        if event is None:
            if kind in REQUIRED_KINDS:
                raise FormatError(f"no {' or '.join(KIND_EVENTS[kind])} event: the reader needs it")
            out.append(None)
            continue
        out.append((event.id, tuple(field_spec(event, n, string=n.endswith("comm")) for n in names)))
    return tuple(out)
