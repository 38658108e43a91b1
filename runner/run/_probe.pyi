"""Type stub of the native core (runner/run/_probe.c): what Python may call, with the types the C code parses."""

from __future__ import annotations

import mmap
from collections.abc import Sequence
from typing import Optional, Union

FILE_HEADER: int
ROSCB_MAGIC: int
ROSCB_VERSION: int
ROSCB_PROC_BYTES: int
ROSCB_STRING_MAX: int
ROSCB_STACK: int
SLOT_GATE_AT: int
STAGE_CWD: int
STAGE_EXEC: int
SLOT_HEADER: int
SAMPLE_SIZE: int
LOCK_WAIT_SIZE: int
MAX_LOCK_SLOTS: int
WORK_SLEEP: int
WORK_PERIODIC: int
WORK_SPIN: int
HIST_BUCKETS: int
HIST_SUB_BITS: int
HIST_SETS: int
RING_NONE: int
RING_ALL: int
RING_OUTLIERS: int

WORK_PROGRAM: int
MAX_PHASES: int
MAX_EVENTS: int
EV_HDR: int
PHASE_BYTES: int
RES_BYTES: int
QDEPTH: int
EV_RUN: int
EV_RUNTIME: int
EV_SLEEP: int
EV_TIMER: int
EV_LOCK: int
EV_UNLOCK: int
EV_WAIT: int
EV_SIGNAL: int
EV_BROADCAST: int
EV_BARRIER: int
EV_SUSPEND: int
EV_RESUME: int
EV_YIELD: int
EV_MEM: int
EV_ALLOC: int
EV_SPAWN: int
EV_IORUN: int
EV_COUNT: int  # one past the last event code (codes run from 1)
EVENT_KINDS: dict[str, int]  # every event kind of records.h by name (RUN, TIMER, ...): its code
RES_MUTEX: int
RES_COND: int
RES_BARRIER: int
RES_QUEUE: int
RES_TIMER: int
QUEUE_KEEP: int
QUEUE_DROP: int
OVR_SKIP: int
OVR_REBASE: int
OVR_CATCHUP: int

# (dl_runtime_ns, dl_deadline_ns, dl_period_ns, util_min, util_max); -1: a uclamp left as is
Extra = tuple[int, int, int, int, int]
# settings applied on entering a phase: (policy, priority, nice, cpus, extra)
PhaseSettings = tuple[Optional[int], Optional[int], Optional[int], Optional[Sequence[int]], Optional[Extra]]
# (gid, delay_ns, loop, mem_bytes, phases: (loop, first, nevents, settings), events: (type, res, res2, mode, arg))
Program = tuple[int, int, int, int, tuple[tuple[int, int, int, Optional[PhaseSettings]], ...], tuple[tuple[int, int, int, int, int], ...]]
# (kind, period_ns, burn_ns, burn_wall, alloc_bytes, offset_ns, wait_spin, bound_ns, ring_mode[, program])
WorkTuple = Union[tuple[int, int, int, bool, int, int, bool, int, int], tuple[int, int, int, bool, int, int, bool, int, int, Program]]

class Group:
    """A worker's threads around one shared sample buffer and one start gate."""

    def __init__(
        self,
        buffer: mmap.mmap,
        nthreads: int,
        capacity: int,
        all_cpus: Sequence[int],
        histograms: bool = True,
        events: int = 0,
        phases: int = 0,
        resources: Optional[mmap.mmap] = None,
        locks: int = 0,
    ) -> None: ...
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
        extra: Optional[Extra] = None,
        deferred: bool = False,
        after: int = -1,
    ) -> None: ...
    def adopt(self, index: int, name: str, work: WorkTuple) -> None: ...
    def wait_ready(self, timeout: float) -> bool: ...
    def release(self, start_ns: int, end_ns: int) -> bool: ...
    def run_main(self, index: int) -> bool: ...
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

def apply(
    policy: Optional[int], priority: Optional[int], nice: Optional[int], cpus: Optional[Sequence[int]], extra: Optional[Extra] = None
) -> tuple[int, int, int]: ...
def buckets(
    buffer: bytes | mmap.mmap | memoryview, offset: int, negated: bool = False, first: int = 0, last: int = ...
) -> list[tuple[int, int, int]]: ...
def init_resources(buffer: mmap.mmap, specs: Sequence[tuple[int, int, int, int]]) -> None: ...
def records() -> dict[str, tuple[int, tuple[tuple[str, int, int, str], ...]]]:
    """{record: (size, ((field, offset, size, struct format), ...))}: the shared buffer's records as records.h declares them."""

def sched_getattr(tid: int) -> tuple[int, int, int, int, int, int, int, int, int]: ...
def set_name(name: str) -> None: ...
def lock_memory() -> None: ...
def preallocate(bytes: int) -> None: ...
def set_default_stacksize(bytes: int) -> None: ...
def install_stop_handler() -> None: ...
def set_pdeathsig(sig: int) -> None: ...
def stopped() -> bool: ...
def open_gate(header: mmap.mmap, start_ns: int, end_ns: int) -> bool: ...
def cancel_gate(header: mmap.mmap) -> bool: ...
def apply_to(
    tid: int,
    policy: Optional[int],
    priority: Optional[int],
    nice: Optional[int],
    cpus: Optional[Sequence[int]],
    extra: Optional[Extra] = None,
) -> tuple[int, int, int]: ...

SettingsTuple = tuple[Optional[int], Optional[int], Optional[int], Optional[Sequence[int]], Optional[Extra]]

def spawn_program(
    path: bytes,
    argv: Sequence[bytes],
    envp: Sequence[bytes],
    cwd: Optional[bytes],
    settings: SettingsTuple,
    reset_on_fork: bool,
    out_fd: int,
    err_fd: int,
) -> tuple[int, int, int]: ...
