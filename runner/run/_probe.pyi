"""Type stub of the native core (runner/run/_probe.c): what Python may call, with the types the C code parses."""

from __future__ import annotations

import mmap
from collections.abc import Sequence
from typing import Optional

FILE_HEADER: int
SLOT_HEADER: int
SAMPLE_SIZE: int
WORK_SLEEP: int
WORK_PERIODIC: int
WORK_SPIN: int
HIST_BUCKETS: int
HIST_SUB_BITS: int
HIST_SETS: int
RING_NONE: int
RING_ALL: int
RING_OUTLIERS: int

# (kind, period_ns, burn_ns, burn_wall, alloc_bytes, offset_ns, wait_spin, bound_ns, ring_mode)
WorkTuple = tuple[int, int, int, bool, int, int, bool, int, int]

class Group:
    """A worker's threads around one shared sample buffer and one start gate."""

    def __init__(self, buffer: mmap.mmap, nthreads: int, capacity: int, all_cpus: Sequence[int], histograms: bool = True) -> None: ...
    def spawn(
        self,
        index: int,
        name: str,
        work: WorkTuple,
        policy: Optional[int],
        priority: Optional[int],
        nice: Optional[int],
        cpus: Optional[Sequence[int]],
        explicit_defaults: bool,
    ) -> None: ...
    def adopt(self, index: int, name: str, work: WorkTuple) -> None: ...
    def wait_ready(self, timeout: float) -> bool: ...
    def release(self, start_ns: int, end_ns: int) -> None: ...
    def run_main(self, index: int) -> None: ...
    def join(self) -> None: ...
    def errors(self, index: int) -> tuple[int, int, int, int, int]:
        """(tid, err_sched, err_nice, err_cpus, err_other) of one slot."""

class Watchdog:
    """An RT thread of the runner that SIGKILLs process groups at a deadline, without the GIL."""

    fired: bool
    rt_priority: int
    def __init__(self, rt_priority: int = ...) -> None: ...
    def arm(self, deadline_ns: int, pids: Sequence[int]) -> None: ...
    def disarm(self) -> None: ...
    def close(self) -> None: ...

def apply(policy: Optional[int], priority: Optional[int], nice: Optional[int], cpus: Optional[Sequence[int]]) -> tuple[int, int, int]: ...
def set_name(name: str) -> None: ...
def lock_memory() -> None: ...
def preallocate(bytes: int) -> None: ...
def set_default_stacksize(bytes: int) -> None: ...
def install_stop_handler() -> None: ...
def set_pdeathsig(sig: int) -> None: ...
def stopped() -> bool: ...
