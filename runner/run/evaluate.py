"""The pure core of a cell run: raw data in, figures, degradations, verdicts and a status out.  No I/O.

The process shell (run/spawn.py) hands over a `RawCell`; this module decides everything
the results say about it, so every rule (what counts as missed, when a thread is
degraded, which expectation applies to which thread, how a status is chosen) is
tested with plain records, without processes or RT rights.
"""

from __future__ import annotations

import errno
import os
from typing import Optional

from runner import units
from runner.figures import has, measured_how
from runner.results.document import (
    Background,
    BackgroundKind,
    CallbackResult,
    CellResult,
    EventResult,
    Overhead,
    PhaseResult,
    RosCaptureInfo,
    Status,
    ThreadHistograms,
    ThreadResult,
    TraceInfo,
    Verdict,
    ps_rows,
    thread_label,
    worst,
)
from runner.results.threadfigures import ThreadFigures
from runner.run import callbacks, outside, programs, traced
from runner.run.measure import check, thread_figures
from runner.run.rawcell import ApplyErrors, RawCell, RawThread, ResourceState, Timeline
from runner.run.samples import SlotData
from runner.scenario.loader import ResolvedCell, spec_json
from runner.scenario.matching import expectations_for, match_threads
from runner.scenario.model import EventKind, Expectation, PeriodicWork, PhasesWork, Policy, Scenario, metric_figure
from runner.scenario.plan import PROGRAM_ORIGIN, PlannedThread, Settings, thread_kind
from runner.scenario.worktext import describe_work

QUEUE_DEPTH = 32  # resumes a queue holds (the native core's QDEPTH)
INTERRUPTED_REASON = "interrupted (Ctrl-C or SIGTERM); figures cover what ran until then"


def releases_due(work: PeriodicWork, timeline: Timeline, interrupted: bool) -> int:
    """Releases on the thread's grid from the start gate to the end of the cell (or to the interrupt).

    Every release no callback served is a missed one, those after a worker was stopped or killed
    included: the count runs to the end of the cell, not to the last callback.
    """
    if timeline.start_ns is None or timeline.end_ns is None:
        return 0
    end = timeline.end_ns
    if interrupted and timeline.stopped_ns is not None:
        end = min(end, timeline.stopped_ns)
    first = timeline.start_ns + work.offset
    return 0 if end <= first else (end - first + work.period - 1) // work.period


def degradation(requested: Settings, applied: Optional[Settings], errors: ApplyErrors, admission: str = "") -> list[str]:
    """How a thread's settings fell short of the request, in words, with the kernel's reason where it gave one.

    `admission` explains a SCHED_DEADLINE refusal (EBUSY) with the cell's bandwidth and the kernel's limit.
    """
    if applied is None:
        return ["the thread was gone before its settings could be read back"]
    why = {k: f" ({os.strerror(v)})" for k, v in errors.failed().items()}
    if requested.policy is Policy.DEADLINE and errors.sched == errno.EBUSY and admission:
        why["sched"] = f" ({admission})"
    out = []
    if (requested.policy, requested.priority, requested.runtime, requested.deadline, requested.period) != (
        applied.policy,
        applied.priority,
        applied.runtime,
        applied.deadline,
        applied.period,
    ):
        if requested.policy is Policy.DEADLINE or applied.policy is Policy.DEADLINE:
            out.append(f"policy {requested.label()} requested, {applied.label().split(' nice')[0]} applied{why.get('sched', '')}")
        else:
            out.append(f"policy {requested.label().split(' ')[0]} requested, {applied.label().split(' ')[0]} applied{why.get('sched', '')}")
    elif errors.sched:  # the policy holds, yet sched_setattr refused something: uclamp, the only other part it sets
        hint = "; uclamp (util_min, util_max) needs a kernel built with CONFIG_UCLAMP_TASK" if errors.sched == errno.EOPNOTSUPP else ""
        out.append(f"the kernel refused part of the scheduling request ({os.strerror(errors.sched)}){hint}")
    if requested.nice != applied.nice:
        out.append(f"nice {requested.nice} requested, {applied.nice} applied{why.get('nice', '')}")
    if requested.cpus != applied.cpus:
        out.append(f"cpus {requested.cpus_label()} requested, {applied.cpus_label()} applied{why.get('cpus', '')}")
    if errors.memory:
        out.append(f"memory lock failed ({os.strerror(errors.memory)})")
    if errors.other:
        out.append(f"a per-callback allocation failed ({os.strerror(errors.other)})")
    return out


