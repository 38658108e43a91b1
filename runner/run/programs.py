"""Figures of programs (`kind: phases`) from the native core's records: per event, per phase, per thread.  Pure, no I/O.

The native core keeps, for every event of a thread's program, a count and a
histogram of what the event is about (the wait of a lock, a condition or a
barrier; the wake-up latency of a timer or a resume; the wall time of the rest),
who held a contended lock, and for every phase its passes, time, rusage, CPUs and
the settings the kernel reported when the thread entered it.  This module names
all of that (threads by name, resources by name) for the results, adds the
per-thread figures the registry declares (lock_wait, cond_wait, barrier_wait,
resume_latency, chain), and finds threads that were stuck at the end of the run.
"""

from __future__ import annotations

import os
from typing import Optional

from runner import figures as fg
from runner import histogram as hg
from runner import units
from runner.results.document import EventResult, Holder, PhaseResult
from runner.run.measure import spread
from runner.run.samples import EventStats, PhaseStats, SlotData
from runner.scenario.model import EventKind, PhasesWork, Policy, Scenario
from runner.scenario.plan import Settings
from runner.scenario.program import deadline_asks

_MEASURES = {
    EventKind.LOCK: "wait",
    EventKind.WAIT: "wait",
    EventKind.BARRIER: "wait",
    EventKind.TIMER: "latency",
    EventKind.SUSPEND: "latency",
}
_FIGURE_OF = {
    EventKind.LOCK: "lock_wait_ns",
    EventKind.WAIT: "cond_wait_ns",
    EventKind.BARRIER: "barrier_wait_ns",
    EventKind.SUSPEND: "resume_latency_ns",
}
STALL_MIN_NS = 100_000_000  # blocked at least this long at the end of the run, ...
STALL_FACTOR = 2  # ... and more than this many times its longest block before: stuck, not just waiting


def _event_result(
    phase: str, index: int, event_label: str, kind: EventKind, resource: Optional[str], st: EventStats, names: dict[int, str]
) -> EventResult:
    return EventResult(
        phase=phase,
        index=index,
        event=event_label,
        kind=kind.value,
        resource=resource,
        measures=_MEASURES.get(kind, "wall"),
        count=st.count,
        total_ns=st.total,
        spread_ns=spread(st.histogram, st.mean, st.m2, st.count),
        contended=st.contended,
        holders=[Holder(thread=names.get(gid, f"thread #{gid}"), contentions=n, wait_ns=w) for gid, n, w in st.holders],
        dropped=st.dropped,
    )


def settings_of(ph: PhaseStats, every: tuple[int, ...]) -> Optional[Settings]:
    """The settings the kernel reported for a thread in a phase record (or a spawned thread's start record)."""
    if not ph.read_back:
        return None
    try:
        policy = Policy.from_kernel(ph.policy)
    except ValueError:
        return None
    cpus = tuple(c for c in ph.affinity)
    runtime, deadline, period = ph.deadline if policy is Policy.DEADLINE else (0, 0, 0)
    return Settings(policy, ph.priority, ph.nice, None if set(cpus) >= set(every) else cpus, runtime, deadline, period)


def program_results(
    work: PhasesWork, slot: SlotData, base: Settings, names: dict[int, str], every: tuple[int, ...]
) -> tuple[list[EventResult], list[PhaseResult], dict[str, Optional[fg.Spread]]]:
    """Per event, per phase, and the thread's event figures (by ThreadFigures field)."""
    events: list[EventResult] = []
    by_figure: dict[str, list[EventStats]] = {}
    phase_names = work.phase_names()
    n = 0
    for k, phase in enumerate(work.phases):
        for ev in phase.events:
            st = slot.events[n] if n < len(slot.events) else EventStats()
            about = ev.resource or ev.cond or ev.timer or ev.thread
            events.append(_event_result(phase_names[k], n, ev.label(), ev.event, about, st, names))
            if ev.event in _FIGURE_OF:
                by_figure.setdefault(_FIGURE_OF[ev.event], []).append(st)
            n += 1
    figures: dict[str, Optional[fg.Spread]] = {}
    for field, stats in by_figure.items():
        figures[field] = _merged(stats)
    chain = slot.events[n] if n < len(slot.events) else EventStats()
    figures["chain_ns"] = spread(chain.histogram, chain.mean, chain.m2, chain.count)

    phases: list[PhaseResult] = []
    current = base
    for k, phase in enumerate(work.phases):
        ph = slot.phases[k] if k < len(slot.phases) else PhaseStats()
        requested = current.with_sched(phase.sched, phase.cpus) if (phase.sched is not None or phase.cpus is not None) else None
        current = requested or current
        applied = settings_of(ph, every)
        degraded = _phase_degraded(requested, applied, ph) if ph.entered else []
        phases.append(
            PhaseResult(
                name=phase_names[k],
                passes=ph.passes,
                entered=ph.entered,
                time_ns=max(0, ph.time_ns),
                involuntary=max(0, ph.ru[0]),
                voluntary=max(0, ph.ru[1]),
                minor_faults=max(0, ph.ru[2]),
                major_faults=max(0, ph.ru[3]),
                cpus_seen=list(ph.cpus_seen),
                applied=applied,
                requested=requested,
                degraded=degraded,
            )
        )
    return events, phases, figures


