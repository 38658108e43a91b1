"""Ring-buffer pages as trace_pipe_raw returns them, built in Python for the trace reader's tests.

The layouts come from real format files of a 6.18 kernel (tests/tracefs), parsed
by runner/run/traceformat.py, so a synthetic page is what that kernel would write.
Events are given with absolute timestamps; the builder writes the deltas, a
TIME_EXTEND where a delta does not fit 27 bits, and starts a new page when one is full.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Optional, Union

from runner.run import _trace, traceformat
from runner.run.traceformat import EventFormat, PageHeader

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "tracefs")  # real files of a 6.18 kernel
TYPE_PADDING, TYPE_TIME_EXTEND, TYPE_TIME_STAMP = 29, 30, 31
MISSED_EVENTS, MISSED_STORED = 1 << 31, 1 << 30
R, R_PLUS, S, D, X = 0, 0x100, 0x1, 0x2, 0x10  # prev_state values as 6.18 reports them

KINDS = {"switch": "sched_switch", "waking": "sched_waking", "wakeup_new": "sched_wakeup_new", "migrate": "sched_migrate_task"}
KINDS |= {"fork": "sched_process_fork", "exec": "sched_process_exec", "exit": "sched_process_exit"}


def read(name: str) -> str:
    with open(os.path.join(DATA, name)) as handle:
        return handle.read()


HEADER = traceformat.parse_header_page(read("header_page"))
FORMATS: dict[str, Optional[EventFormat]] = {kind: traceformat.parse_format(read(f"{name}.format")) for kind, name in KINDS.items()}


def reader(max_threads: int = 8192, formats: Optional[dict[str, Optional[EventFormat]]] = None, header: PageHeader = HEADER) -> Any:
    """A native Reader with the 6.18 layouts, fed by tests instead of tracefs."""
    fmts = FORMATS if formats is None else formats
    switch = fmts["switch"]
    assert switch is not None
    return _trace.Reader(
        header.page_size,
        (header.timestamp_offset, header.commit_offset, header.commit_size, header.data_offset),
        traceformat.common_type(switch),
        traceformat.layouts(fmts, _trace.FIELDS),
        traceformat.switch_state_mask(switch.print_fmt),
        max_threads,
    )


def record(event: EventFormat, **values: Union[int, str]) -> bytes:
    """One event's record: fields packed at their offsets, __data_loc strings after the fixed part."""
    fixed = max(f.offset + f.size for f in event.fields.values())
    out = bytearray(fixed)
    tail = bytearray()
    values = {"common_type": event.id, **values}
    for name, value in values.items():
        f = event.fields[name]
        if f.is_data_loc:
            raw = str(value).encode() + b"\0"
            struct.pack_into("<I", out, f.offset, (len(raw) << 16) | (fixed + len(tail)))
            tail += raw
        elif f.is_char_array:
            raw = str(value).encode()[: f.size - 1]
            out[f.offset : f.offset + len(raw)] = raw
        else:
            code = {1: "b", 2: "h", 4: "i", 8: "q"}[f.size]
            struct.pack_into("<" + (code if f.signed else code.upper()), out, f.offset, int(value))
    return bytes(out + tail)


Task = tuple[int, str, int]  # (tid, comm, prio)
IDLE0: Task = (0, "swapper/0", 120)


def switch(prev: Task, nxt: Task, state: int) -> bytes:
    fmt = FORMATS["switch"]
    assert fmt is not None
    return record(
        fmt, prev_pid=prev[0], prev_comm=prev[1], prev_prio=prev[2], prev_state=state, next_pid=nxt[0], next_comm=nxt[1], next_prio=nxt[2]
    )


def waking(task: Task, target_cpu: int = 0, kind: str = "waking") -> bytes:
    fmt = FORMATS[kind]
    assert fmt is not None
    return record(fmt, pid=task[0], comm=task[1], prio=task[2], target_cpu=target_cpu)


def migrate(task: Task, orig: int, dest: int) -> bytes:
    fmt = FORMATS["migrate"]
    assert fmt is not None
    return record(fmt, pid=task[0], comm=task[1], prio=task[2], orig_cpu=orig, dest_cpu=dest)