def verdict_label(t: PlannedThread, processes: int) -> str:
    """How a verdict names its thread: the instance only when a cell runs several process instances."""
    return thread_label(t.process, t.instance, t.index, t.name, show_instance=processes > 1)


def _figures(raw: RawThread, timeline: Timeline, interrupted: bool, bound: Optional[int]) -> ThreadFigures:
    work = raw.planned.work
    due = releases_due(work, timeline, interrupted) if isinstance(work, PeriodicWork) else 0
    return thread_figures(raw.slot, raw.planned.periodic, due, bound, released=raw.planned.released)


def _histograms(slot: SlotData) -> Optional[ThreadHistograms]:
    st = slot.stats
    if st.latency is None and st.slack is None and st.wall is None:
        return None
    return ThreadHistograms(latency=st.latency, slack=st.slack, callback_wall=st.wall)


def behind(f: ThreadFigures) -> str:
    """`missed 41 of 200 releases, 41 of 159 callbacks overran their period (worst slack −1.64 ms)`, or "" when the thread kept up."""
    parts = []
    if f.missed_releases:
        parts.append(f"missed {f.missed_releases:,} of {f.releases:,} releases")
    if f.overruns and f.overruns > f.callbacks:  # a ROS 2 callback still running at the end overran too, and never ended
        parts.append(f"{f.overruns:,} callbacks overran their period ({f.callbacks:,} ended, the others were still running at the end)")
    elif f.overruns:
        parts.append(f"{f.overruns:,} of {f.callbacks:,} callbacks overran their period")
    worst = f" (worst slack {units.human_duration(f.slack_ns.min)})" if f.slack_ns and parts else ""
    return ", ".join(parts) + worst


def throttled(requested: Settings, f: ThreadFigures) -> str:
    """Why a SCHED_DEADLINE thread fell behind, when its callbacks took longer than its runtime: the kernel throttled it."""
    runtime, period = requested.runtime, requested.period
    wall = f.callback_wall_ns
    if requested.policy is not Policy.DEADLINE or not runtime or not period or wall is None or wall.max <= runtime:
        return ""
    return (
        f"; as SCHED_DEADLINE it has {units.human_duration(runtime)} of runtime every {units.human_duration(period)} and its "
        f"callbacks took up to {units.human_duration(wall.max)}: the kernel stops it until its next period once the runtime is spent"
    )


def warnings(threads: list[ThreadResult], processes: int, failed: frozenset[str] = frozenset()) -> list[str]:
    """What the figures show went wrong without an expectation failing, in words: never a silent `passed`.

    A periodic thread that missed releases or overran could not keep up with its period
    (said here when the scenario's own expectation bounds it; otherwise its implicit
    verdict, failed, says it: `failed` names the threads that have one); a thread whose
    samples could not all be written has figures that still count every callback.
    """
    out = []
    for t in threads:
        f = t.figures
        name = t.label(processes > 1)
        if (t.periodic or t.released) and (f.missed_releases or f.overruns) and name not in failed:
            out.append(f"{name} could not keep up: {behind(f)}{throttled(t.requested, f)}")
        if t.samples_lost:
            out.append(
                f"{name}: {t.samples_lost:,} per-callback samples were overwritten before the runner could write them;"
                " the figures still count every callback"
            )
    return out


KEEPS_UP_METRICS = ("missed_releases", "overruns")  # figures of the registry: a scenario's own bound on them replaces the implicit one
RAN_METRIC = "callbacks"  # ... and on this one, the implicit verdict that a thread with callbacks ran one


def queue_consumers(raw: RawCell) -> dict[str, list[PlannedThread]]:
    """The stages released by resumes that take from each queue (instances apart), by queue name."""
    out: dict[str, list[PlannedThread]] = {}
    for t in raw.threads:
        if t.planned.released and isinstance(t.planned.work, PhasesWork) and (t.slot.tid or not t.planned.spawned):
            for q in t.planned.work.suspends_on():
                out.setdefault(q, []).append(t.planned)
    return out


