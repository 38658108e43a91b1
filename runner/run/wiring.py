"""The scenario as the native core takes it: pure translation of the planned threads into worker specs and tuples.

Nothing here starts a process or reads the machine: the CPUs a worker may use are given
(`all_cpus`), so every spec and tuple a cell's workers are told can be checked without
real-time rights.  `spawn` starts the workers with them; `worker` hands them to `_probe`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

from runner.run import _probe, samples
from runner.run.external import sched_json
from runner.scenario import program as programs
from runner.scenario.model import (
    BurnClock,
    EventKind,
    HogKind,
    Overrun,
    Pending,
    PeriodicWork,
    PhasesWork,
    Protocol,
    Resource,
    ResourceKind,
    Samples,
    SamplesMode,
    Scenario,
    SleepWork,
    SpinWork,
    Start,
    Wait,
    Work,
)
from runner.scenario.plan import PlannedThread

RING_MAX = 1 << 17  # samples per thread's ring at most (8 MiB): 1.3 s of a 10 us period
RING_SECONDS = 2  # otherwise, the ring holds this long of callbacks: the runner drains it five times a second
_RING_MODES = {SamplesMode.ALL: _probe.RING_ALL, SamplesMode.LAST: _probe.RING_ALL, SamplesMode.OUTLIERS: _probe.RING_OUTLIERS}


# The native core's code of each event kind, by name (records.h's EVENT_KINDS): a kind without one fails at import.
_EVENT_TYPES = {kind: _probe.EVENT_KINDS[kind.name] for kind in EventKind}
_RESOURCE_KINDS = {
    ResourceKind.MUTEX: _probe.RES_MUTEX,
    ResourceKind.COND: _probe.RES_COND,
    ResourceKind.BARRIER: _probe.RES_BARRIER,
    ResourceKind.QUEUE: _probe.RES_QUEUE,
    ResourceKind.TIMER: _probe.RES_TIMER,
}
_OVERRUN = {Overrun.SKIP: _probe.OVR_SKIP, Overrun.REBASE: _probe.OVR_REBASE, Overrun.CATCHUP: _probe.OVR_CATCHUP}


def resource_specs(scenario: Scenario) -> list[tuple[int, int, int, int]]:
    """The native core's (kind, protocol, parties, period_ns) of each declared resource, in declaration order; a queue's
    protocol says what becomes of a resume no thread waits for."""
    parties = programs.barrier_parties(scenario.processes)
    return [(_RESOURCE_KINDS[r.kind], _protocol(r), parties.get(name, 0), r.period or 0) for name, r in scenario.resources.items()]


def _protocol(r: Resource) -> int:
    if r.kind is ResourceKind.QUEUE:
        return _probe.QUEUE_DROP if r.pending is Pending.DROP else _probe.QUEUE_KEEP
    return 1 if r.protocol is Protocol.INHERIT else 0


def program_tuple(work: PhasesWork, gid: int, scenario: Scenario, templates: Optional[dict[str, tuple[int, int]]] = None) -> _probe.Program:
    """A program as the native core takes it: resources by their index in the scenario's declaration.

    `templates` gives, per thread name a spawn event names, the slot of its first instance in the
    process and how many instances it has (the spawn event's resource and value).
    """
    index = {name: i for i, name in enumerate(scenario.resources)}
    slots = lock_slots(work)
    events: list[tuple[int, int, int, int, int]] = []
    phases: list[tuple[int, int, int, Optional[_probe.PhaseSettings]]] = []
    for phase in work.phases:
        first = len(events)
        for e in phase.events:
            res = res2 = -1
            mode, arg = _probe.OVR_SKIP, e.duration or e.size or 0
            if e.event is EventKind.WAIT:
                res, res2 = index[e.cond or ""], index[e.mutex or ""]
            elif e.event is EventKind.TIMER:
                named = scenario.resources.get(e.timer or "")
                res = index[e.timer] if e.timer is not None else -1
                arg = named.period or 0 if named is not None else e.period or 0
                overrun = named.overrun if named is not None else (e.overrun or Overrun.SKIP)
                mode = _OVERRUN[overrun]
            elif e.event is EventKind.SPAWN:
                res, arg = (templates or {})[e.thread or ""]
            elif e.resource is not None:
                res = index[e.resource]
                if e.event is EventKind.LOCK:
                    res2 = slots.index(e.resource) if e.resource in slots else -1
            events.append((_EVENT_TYPES[e.event], res, res2, mode, arg))
        settings = None
        if phase.sched is not None or phase.cpus is not None:
            sched = sched_json(phase.sched)
            policy, priority, nice, extra = sched if sched else (None, None, None, None)
            settings = (policy, priority, nice, list(phase.cpus) if phase.cpus else None, extra)
        phases.append((phase.loop, first, len(events) - first, settings))
    return (gid, work.delay, work.loop, work.buffer_bytes(), tuple(phases), tuple(events))


def work_tuple(
    work: Work, bound_ns: int = 0, samples: Optional[Samples] = None, program: Optional[_probe.Program] = None
) -> _probe.WorkTuple:
    """The native core's (kind, period_ns, burn_ns, burn_wall, alloc_bytes, offset_ns, wait_spin, bound_ns, ring_mode[, program])."""
    ring = _RING_MODES.get(samples.mode, _probe.RING_NONE) if samples else _probe.RING_ALL
    if isinstance(work, PhasesWork):
        assert program is not None, "a program's work needs its program tuple"
        return (_probe.WORK_PROGRAM, 0, 0, False, 0, 0, False, bound_ns, ring, program)
    if isinstance(work, PeriodicWork):
        return (
            _probe.WORK_PERIODIC,
            work.period,
            work.burn,
            work.burn_clock is BurnClock.WALL,
            work.alloc,
            work.offset,
            work.wait is Wait.SPIN,
            bound_ns,
            ring,
        )
    if isinstance(work, SpinWork):
        return (_probe.WORK_SPIN, 0, 0, False, 0, 0, False, 0, _probe.RING_NONE)
    return (_probe.WORK_SLEEP, 0, 0, False, 0, 0, False, 0, _probe.RING_NONE)


def worker_layout(threads: list[PlannedThread], duration_ns: int, policy: Samples) -> samples.Layout:
    """The shared buffer of one worker process: a slot per thread, its ring, and room for its programs' stats and lock slots."""
    events, phases = program_sizes(threads)
    return samples.Layout(
        len(threads),
        ring_capacity(threads, duration_ns, policy),
        events=events,
        phases=phases,
        locks=max((len(lock_slots(t.work)) for t in threads), default=0),
    )


def ring_capacity(threads: list[PlannedThread], duration_ns: int, policy: Samples) -> int:
    """Samples each thread's ring holds: the whole cell when that is small, else enough for the runner to drain in time."""
    periods = [t.period for t in threads if t.period]
    if not any(t.has_callbacks for t in threads) or policy.mode is SamplesMode.NONE:
        return 0
    if policy.mode is SamplesMode.LAST:
        return policy.last or 0
    if not periods:  # only stages released by resumes, at whatever rate their producers set
        return min(RING_MAX, max(4096, RING_SECONDS * 1000))
    rate = max(1_000_000_000 // p for p in periods)  # callbacks per second of the fastest thread
    return min(RING_MAX, max(duration_ns // p + 16 for p in periods), max(4096, RING_SECONDS * rate))


def process_spec(
    threads: list[PlannedThread], scenario: Scenario, layout: samples.Layout, gids: dict[int, int], all_cpus: tuple[int, ...]
) -> dict[str, Any]:
    """What one worker process is told to create, its buffer sized as `layout`; `gids` numbers every thread of the cell (by id),
    `all_cpus` are the CPUs the runner may use (what a thread without `cpus` is given)."""
    proc = next(p for p in scenario.workers if p.name == threads[0].process)
    mem = proc.memory
    bound = scenario.latency_bound or 0
    by_index = {t.index: t for t in threads}
    templates: dict[str, tuple[int, int]] = {}
    for t in threads:
        if t.spawned and t.spec_name not in templates:
            templates[t.spec_name] = (t.index, sum(1 for u in threads if u.spec_name == t.spec_name and u.index > 0))

    def work(w: Work, index: int) -> _probe.WorkTuple:
        program = program_tuple(w, gids[id(by_index[index])], scenario, templates) if isinstance(w, PhasesWork) else None
        return work_tuple(w, bound, scenario.samples, program)

    members = [(spec, member) for spec in proc.threads for member in spec.members()]
    after = start_after([spec.spawned for spec, _ in members]) if proc.start is Start.IN_ORDER else {}

    return {
        "comm": proc.name,
        "capacity": layout.capacity,
        "all_cpus": all_cpus,
        "reset_on_fork": proc.reset_on_fork,
        "memory": {"lock": mem.lock, "prealloc": mem.prealloc, "stack_size": mem.stack_size},
        "main": {
            "name": proc.main_name,
            "apply": proc.main.apply.value,
            "sched": sched_json(proc.main.sched),
            "cpus": list(proc.main.cpus) if proc.main.cpus else None,
            "work": work(proc.main.work, 0),
        },
        "threads": [
            {
                "name": member.name,
                "explicit": not spec.inherit,
                "spawned": spec.spawned,
                "sched": sched_json(member.sched),
                "cpus": list(member.cpus) if member.cpus else None,
                "work": work(member.work, index),
                "after": after.get(index, -1),
            }
            for index, (spec, member) in enumerate(members, start=1)  # pin: each, priospread and distance give each its own settings
        ],
        "events": layout.events,
        "phases": layout.phases,
        "locks": layout.locks,
    }


def start_after(spawned: list[bool]) -> dict[int, int]:
    """`start: in_order`: the slot each thread begins after (slot numbers from 1, the main thread's 0 aside), by its slot:
    the thread listed before it that starts with the cell; spawned threads begin when a spawn creates them."""
    out: dict[int, int] = {}
    last = -1
    for index, mid_run in enumerate(spawned, start=1):
        if mid_run:
            continue
        if last >= 0:
            out[index] = last
        last = index
    return out


def lock_slots(work: Work) -> tuple[str, ...]:
    """The mutexes whose waits each of the thread's activations keeps apart (its first MAX_LOCK_SLOTS), in slot order."""
    return work.locked_mutexes()[: _probe.MAX_LOCK_SLOTS] if isinstance(work, PhasesWork) else ()


def program_sizes(threads: list[PlannedThread]) -> tuple[int, int]:
    """Event stats (events plus the chain entry) and phase stats each slot of a worker holds: its longest program's."""
    works = [t.work for t in threads if isinstance(t.work, PhasesWork)]
    if not works:
        return 0, 0
    spawned = any(t.spawned for t in threads)  # one more phase record: a spawned thread's settings as it started
    return max(len(w.events()) for w in works) + 1, max(len(w.phases) for w in works) + spawned


@dataclass(frozen=True)
class HogSpec:
    """One process of background load as its worker is told it: `label` in words, its log's file name in the cell's folder."""

    label: str
    spec: dict[str, Any]
    layout: samples.Layout
    log_name: str


def hog_specs(scenario: Scenario, all_cpus: tuple[int, ...]) -> list[HogSpec]:
    """Background hogs as worker processes: one spinning process each, or one process of spinning threads (its main asleep)."""
    out: list[HogSpec] = []
    spin = work_tuple(SpinWork())
    for h, hog in enumerate(scenario.background.hogs):
        as_processes = hog.kind is HogKind.PROCESS
        copies, threads = (hog.count, 0) if as_processes else (1, hog.count)
        for i in range(copies):
            spec = {
                "comm": hog.name,
                "capacity": 0,
                "all_cpus": all_cpus,
                "histograms": False,
                "memory": {},
                "main": {
                    "name": hog.name,
                    "apply": "before_threads",
                    "sched": sched_json(hog.sched),
                    "cpus": list(hog.cpus) if hog.cpus else None,
                    "work": spin if as_processes else work_tuple(SleepWork()),
                },
                "threads": [{"name": hog.name, "work": spin} for _ in range(threads)],
            }
            layout = samples.Layout(1 + threads, 0, histograms=False)
            out.append(HogSpec(f"hog {hog.name}[{i}]", spec, layout, f"hog{h}-{i}.log"))
    return out
