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
from collections.abc import Sequence
from typing import Optional

from runner import histogram as hg
from runner import units
from runner.results.document import EventResult, Holder, PhaseResult
from runner.results.threadfigures import Spread
from runner.run.measure import spread
from runner.run.rawcell import RawThread
from runner.run.samples import EventStats, PhaseStats, SlotData
from runner.scenario.model import Event, EventKind, PhasesWork, Policy, Scenario
from runner.scenario.plan import Settings, phase_settings
from runner.scenario.program import admitted_words, asked_words, deadline_asks

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
STALL_MIN_NS = 100_000_000  # blocked at least this long at the end of the run, with nothing left to release it: stuck


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
        dropped=st.dropped if kind is EventKind.SPAWN else 0,
        lost=st.dropped if kind is EventKind.RESUME else 0,  # the native core counts both as its event's drops
        cut=st.cut,
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
) -> tuple[list[EventResult], list[PhaseResult], dict[str, Optional[Spread]]]:
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
    figures: dict[str, Optional[Spread]] = {}
    for field, stats in by_figure.items():
        figures[field] = _merged(stats)
    chain = slot.events[n] if n < len(slot.events) else EventStats()
    figures["chain_ns"] = spread(chain.histogram, chain.mean, chain.m2, chain.count)

    phases: list[PhaseResult] = []
    for k, requested in enumerate(phase_settings(work, base)):
        ph = slot.phases[k] if k < len(slot.phases) else PhaseStats()
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


def _merged(stats: list[EventStats]) -> Optional[Spread]:
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


_RELEASED_BY = {  # what a thread blocked in the first is waiting for: another thread's event of the second kind on it
    EventKind.WAIT: (EventKind.SIGNAL, EventKind.BROADCAST),
    EventKind.SUSPEND: (EventKind.RESUME,),
    EventKind.BARRIER: (EventKind.BARRIER,),
}


def stalls(threads: Sequence[RawThread], end_ns: Optional[int], labels: dict[int, str]) -> list[str]:
    """The threads still blocked at the end that nothing left in the cell could release: deadlocks, releases that never came.

    A thread blocked at the end (in a lock, a condition wait, a barrier or a suspend) for
    STALL_MIN_NS or more is stuck unless some thread that could release it was still going:
    the holder of its mutex, or a thread with a signal, resume or barrier event on what it waits
    for, which itself was not blocked for good and had not finished its program.  A stage
    waiting for its producer's next release (however far apart they came) is waiting; two
    threads each holding the mutex the other wants, a waiter whose only signaller finished, and
    a barrier a finished thread will never pass again are stuck.  `labels` names threads by
    their index in `threads`.
    """
    if end_ns is None:
        return []
    owners: dict[str, int] = {}  # who held each mutex when the run ended, by where each thread stood in its program
    waits: dict[int, tuple[Event, PhasesWork]] = {}
    going: set[int] = set()
    can_release: dict[tuple[EventKind, str], set[int]] = {}
    for gid, t in enumerate(threads):
        work, slot = t.planned.work, t.slot
        if not isinstance(work, PhasesWork) or not slot.tid:
            continue
        events = [e for _, e in work.events()]
        for e in events:
            for name, _ in e.names():
                can_release.setdefault((e.event, name), set()).add(gid)
        for name in _held(work, slot.cur_phase, slot.cur_event):
            owners[name] = gid
        if slot.blocked_since_ns and 0 <= slot.cur_event < len(events):
            waits[gid] = (events[slot.cur_event], work)
        elif not (slot.work_end_ns and slot.work_end_ns < end_ns):  # neither blocked nor done with its program
            going.add(gid)
    changed = True
    while changed:  # a blocked thread that something going can release is going too
        changed = False
        for gid, (event, _) in waits.items():
            if gid not in going and _releasable(gid, event, going, owners, can_release):
                going.add(gid)
                changed = True
    out = []
    for gid, (event, work) in waits.items():
        slot = threads[gid].slot
        blocked = end_ns - slot.blocked_since_ns
        if gid in going or blocked < STALL_MIN_NS:
            continue
        phase = work.phase_names()[slot.cur_phase] if 0 <= slot.cur_phase < len(work.phases) else "?"
        out.append(
            f"{labels.get(gid, str(gid))} was blocked in `{event.label()}` (phase {phase}, event {slot.cur_event}) for the last "
            f"{units.human_duration(blocked)} of the run; {_why_stuck(event, owners, labels)}"
        )
    return out


def _held(work: PhasesWork, phase: int, at: int) -> set[str]:
    """The mutexes a thread standing at event `at` (program order) of `phase` holds: those locked earlier in the phase's
    pass and not unlocked (a phase ends holding none: validation sees to that); a condition wait's mutex is let go
    while it waits.  The runner reads this from where the thread stood, not from the mutexes: a thread cut by the
    end unlocks what it held as it leaves, before the runner looks."""
    held: set[str] = set()
    if not 0 <= phase < len(work.phases):
        return held
    for n, (k, event) in enumerate(work.events()):
        if k != phase or n > at:
            continue
        name = event.names()[0][0] if event.names() else ""
        if event.event is EventKind.LOCK and n < at:
            held.add(name)
        elif event.event is EventKind.UNLOCK and n < at:
            held.discard(name)
        elif event.event is EventKind.WAIT and n == at and event.mutex:
            held.discard(event.mutex)
    return held


def _releasable(
    gid: int, event: Event, going: set[int], owners: dict[str, int], can_release: dict[tuple[EventKind, str], set[int]]
) -> bool:
    name = event.names()[0][0] if event.names() else ""
    if event.event is EventKind.LOCK:
        owner = owners.get(name, -1)
        return owner < 0 or owner in going
    return any(other in going and other != gid for kind in _RELEASED_BY.get(event.event, ()) for other in can_release.get((kind, name), ()))


def _why_stuck(event: Event, owners: dict[str, int], labels: dict[int, str]) -> str:
    name = event.names()[0][0] if event.names() else ""
    if event.event is EventKind.LOCK:
        return f"its holder, {labels.get(owners.get(name, -1), 'a thread')}, was stuck too"
    what = {EventKind.WAIT: f"signals {name}", EventKind.SUSPEND: f"resumes {name}", EventKind.BARRIER: f"passes the barrier {name}"}
    return f"no thread that {what.get(event.event, name)} was still going"


def deadline_admission(scenario: Scenario, rt_runtime_us: Optional[int], rt_period_us: Optional[int], cpus: int) -> str:
    """Why the kernel refused SCHED_DEADLINE (EBUSY), in numbers: the cell's bandwidth against what the kernel admits."""
    text = f"the kernel refused SCHED_DEADLINE admission (EBUSY): this cell asks {asked_words(deadline_asks(scenario))}"
    if rt_runtime_us is not None and rt_period_us and rt_runtime_us >= 0:
        text += f" and the kernel admits {admitted_words(rt_runtime_us, rt_period_us, cpus)}, less what other deadline tasks hold"
    return text