def left_behind(queue: ResourceState, raw: RawCell) -> int:
    """Resumes still queued at the end beyond what the threads resuming it put there in one go: a backlog that grew.

    At any instant a stage that keeps up holds at most the resumes that came while it served
    the last ones, and those come in bursts of at most one per resume event of each thread
    resuming the queue (a producer resuming it three times per release: three).  What is
    queued beyond that at the end is a backlog it could not serve: missed, as what the queue
    drops is.  (12 ms of work behind a 10 ms producer left 17 after 1 s.)
    """
    burst = sum(
        sum(1 for _, e in t.planned.work.events() if e.event is EventKind.RESUME and e.resource == queue.name)
        for t in raw.threads
        if isinstance(t.planned.work, PhasesWork)
    )
    return max(0, queue.queued - burst)


def _missed_words(queue: str, dropped: int, left: int) -> str:
    parts = [f"queue {queue} dropped {dropped:,} resumes, each when {QUEUE_DEPTH} were queued already"] if dropped else []
    if left:
        parts.append(f"{left:,} resumes of queue {queue} were still waiting at the end beyond one burst of its resumes")
    return "; ".join(parts)


def queue_words(planned: PlannedThread, raw: RawCell) -> str:
    """`: 12 resumes of queue frames were still waiting at the end ...`: where a stage released by resumes missed them, named
    (its missed releases are its sole queues' drops and backlog); "" for any other thread."""
    if not planned.released or not isinstance(planned.work, PhasesWork):
        return ""
    consumers = queue_consumers(raw)
    parts = [
        _missed_words(r.name, r.dropped, 0 if raw.interrupted else left_behind(r, raw))
        for r in raw.resources
        if r.name in planned.work.suspends_on() and len(consumers.get(r.name, ())) == 1
    ]
    text = "; ".join(p for p in parts if p)
    return f": {text}" if text else ""


def lost_words(queue: ResourceState) -> str:
    """What a queue that drops resumes (pending: drop, rt-app's resume) lost, in words: never a miss, always said."""
    n = queue.lost
    return (
        f"queue {queue.name}: {n:,} resume{'s' if n != 1 else ''} came while no thread was suspended on it and "
        f"{'were' if n != 1 else 'was'} lost, as rt-app loses a resume nobody waits for (pending: drop); "
        "no thread's missed releases count them"
    )


def pool_verdicts(raw: RawCell, consumers: dict[str, list[PlannedThread]], expectations: list[Expectation]) -> list[Verdict]:
    """A failed verdict for each queue several stages take from that dropped resumes or left some behind: the pool could not keep up.

    No one stage missed them (any of them could have taken each), so none is charged with them;
    a bound of the scenario's own on missed_releases for every stage of the pool replaces it.
    `consumers`: queue_consumers of the cell.
    """
    out = []
    for q, stages in consumers.items():
        queue = next((r for r in raw.resources if r.name == q), None)
        if len(stages) < 2 or queue is None:
            continue
        left = 0 if raw.interrupted else left_behind(queue, raw)
        dropped = queue.dropped + left
        if not dropped:
            continue
        own = {id(t) for exp in expectations if exp.metric.value == KEEPS_UP_METRICS[0] for t in match_threads(stages, exp.thread)}
        if all(id(t) in own for t in stages):
            continue
        labels = [verdict_label(t, raw.processes) for t in stages]
        out.append(
            Verdict(
                thread=", ".join(labels),
                metric=KEEPS_UP_METRICS[0],
                limit="<= 0",
                measured=dropped,
                passed=False,
                note=f"could not keep up: {_missed_words(q, queue.dropped, left)} that none of its {len(stages)} stages had taken; "
                "implicit unless the scenario bounds missed_releases for them itself",
            )
        )
    return out


def no_release_due(raw: RawCell) -> set[int]:
    """The threads (ids of their plans) that had no release due in the cell, so that running no callback was right.

    A program's timer releases first one period after the thread reaches it: one longer than
    what was left of the cell had none due (the native core says where its next release was).
    A stage released by resumes had none due when its queues got no resume.  A thread that
    never reached its timer at all is not among them: it was held before it (starved, stuck).
    """
    resumes: dict[str, int] = {}
    for t in raw.threads:
        if isinstance(t.planned.work, PhasesWork):
            for e, (_, event) in enumerate(t.planned.work.events()):
                if event.event is EventKind.RESUME and event.resource and e < len(t.slot.events):
                    resumes[event.resource] = resumes.get(event.resource, 0) + t.slot.events[e].count
    end = raw.timeline.end_ns
    out = set()
    for t in raw.threads:
        work = t.planned.work
        if not isinstance(work, PhasesWork):
            continue
        late_timer = t.planned.periodic and end is not None and t.slot.timer_due_ns >= end
        never_resumed = t.planned.released and not any(resumes.get(q, 0) for q in work.suspends_on())
        if late_timer or never_resumed:
            out.add(id(t.planned))
    return out


