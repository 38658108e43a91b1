"""Type stub of the native trace reader (runner/run/_trace.c): what Python may call, with the types the C code parses."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Optional

from typing_extensions import Buffer

# (kind, field names) in the order Reader takes its layouts
FIELDS: tuple[tuple[str, tuple[str, ...]], ...]
BUCKETS: int
MAX_PREEMPTORS: int
MAX_WORST: int
MAX_HELD: int
THREAD_BYTES: int
HIST_BYTES: int
HELD_BYTES: int
FK_UINT: int
FK_INT: int
FK_CHARS: int
FK_DATA_LOC: int
TYPE_PADDING: int
TYPE_TIME_EXTEND: int
TYPE_TIME_STAMP: int

def hist_add(counts: Buffer, i: int) -> None: ...  # HIST_BUCKETS uint32 counters, writable (an array("I"))

# (event id, ((offset, size, kind), ...)) per kind of FIELDS; None: the kernel lacks the event
Layout = Optional[tuple[int, Sequence[tuple[int, int, int]]]]

class Reader:
    def __init__(
        self,
        page_size: int,
        header: tuple[int, int, int, int],  # timestamp offset, commit offset, commit size, data offset
        common_type: tuple[int, int],  # offset, size
        layouts: Sequence[Layout],
        state_mask: int,
        max_threads: int = 8192,
        hold_ns: int = 10_000_000,
    ) -> None: ...
    def track(self, tids: Sequence[int]) -> None: ...
    def window(self, start_ns: int, end_ns: int) -> None: ...
    def feed(self, cpu: int, pages: bytes) -> None: ...
    def start(self, files: Sequence[tuple[int, str]], interval_ns: int) -> None: ...
    def stop(self) -> None: ...
    def result(self) -> dict[str, Any]: ...
