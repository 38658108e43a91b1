"""The common start of a cell: the workers' start gates, then the hogs' load spread one per CPU, and how late either was.

Every measured thread waits at a gate in its worker's shared buffer, at its own policy, and
one futex wake per worker releases them all at the common start `t0` (`start_margin` says
how far ahead of it the gates open).  The hogs are woken after the measured threads passed
their gates, one per CPU, so the load is spread from its first millisecond.  What the slots
recorded says afterwards how late a worker's last thread or a CPU's load was.
"""

from __future__ import annotations

import os
import time
from contextlib import suppress
from typing import Optional

from runner.run import samples
from runner.run.workers import Worker, exit_code

GATE_POLL_S = 0.0001
LOAD_LEAD_S = 0.001  # the load starts this long before the common start at the latest


def start_margin(processes: int, threads: int) -> float:
    """Seconds from opening the workers' start gates to the common start: time for every thread to pass its gate, then
    for the hogs' load to begin.

    `processes` counts the workers, `threads` their slots.  Each thread waits at the gate in its
    shared buffer itself, at its own policy, and one futex wake per worker releases them all:
    measured on the 2-CPU VM (policy_matrix cells of 0.5 s, one worker of ten threads and two
    hogs), every thread passed its gate within 0.1 ms of its opening, and the hogs, woken one per
    CPU once they had, began their load 0.1 to 0.4 ms after; 1,024 threads in 16 processes passed
    theirs within 10 ms.  A SCHED_OTHER thread woken onto a CPU that runs something else waits
    for that task's slice or the tick (4 ms here; this kernel does not preempt): beside a busy
    loop of another program, a hog began its load after the start in 14 of 120 cells with 4 ms,
    6 of 160 with 5 ms and 7 of 200 with 6 ms (the old 10 ms: none of 60); none of 120 on a quiet
    VM with 5 ms.  So 5 ms, 0.3 ms a process and 12 µs a thread.  (Before the gate was in shared memory, a
    Python thread of each worker read a `go` line and released the others: up to 8 ms behind the
    hogs on this VM, and the margin was 10 ms, 0.5 ms a process and 12 µs a thread.)  A worker
    whose last thread passed its gate after the start is said in the cell's warnings, as is a hog
    whose load began after it (their slots say when).
    """
    return min(0.060, 0.005 + 0.0003 * processes + 0.000012 * threads)


LoadGroup = list[tuple[Worker, int]]  # the hog threads (worker, slot) woken on one CPU, or one left unpinned


def _group_began(group: LoadGroup) -> list[tuple[int, Worker]]:
    """When each thread of a load group began its work, with its hog, for those that did."""
    return [(t, h) for h, index in group if h.buffer is not None and (t := h.buffer.work_started()[index])]


def load_late(groups: list[LoadGroup], t0: Optional[int]) -> list[tuple[str, int]]:
    """The CPUs whose load began after the common start `t0`: (the hog that began first there, how late), from their slots.

    A CPU is loaded once one of the hogs woken on it runs: more hogs than CPUs share them, and
    one waiting for its turn beside a hog that spins is no CPU without load.  A group none of
    whose threads ever began is a dead hog, said elsewhere."""
    out = []
    for group in groups:
        began = _group_began(group)
        if began and t0:
            first, hog = min(began, key=lambda each: each[0])
            if first > t0:
                out.append((hog.label, first - t0))
    return out


def gate_late(buffer: samples.Buffer, t0: Optional[int]) -> int:
    """How long after the common start `t0` a worker's last thread passed the start gate (ns; 0 or less: in time or never started)."""
    passed = [t for t in buffer.gate_passed() if t]
    return max(passed) - t0 if passed and t0 else 0


def await_gates(workers: list[Worker], until_ns: int) -> None:
    """Return once every thread of the workers that starts with the cell passed its start gate, or at `until_ns`.

    The load starts after: a thread at SCHED_OTHER woken at its gate while the hogs spin waits
    for a CPU like any other (4 ms and more on the 2-CPU VM), and would start late for it.  A
    thread spawned mid-run (`spawned: true`) is at no gate, and a worker that exited passes none:
    neither is waited for (waiting gave the hogs 1 ms to begin instead of the margin's 5)."""
    pending = [w for w in workers if w.buffer is not None]
    while pending and time.monotonic_ns() < until_ns:
        pending = [w for w in pending if not _gates_passed(w)]
        if pending:
            time.sleep(GATE_POLL_S)


def _gates_passed(w: Worker) -> bool:
    """Whether every thread of `w` that starts with the cell passed its gate, or `w` is gone."""
    assert w.buffer is not None
    if w.popen is not None and exit_code(w.popen) is not None:
        return True
    at_start = {t.index for t in w.planned if not t.spawned}
    return all(passed for i, passed in enumerate(w.buffer.gate_passed()) if i in at_start)


def _await_load(groups: list[LoadGroup], until_ns: int) -> None:
    """Return once a hog began its load on every CPU the hogs were woken on, or at `until_ns`; asleep meanwhile, so that
    a hog woken on the runner's own CPU has it (the runner going on with its own work held one back by 2 ms)."""
    pending = groups
    while pending and time.monotonic_ns() < until_ns:
        pending = [g for g in pending if not _group_began(g)]
        if pending:
            time.sleep(GATE_POLL_S)


def start_load(hogs: list[Worker], start_ns: int, end_ns: int, until_ns: int) -> list[LoadGroup]:
    """Open the hogs' gates, each spinning thread woken on the CPU it may use that has the fewest so far, then given its
    own CPUs back once a hog runs on each: the load is spread at once.  Returns the threads by the CPU they were woken on.

    Woken together, two hogs of the 2-CPU VM were put on one CPU and waited for the load balancer,
    2 to 5 ms and once 41 ms (README, "The start margin follows the threads"); woken one per CPU,
    they began within 0.4 ms of their gates on a quiet VM.  Where they go after is the
    scheduler's to say, as before."""
    by_cpu: dict[int, LoadGroup] = {}
    alone: list[LoadGroup] = []
    restore: list[tuple[int, set[int]]] = []
    threads: list[tuple[Worker, int, int, set[int]]] = []  # (hog, slot, tid, the CPUs it may use)
    for h in hogs:
        tids = list((h.ready or {}).get("tids", []))
        spinning = range(1, len(tids)) if h.spec.get("threads") else range(len(tids))  # a hog of threads has a sleeping main
        for index in spinning:
            try:
                threads.append((h, index, tids[index], os.sched_getaffinity(tids[index])))
            except OSError:  # gone: left where the scheduler put it
                alone.append([(h, index)])
    # The threads with the fewest CPUs choose first: a hog pinned to CPU 0 after one that may go anywhere would
    # otherwise share CPU 0 with it, and leave CPU 1 without load until the balancer moved one.
    threads.sort(key=lambda thread: len(thread[3]))
    try:
        for h, index, tid, allowed in threads:
            cpu = min(sorted(allowed), key=lambda c: len(by_cpu.get(c, [])))
            try:
                os.sched_setaffinity(tid, {cpu})
            except (OSError, ValueError):  # gone, or a CPU it may no longer use
                alone.append([(h, index)])
                continue
            restore.append((tid, allowed))
            by_cpu.setdefault(cpu, []).append((h, index))
        for h in hogs:
            assert h.buffer is not None
            h.buffer.open_gate(start_ns, end_ns)
        groups = list(by_cpu.values()) + alone
        _await_load(groups, until_ns)
    finally:
        for tid, allowed in restore:
            with suppress(OSError):
                os.sched_setaffinity(tid, allowed)
    return groups