def keeps_up(
    measured: list[tuple[PlannedThread, ThreadFigures]], expectations: list[Expectation], raw: RawCell, idle: frozenset[int] = frozenset()
) -> list[Verdict]:
    """A failed verdict for each thread that could not keep up: a cell never passes on one.

    A periodic thread that missed releases or overran, a stage released by resumes whose queue
    dropped some (it was QUEUE_DEPTH activations behind), and a thread with callbacks (periodic,
    or released by resumes) that ran none: starved, or stuck before it reached its timer.
    `idle` names the threads that had no release due (no_release_due).  The verdict is
    implicit (no line in the scenario); an expectation of the scenario's own
    on `missed_releases` or `overruns` (on `callbacks`, for one that ran none) naming the
    thread in this cell replaces it, so a scenario that accepts some misses says how many.
    """
    planned_threads = [p for p, _ in measured]

    def bounded(metrics: tuple[str, ...]) -> set[int]:
        return {id(t) for exp in expectations if exp.metric.value in metrics for t in match_threads(planned_threads, exp.thread)}

    own, own_ran = bounded(KEEPS_UP_METRICS), bounded((RAN_METRIC,))
    out = []
    for planned, fig in measured:
        label = verdict_label(planned, raw.processes)
        if planned.has_callbacks and (fig.missed_releases or fig.overruns):
            if id(planned) in own:
                continue
            metric = KEEPS_UP_METRICS[0] if fig.missed_releases else KEEPS_UP_METRICS[1]
            out.append(
                Verdict(
                    thread=label,
                    metric=metric,
                    limit="<= 0",
                    measured=fig.missed_releases or fig.overruns,
                    passed=False,
                    note=f"could not keep up: {behind(fig)}{throttled(planned.settings, fig)}{queue_words(planned, raw)}; "
                    "implicit (every release served) unless "
                    "the scenario bounds missed_releases or overruns for this thread itself",
                )
            )
        elif planned.has_callbacks and not fig.callbacks and id(planned) not in own_ran | idle and not raw.interrupted:
            out.append(
                Verdict(
                    thread=label,
                    metric=RAN_METRIC,
                    limit=">= 1",
                    measured=0,
                    passed=False,
                    note="could not keep up: not one callback ran (starved, or it never reached its timer or a resume); "
                    "implicit unless the scenario bounds callbacks for this thread itself",
                )
            )
    return out


def callbacks_keep_up(results: list[CallbackResult], expectations: list[Expectation]) -> list[Verdict]:
    """A failed verdict for each ROS 2 timer callback that could not keep up with its timer, as for a periodic thread
    (`keeps_up`): implicit, replaced by a `callback:` expectation of the scenario's own on missed_releases or overruns
    that names it."""
    own = {
        r.key
        for exp in expectations
        if exp.callback and exp.metric.value in KEEPS_UP_METRICS
        for r in callbacks.matching(results, exp.callback)
    }
    return [
        Verdict(
            thread=r.label,
            metric=KEEPS_UP_METRICS[0] if r.figures.missed_releases else KEEPS_UP_METRICS[1],
            limit="<= 0",
            measured=r.figures.missed_releases or r.figures.overruns,
            passed=False,
            note=f"could not keep up: {behind(r.figures)}; implicit (every release of its timer served) unless the scenario "
            "bounds missed_releases or overruns for this callback itself",
        )
        for r in results
        if (r.figures.missed_releases or r.figures.overruns) and r.key not in own
    ]