def fork(parent: Task, child: Task) -> bytes:
    fmt = FORMATS["fork"]
    assert fmt is not None
    return record(fmt, parent_pid=parent[0], parent_comm=parent[1], child_pid=child[0], child_comm=child[1])


def exit_(task: Task) -> bytes:
    fmt = FORMATS["exit"]
    assert fmt is not None
    return record(fmt, pid=task[0], comm=task[1], prio=task[2], group_dead=0)


@dataclass(frozen=True)
class Raw:
    """Bytes put on the page as they are (a padding event, a time stamp, anything a test wants)."""

    data: bytes


def header_word(type_len: int, delta: int) -> bytes:
    return struct.pack("<I", (delta << 5) | type_len)


def data_event(delta: int, payload: bytes, long: bool = False) -> bytes:
    """A data event: type_len = length / 4 for up to 112 bytes (as the kernel writes them), else (or `long`) length in array[0]."""
    padded = payload + b"\0" * (-len(payload) % 4)
    if not long and len(padded) <= 28 * 4:
        return header_word(len(padded) // 4, delta) + padded
    return header_word(0, delta) + struct.pack("<I", len(padded) + 4) + padded


def time_extend(delta: int) -> bytes:
    return header_word(TYPE_TIME_EXTEND, delta & ((1 << 27) - 1)) + struct.pack("<I", delta >> 27)


def time_stamp(ts: int) -> bytes:
    return header_word(TYPE_TIME_STAMP, ts & ((1 << 27) - 1)) + struct.pack("<I", (ts >> 27) & 0xFFFFFFFF)


def padding(length: int, delta: int = 1) -> bytes:
    """A discarded event of `length` bytes after its 8-byte head (delta 0 would mean: the rest of the page)."""
    return header_word(TYPE_PADDING, delta) + struct.pack("<I", length + 4) + b"\xee" * length


def page(ts: int, body: bytes, missed: Optional[int] = None, header: PageHeader = HEADER, stored: bool = True) -> bytes:
    """A page with timestamp `ts` and `body` as its data; `missed`: events lost before it (flags, and the count when `stored`)."""
    commit = len(body)
    tail = b""
    if missed is not None:
        commit |= MISSED_EVENTS
        if stored:
            commit |= MISSED_STORED
            tail = struct.pack("<Q" if header.commit_size == 8 else "<I", missed)
    out = bytearray(header.page_size)
    struct.pack_into("<Q", out, header.timestamp_offset, ts)
    struct.pack_into("<Q" if header.commit_size == 8 else "<I", out, header.commit_offset, commit)
    data = body + tail
    assert len(data) <= header.data_size, "the body does not fit one page"
    out[header.data_offset : header.data_offset + len(data)] = data
    return bytes(out)


def pages(events: Iterable[tuple[int, Union[bytes, Raw]]], header: PageHeader = HEADER, long: bool = False) -> bytes:
    """Pages holding `events` ((absolute ts, record) in time order): deltas, TIME_EXTENDs, a new page when one is full.

    A Raw item goes on the page as it is; the next event's delta still counts from the event before it.
    """
    out: list[bytes] = []
    body = b""
    page_ts = last = None
    for ts, item in events:
        if page_ts is None:
            page_ts = last = ts
        assert last is not None and ts >= last, "events in time order"
        if isinstance(item, Raw):
            chunk = item.data
        else:
            delta = ts - last
            chunk = b""
            if delta >= 1 << 27:
                chunk, delta = time_extend(delta), 0
            chunk += data_event(delta, item, long)
        if len(body) + len(chunk) > header.data_size:
            out.append(page(page_ts, body, header=header))
            body, page_ts = b"", ts
            chunk = chunk if isinstance(item, Raw) else data_event(0, item, long)
        body += chunk
        if not isinstance(item, Raw):
            last = ts
    if page_ts is not None:
        out.append(page(page_ts, body, header=header))
    return b"".join(out)


def feed(r: Any, cpu: int, events: Sequence[tuple[int, Union[bytes, Raw]]], long: bool = False) -> None:
    r.feed(cpu, pages(events, long=long))


def rest_of_page() -> bytes:
    """Padding with delta 0: nothing after it on this page is an event."""
    return header_word(TYPE_PADDING, 0)