def _merged(stats: list[EventStats]) -> Optional[fg.Spread]:
    """One spread over several events of a kind (every lock of the thread): histograms merged, mean and variance pooled."""
    hist = hg.merge(s.histogram for s in stats)
    total = sum(s.count for s in stats)
    if hist is None or not total:
        return None
    mean = sum(s.mean * s.count for s in stats) / total
    m2 = sum(s.m2 + s.count * (s.mean - mean) ** 2 for s in stats)
    return spread(hist, mean, m2, total)


def _phase_degraded(requested: Optional[Settings], applied: Optional[Settings], ph: PhaseStats) -> list[str]:
    """How a phase's settings fell short, with the kernel's reason (the errno of applying them on entry)."""
    if requested is None or applied is None:
        return []
    sched_err, nice_err, cpus_err = ph.errors
    out = []
    if (requested.policy, requested.priority, requested.runtime, requested.period) != (
        applied.policy,
        applied.priority,
        applied.runtime,
        applied.period,
    ):
        why = f" ({os.strerror(sched_err)})" if sched_err else ""
        out.append(f"policy {requested.label()} requested, {applied.label()} applied{why}")
    if requested.cpus != applied.cpus:
        why = f" ({os.strerror(cpus_err)})" if cpus_err else ""
        out.append(f"cpus {requested.cpus_label()} requested, {applied.cpus_label()} applied{why}")
    if nice_err and requested.nice != applied.nice:
        out.append(f"nice {requested.nice} requested, {applied.nice} applied ({os.strerror(nice_err)})")
    return out


def stall(work: PhasesWork, slot: SlotData, end_ns: Optional[int], label: str) -> Optional[str]:
    """A thread still blocked at the end of the run, stuck rather than waiting: a deadlock or a release that never came.

    Stuck: blocked for STALL_MIN_NS or more, and more than STALL_FACTOR times the longest block
    it came out of during the run (or it came out of none).  A thread that waits as long as it
    always did (a stage between its producer's releases) is waiting; one that had waited 10 ms
    at most and has now waited 780 ms is not, however late in the run its block began.
    """
    if not slot.blocked_since_ns or end_ns is None:
        return None
    blocked = end_ns - slot.blocked_since_ns
    if blocked < STALL_MIN_NS or blocked <= STALL_FACTOR * slot.block_max_ns:
        return None
    events = [e for _, e in work.events()]
    where = events[slot.cur_event].label() if 0 <= slot.cur_event < len(events) else "an event"
    phase = work.phase_names()[slot.cur_phase] if 0 <= slot.cur_phase < len(work.phases) else "?"
    before = (
        f"its longest block before was {units.human_duration(slot.block_max_ns)}"
        if slot.block_max_ns
        else "it had come out of no block before"
    )
    return (
        f"{label} was blocked in `{where}` (phase {phase}, event {slot.cur_event}) for the last {units.human_duration(blocked)} "
        f"of the run; {before}"
    )


def deadline_admission(scenario: Scenario, rt_runtime_us: Optional[int], rt_period_us: Optional[int], cpus: int) -> str:
    """Why the kernel refused SCHED_DEADLINE (EBUSY), in numbers: the cell's bandwidth against what the kernel admits."""
    asks = deadline_asks(scenario)
    total = sum(b for _, b in asks)
    parts = ", ".join(f"{name} {b:.2f}" for name, b in asks[:6]) + (", ..." if len(asks) > 6 else "")
    text = f"the kernel refused SCHED_DEADLINE admission (EBUSY): this cell asks {total:.2f} CPUs of bandwidth ({parts})"
    if rt_runtime_us is not None and rt_period_us and rt_runtime_us >= 0:
        share = rt_runtime_us / rt_period_us
        text += (
            f" and the kernel admits at most {share:.2f} per CPU x {cpus} CPUs = {share * cpus:.2f} "
            f"(sched_rt_runtime_us {rt_runtime_us} / sched_rt_period_us {rt_period_us}), less what other deadline tasks hold"
        )
    return text