def spawn_warnings(threads: list[ThreadResult], never: list[str], processes: int) -> list[str]:
    """Spawns that found no free instance, and spawned threads of which no instance ever ran: the program did not run as written.

    `count` is how many instances a spawned thread can have, so instances left unused are not a problem.
    Drops are told once per spawn event of a process, however many of its threads ran it (the
    instances of a thread that spawns itself all do).
    """
    drops: dict[tuple[str, int, str], list[tuple[ThreadResult, int]]] = {}
    for t in threads:
        for e in t.events:
            if e.dropped:
                drops.setdefault((t.process, t.instance, e.event), []).append((t, e.dropped))
    out = []
    for (process, instance, event), found in drops.items():
        who = (
            found[0][0].label(processes > 1)
            if len(found) == 1
            else f"{process}{f'[{instance}]' if processes > 1 else ''} ({len(found)} threads)"
        )
        out.append(
            f"{who}: {sum(n for _, n in found):,} `{event}` found every instance taken (or the kernel refused the thread);"
            " raise the spawned thread's count"
        )
    out += [f"{spec}: never spawned: no spawn event naming it ran" for spec in never]
    return out


def _overhead(raw: RawCell) -> Overhead:
    """Start of the cell to its first callback, last callback to the workers' exit (ns)."""
    wakes = [t.slot.stats.first_wake_ns for t in raw.threads if t.slot.loops and t.slot.stats.first_wake_ns]
    ends = [t.slot.stats.last_end_ns for t in raw.threads if t.slot.loops and t.slot.stats.last_end_ns]
    stopped = raw.timeline.stopped_ns
    return Overhead(
        start_to_first_callback=min(wakes) - raw.timeline.began_ns if wakes else None,
        last_callback_to_exit=stopped - max(ends) if stopped and ends else None,
    )


def judged_threads(exp: Expectation, named: list[tuple[PlannedThread, ThreadFigures]]) -> list[tuple[PlannedThread, ThreadFigures]]:
    """The threads `exp` names that it judges (docs/scenarios.md, "Expectations and validation").

    The runner's own threads are known from the file: of those it names, the ones that cannot
    have the figure are left out when another can (a ROS process names its helper threads after
    itself: `minimal_schedul`'s latency is its periodic main thread's), as validation showed.  A
    program's threads are known only as the cell runs: each one named is judged, and one that
    cannot have the figure fails `not measured` rather than drop out of the verdicts.
    """
    fig = metric_figure(exp.metric)
    own = [(p, f) for p, f in named if p.origin != PROGRAM_ORIGIN]
    if not any(has(thread_kind(p), fig) for p, _ in own):
        return named
    return [(p, f) for p, f in named if p.origin == PROGRAM_ORIGIN or has(thread_kind(p), fig)]


def judged(exp: Expectation, planned: PlannedThread, figs: ThreadFigures, processes: int, trace: TraceInfo) -> Verdict:
    """`exp` on one thread it names: checked against its figures, or failed `not measured` saying why.

    A thread of a kind that cannot have the figure (a program's thread asked for a latency, a
    thread without callbacks for a per-callback figure) fails, never drops out of the verdicts;
    so does one whose figure comes from the scheduler trace when the trace did not run or did
    not see it, with the trace's own reason (--no-trace, no tracefs).
    """
    label = verdict_label(planned, processes)
    fig = metric_figure(exp.metric)
    kind = thread_kind(planned)
    if not has(kind, fig):
        return Verdict(
            thread=label,
            metric=fig.name,
            limit=exp.describe_limit(),
            measured=None,
            passed=False,
            note=f"not measured ({fig.name} {measured_how(fig)}; this is {kind.words})",
        )
    absent = ""
    if fig.in_trace and (fig.traced or not kind.proc):  # this thread can have it from the scheduler trace alone
        absent = f"the scheduler trace did not run: {trace.reason}" if not trace.enabled else "the scheduler trace did not see it run"
    return check(exp, label, figs, absent)


def _unchecked(exp: Expectation, folded: list[tuple[PlannedThread, int]], unnamed: list[tuple[str, int]], cap: int) -> str:
    """Why threads an expectation names were not checked, in words: they exited beyond a program's cap of thread records
    and were folded into counts; "" when none were.

    A folded thread's figures are not kept, so an expectation cannot be checked on it: a
    cell must neither pass on the kept threads of a name alone nor say none of it ran.
    """
    matched = {id(t) for t in match_threads([planned for planned, _ in folded], exp.thread)}
    count = sum(n for planned, n in folded if id(planned) in matched)
    records = f"beyond {cap:,} thread records"
    if count:
        were = "threads of that name were" if count != 1 else "thread of that name was"
        return f"{count} {were} folded ({records}) and not checked"
    process, sep, _ = exp.thread.rpartition("/")
    maybe = sum(n for program, n in unnamed if not sep or program == process)
    if maybe:
        return (
            f"{maybe} folded thread{'s' if maybe != 1 else ''} ({records}) whose names were not kept may be of that name, "
            "and were not checked"
        )
    return ""


