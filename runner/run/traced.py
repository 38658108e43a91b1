"""What the scheduler's trace says about each thread of a cell: pure, no I/O.

The shell hands over the native reader's per-thread aggregates (runner/run/tracing.py)
and what it could still learn about the tasks the trace names (their process and
policy, read while they lived).  This turns them into figures every thread can have,
the runner's own and a program's alike: the wake-up latency of every wake-up (from
sched_waking to the switch onto a CPU) as a spread, preemptions with who took the CPU,
the trace's migrations, for the worst wake-ups who held the CPU meanwhile, and for the most
preempted runs (callbacks, for a thread with callbacks) how long and by whom.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Optional

from runner.histogram import from_rows
from runner.results.document import PreemptedRun as StoredRun
from runner.results.document import Preemptor as StoredPreemptor
from runner.results.document import ThreadHistograms, ThreadResult, TraceInfo
from runner.run.measure import spread
from runner.run.tracing import PreemptedRun, TraceData, TracedThread, TraceUnavailable

IDLE = "idle"


@dataclass(frozen=True)
class Task:
    """What the shell could still read about a task the trace names: its process and its class as ps writes it."""

    pid: int
    cls: str  # TS, FF, RR, B, IDL, DLN


def task_class(prio: int, known: Optional[Task]) -> tuple[str, Optional[int]]:
    """(class as ps writes it, RT priority) from sched_switch's prio, sharpened by what /proc said while the task lived."""
    if prio < 0:
        return "DLN", None
    if prio < 100:
        cls = known.cls if known is not None and known.cls in ("FF", "RR") else "RT"
        return cls, 99 - prio
    return (known.cls if known is not None and known.cls in ("TS", "B", "IDL") else "TS"), None


def _stored(tid: int, comm: str, prio: int, count: int, tasks: dict[int, Task]) -> StoredPreemptor:
    known = tasks.get(tid)
    if tid == 0:
        return StoredPreemptor(comm=comm or "swapper", tid=0, pid=0, cls=IDLE, count=count)
    cls, rtprio = task_class(prio, known)
    return StoredPreemptor(comm=comm, tid=tid, pid=known.pid if known else None, cls=cls, rtprio=rtprio, count=count)


def _late(t: TracedThread, bound: int, tasks: dict[int, Task]) -> list[StoredPreemptor]:
    """Who held the CPU during each of the worst wake-ups above `bound`, most often first."""
    counts: Counter[tuple[int, str, int]] = Counter()
    for w in t.worst:
        if w.latency_ns > bound:
            counts[(w.delayer_tid, w.delayer_comm, w.delayer_prio)] += 1
    return [_stored(tid, comm, prio, n, tasks) for (tid, comm, prio), n in counts.most_common()]


def _run(r: PreemptedRun, window_start: int, tasks: dict[int, Task]) -> StoredRun:
    return StoredRun(
        at_ns=r.start_ns - window_start,
        wall_ns=max(0, r.end_ns - r.start_ns),
        preempted_ns=r.preempted_ns,
        preemptions=r.preemptions,
        by=_stored(r.taker_tid, r.taker_comm, r.taker_prio, r.taker_count, tasks),
        by_ns=r.taker_ns,
    )


def with_trace(thread: ThreadResult, t: TracedThread, tasks: dict[int, Task], window_start: int = 0) -> ThreadResult:
    """A thread's result with the trace's figures and attributions added."""
    hist = from_rows(t.latency, t.latency_min, t.latency_max)
    wakeup = spread(hist, t.latency_sum / t.wakeups if t.wakeups else None, None, t.wakeups)  # the reader sums, it keeps no squares
    figures = thread.figures.model_copy(
        update={
            "wakeup_ns": wakeup,
            "preemptions": t.preemptions,
            "migrations": thread.figures.migrations if thread.figures.migrations is not None else t.migrations,
            "cpus_seen": thread.figures.cpus_seen or t.cpus,
        }
    )
    histograms = thread.histograms.model_copy(update={"wakeup": hist}) if thread.histograms else ThreadHistograms(wakeup=hist)
    preempted_by = [_stored(p.tid, p.comm, p.prio, p.times, tasks) for p in t.preemptors]
    late = _late(t, wakeup.p99, tasks) if wakeup is not None else []
    return thread.model_copy(
        update={
            "figures": figures,
            "histograms": histograms if hist is not None else thread.histograms,
            "preempted_by": preempted_by,
            "late_wakeups_by": late,
            "late_wakeups": sum(p.count for p in late),
            "preempted_runs": [_run(r, window_start, tasks) for r in t.runs],
        }
    )


def apply(
    threads: list[ThreadResult], trace: TraceData | TraceUnavailable | None, tasks: dict[int, Task], window_start: Optional[int] = None
) -> tuple[list[ThreadResult], TraceInfo]:
    """Every thread with the trace's figures where the trace followed it, and what the trace was (or why there was none).

    `window_start` (CLOCK_MONOTONIC of the measured window's start) is where preempted runs' times count from.
    """
    if trace is None:
        return threads, TraceInfo(enabled=False, reason="not asked for (--no-trace)")
    if isinstance(trace, TraceUnavailable):
        return threads, TraceInfo(enabled=False, reason=trace.reason)
    origin = window_start or 0
    out = [with_trace(t, trace.threads[t.tid], tasks, origin) if t.tid in trace.threads else t for t in threads]
    info = TraceInfo(
        enabled=True,
        events=trace.events,
        lost=trace.lost,
        untracked=trace.untracked,
        unseen_switch_ins=trace.unseen_switch_ins,
        reader_cpu_ns=trace.reader_cpu_ns,
        duration_ns=trace.duration_ns,
        window_start_ns=window_start,
        notes=list(trace.notes),
    )
    return out, info


def warnings(info: TraceInfo) -> list[str]:
    """What makes the trace's figures incomplete, in words."""
    out = []
    if info.lost:
        out.append(
            f"the scheduler trace lost {info.lost:,} events (its buffer overflowed): wake-up latencies and preemptions are undercounted"
        )
    if info.untracked:
        out.append(f"the scheduler trace followed more threads than its table holds: {info.untracked:,} events were not attributed")
    return out