def evaluate(cell: ResolvedCell, scenario: Scenario, raw: RawCell, allow_degraded: bool, allow_priority_99: bool = False) -> CellResult:
    """Decide what one cell run means: figures per thread, verdicts, degradations, status and reason.

    `allow_priority_99`: the run allowed RT priority 99, so a program that raised a thread there is a warning, not an error.
    """
    result = CellResult(
        id=cell.id,
        matrix=dict(cell.matrix),
        spec_hash=cell.spec_hash,
        status=Status.PASSED,
        spec=spec_json(cell.scenario),
        started_at=raw.started_at,
    )
    measured: list[tuple[PlannedThread, ThreadFigures]] = []
    names = {gid: verdict_label(t.planned, raw.processes) for gid, t in enumerate(raw.threads)}
    admission = programs.deadline_admission(scenario, raw.rt_limit_us[0], raw.rt_limit_us[1], len(raw.online_cpus))
    stalls = [] if raw.interrupted else programs.stalls(raw.threads, raw.timeline.end_ns, names)
    consumers = queue_consumers(raw)
    # A queue's drops are the missed releases of the one stage that takes from it; a pool's are the pool's (pool_verdicts).
    sole = {r.name: r for r in raw.resources if len(consumers.get(r.name, ())) == 1}  # the queues one stage takes from
    spawned: dict[str, bool] = {}  # spawned thread, as `process/name`: whether any instance ran
    for t in raw.threads:
        p = t.planned
        if p.spawned:
            where = f"{p.process}[{p.instance}]" if raw.processes > 1 else p.process
            key = f"{where}/{p.spec_name}"
            spawned[key] = spawned.get(key, False) or bool(t.slot.tid)
            if not t.slot.tid:  # an instance no spawn event created: nothing ran, nothing to measure
                continue
        fig = _figures(t, raw.timeline, raw.interrupted, scenario.latency_bound)
        degraded = degradation(p.settings, t.applied, t.errors, admission) if t.ready else []
        events: list[EventResult] = []
        phases: list[PhaseResult] = []
        if isinstance(p.work, PhasesWork):
            events, phases, extra = programs.program_results(p.work, t.slot, p.settings, names, raw.online_cpus)
            fig = fig.model_copy(update=extra)
            if p.released:  # its releases are the resumes it took, and those it missed: dropped, or left waiting at the end
                queues = [sole[q] for q in p.work.suspends_on() if q in sole]
                missed = sum(r.dropped + (0 if raw.interrupted else left_behind(r, raw)) for r in queues)
                fig = fig.model_copy(update={"missed_releases": missed, "releases": fig.callbacks + missed})
            degraded += [f"phase {ph.name}: {d}" for ph in phases for d in ph.degraded]
        result.threads.append(
            ThreadResult(
                process=p.process,
                instance=p.instance,
                index=p.index,
                name=p.name,
                pid=t.pid,
                tid=t.slot.tid,
                work=describe_work(p.work),
                periodic=p.periodic,
                released=p.released,
                requested=p.settings,
                applied=t.applied,
                degraded=degraded,
                figures=fig,
                histograms=_histograms(t.slot),
                samples_written=t.samples_written,
                samples_lost=t.samples_lost,
                events=events,
                phases=phases,
                spawned=p.spawned,
                began_ns=t.slot.work_start_ns - raw.timeline.start_ns if t.slot.work_start_ns and raw.timeline.start_ns else None,
            )
        )
        measured.append((p, fig))
    program_failures: list[str] = []
    program_warnings: list[str] = []
    before_start = ""  # why the cell stopped before its start gate, for the programs it left there
    if raw.timeline.start_ns is None:
        before_start = "the run was interrupted" if raw.interrupted else (raw.failures[0] if raw.failures else "")
    folded: list[tuple[PlannedThread, int]] = []  # programs' threads folded beyond their cap, by name: never checked
    unnamed: list[tuple[str, int]] = []  # (program, folded threads whose names were not kept)
    cap = 0
    for prog in raw.programs:
        end = raw.timeline.stopped_ns or raw.timeline.ended_ns
        out = outside.outcome(prog, raw.timeline.start_ns, end, raw.interrupted, degradation, before_start, allow_priority_99)
        folded += out.folded
        if out.folded_unnamed:
            unnamed.append((prog.spec.name, out.folded_unnamed))
        cap = max(cap, out.folded_cap)
        result.programs.append(out.result)
        result.threads.extend(t for _, t in out.threads)
        measured.extend((planned, t.figures) for planned, t in out.threads)
        program_failures += out.failures
        program_warnings += out.warnings
    result.threads, result.trace = traced.apply(result.threads, raw.trace, raw.trace_tasks, raw.timeline.start_ns)
    measured = [(planned, t.figures) for (planned, _), t in zip(measured, result.threads)]
    ros = _callbacks(raw, result)
    for i in expectations_for(scenario, cell.matrix):
        exp = scenario.expect[i]
        mark = cell.expect_marks[i] if i < len(cell.expect_marks) else None
        if exp.callback:
            for verdict in callbacks.judge(exp, result.callbacks, ros):
                if mark is not None:
                    verdict.line, verdict.col = mark.line, mark.col
                result.expectations.append(verdict)
            continue
        targets = {id(t) for t in match_threads([planned for planned, _ in measured], exp.thread)}
        unchecked = _unchecked(exp, folded, unnamed, cap)
        if (not targets and raw.programs and not raw.interrupted) or unchecked:
            # a program's thread that never appeared, or threads of that name folded unchecked: never a silent pass
            if not targets:
                why = unchecked or "no thread of that name ran"
            else:
                why = f"{unchecked}; the verdicts of the kept threads of that name do not speak for them"
            verdict = Verdict(
                thread=exp.thread,
                metric=exp.metric.value,
                limit=exp.describe_limit(),
                measured=None,
                passed=False,
                note=f"not measured ({why})",
            )
            if mark is not None:
                verdict.line, verdict.col = mark.line, mark.col
            result.expectations.append(verdict)
        for planned, fig in judged_threads(exp, [(planned, fig) for planned, fig in measured if id(planned) in targets]):
            verdict = judged(exp, planned, fig, raw.processes, result.trace)
            if mark is not None:  # where the expectation is written: CI annotations point there
                verdict.line, verdict.col = mark.line, mark.col
            result.expectations.append(verdict)
    own = [scenario.expect[i] for i in expectations_for(scenario, cell.matrix)]
    implicit = keeps_up(measured, own, raw, frozenset(no_release_due(raw))) + pool_verdicts(raw, consumers, own)
    implicit += callbacks_keep_up(result.callbacks, own)
    result.expectations += implicit
    result.thread_table = ps_rows(raw.table)
    result.background = [
        Background(kind=BackgroundKind.HOG, name=b.name, pid=b.pid)
        if b.kind == "hog"
        else Background(
            kind=BackgroundKind.COMMAND,
            name=b.name,  # the scenario's name: for it (else the program's)
            argv=list(b.argv),
            pid=b.pid,
            log=b.log or None,
            output_bytes=b.output.written if b.output else None,
            output_dropped=b.output.dropped if b.output else None,
        )
        for b in raw.background
    ]
    result.duration_ns = raw.timeline.ended_ns - raw.timeline.began_ns
    result.overhead_ns = _overhead(raw)
    result.warnings = (
        warnings(result.threads, raw.processes, frozenset(v.thread for v in implicit))
        + [
            f"queue {r.name}: {r.dropped:,} resumes were dropped, each when {QUEUE_DEPTH} were queued already that no "
            "thread suspending on it had taken; chain figures cover the activations that ran"
            for r in raw.resources
            if r.dropped
        ]
        + [lost_words(r) for r in raw.resources if r.lost]
        + [
            f"{r.kind} {r.name}: {r.owner_died:,} time{'s' if r.owner_died != 1 else ''} a thread found its mutex held by a thread"
            " that had died holding it (its process was killed or crashed), and took it over; what that holder was doing"
            " was left unfinished"
            for r in raw.resources
            if r.owner_died
        ]
        + spawn_warnings(result.threads, [k for k, ran in spawned.items() if not ran], raw.processes)
        + [f"{p.spec.name}: {words}" for p in raw.programs if p.callbacks is not None for words in callbacks.loss_words(p.callbacks)]
        + [
            f"callback {r.label} could not keep up: {behind(r.figures)}"
            for r in result.callbacks
            if (r.figures.missed_releases or r.figures.overruns) and r.label not in {v.thread for v in implicit}
        ]
        + program_warnings
        + traced.warnings(result.trace)
        + [
            f"{label} was released {units.human_duration(late)} after the common start (the runner's start margin was too short):"
            " its threads' first releases were late by the runner's doing, not the scheduler's"
            for label, late in raw.released_late
        ]
        + [
            w
            for b in raw.background
            if b.output is not None
            for w in outside.output_warnings(f"background command {b.name}", "its log", b.log, b.output, "the limit of a command's log")
        ]
        + [
            f"background {label} began its load {units.human_duration(late)} after the common start (the runner's start margin"
            " was too short): the cell's first moments ran without it"
            for label, late in raw.load_late
        ]
    )
    if stalls:
        stalls.insert(0, "threads were stuck at the end of the run (a deadlock, or a release that never came)")
    result.status, result.reason = status(result, raw, allow_degraded, stalls, program_failures)
    return result


def _callbacks(raw: RawCell, result: CellResult) -> dict[str, RosCaptureInfo]:
    """The ROS 2 callbacks of the cell's programs into `result` (and what each capture said into its program's record).

    A program's callbacks count to the end of the measured work (to the interrupt, or to its own exit if earlier): the
    releases of a timer after it are missed ones.
    """
    tl = raw.timeline
    end = (tl.stopped_ns if raw.interrupted and tl.stopped_ns else tl.end_ns) or tl.ended_ns
    captures = [
        callbacks.ProgramCapture(p.spec.name, p.callbacks, min(end, p.exited_ns) if p.exited_ns else end)
        for p in raw.programs
        if p.callbacks is not None
    ]
    if not captures:
        return {}
    result.callbacks, infos = callbacks.cell_callbacks(captures, tl.start_ns or tl.began_ns)
    for prog in result.programs:
        if prog.name in infos:
            prog.ros = infos[prog.name]
    return infos


def status(
    result: CellResult, raw: RawCell, allow_degraded: bool, stalls: Optional[list[str]] = None, programs: Optional[list[str]] = None
) -> tuple[Status, str]:
    """The cell's status and the reason given for it, most severe first.

    Interrupted beats everything (the figures are partial); a failure of the run itself (a
    worker that died, the watchdog, background load that ended, a stopped process) is an
    error; then failed expectations; then settings that were not applied, which are an error
    unless the user allowed degraded runs.
    """
    reasons = (
        list(raw.failures)
        + list(raw.incidents)
        + list(programs or [])
        + ([": ".join([stalls[0], "; ".join(stalls[1:])])] if stalls else [])
    )
    statuses = []
    if raw.interrupted:
        statuses.append(Status.INTERRUPTED)
        reasons = [INTERRUPTED_REASON]
    elif reasons:
        statuses.append(Status.ERROR)
    if any(not v.passed for v in result.expectations):
        statuses.append(Status.FAILED)
    if any(t.degraded for t in result.threads):
        statuses.append(Status.DEGRADED if allow_degraded else Status.ERROR)
        if not allow_degraded and not reasons:
            reasons = [
                "settings were not applied as requested: "
                + "; ".join(f"{t.process}/{t.name}: {', '.join(t.degraded)}" for t in result.threads if t.degraded)
            ]
    return worst(statuses), "; ".join(reasons)


def with_write_error(result: CellResult, path: str, error: OSError) -> CellResult:
    """The result of a cell whose samples could not be stored: an error, its figures kept."""
    note = f"the samples could not be written to {path}: {error.strerror or error}; the figures above are complete"
    result.status = worst([result.status, Status.ERROR])
    result.reason = f"{result.reason}; {note}" if result.reason else note
    result.samples_file = None
    result.unwritten = True
    return result


def unrun(cell: ResolvedCell, reason: str, started_at: str) -> CellResult:
    """The record of a cell that could not even start (its files could not be created)."""
    return CellResult(
        id=cell.id,
        matrix=dict(cell.matrix),
        spec_hash=cell.spec_hash,
        status=Status.ERROR,
        spec=spec_json(cell.scenario),
        reason=reason,
        unwritten=True,
        started_at=started_at,
    )
