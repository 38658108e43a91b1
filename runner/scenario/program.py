"""Rules of programs (`kind: phases`) that span threads: resource references, barrier parties, deadline threads.

Pure.  The models check each thread's program on its own (events complete, locks
balanced within a phase); what needs the whole scenario is here: every name an
event uses is declared in `resources` with the right kind, a barrier has the two
or more parties it counts, every queue a thread suspends on is resumed by some
thread, every condition waited on is signalled, every spawn names a thread of its
process declared `spawned: true` that some thread started at the start can reach,
and SCHED_DEADLINE threads keep the kernel's rules (no affinity subset, no thread
creation).  The loader turns the findings into located problems, all at once.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Optional, Union

from runner import units
from runner.errors import did_you_mean
from runner.scenario.model import (
    AnyProcess,
    ApplyWhen,
    EventKind,
    PeriodicWork,
    PhasesWork,
    Policy,
    ProcessSpec,
    Resource,
    ResourceKind,
    Scenario,
    Sched,
)

Path = tuple[Union[str, int], ...]


def _programs(processes: list[AnyProcess]) -> Iterator[tuple[Path, PhasesWork, int]]:
    """Every program with its path and how many threads run it (count times instances)."""
    for i, proc in enumerate(processes):
        if not isinstance(proc, ProcessSpec):
            continue
        if isinstance(proc.main.work, PhasesWork):
            yield ("processes", i, "main", "work"), proc.main.work, proc.instances
        for j, spec in enumerate(proc.threads):
            if isinstance(spec.work, PhasesWork):
                yield ("processes", i, "threads", j, "work"), spec.work, spec.count * proc.instances


def barrier_parties(processes: list[AnyProcess]) -> dict[str, int]:
    """Threads that pass each barrier: every thread whose program names it, each copy counted."""
    out: dict[str, int] = {}
    for _, work, copies in _programs(processes):
        for name in {e.resource for _, e in work.events() if e.event is EventKind.BARRIER}:
            out[name or ""] = out.get(name or "", 0) + copies
    return out


def reference_problems(processes: list[AnyProcess], resources: dict[str, Resource]) -> list[tuple[Path, str]]:
    """Every event naming an undeclared resource or one of the wrong kind, and objects nobody could ever release."""
    out: list[tuple[Path, str]] = []
    used: dict[EventKind, set[str]] = {}
    declared = sorted(resources)
    for path, work, _ in _programs(processes):
        for k, phase in enumerate(work.phases):
            for e, event in enumerate(phase.events):
                where = path + ("phases", k, "events", e)
                used.setdefault(event.event, set()).update(n for n, _ in event.names())
                for name, wanted in event.names():
                    res = resources.get(name)
                    if res is None:
                        hint = did_you_mean(name, declared) or f"; declare it: resources: {{{name}: {{kind: {wanted.value}}}}}"
                        out.append((where, f"{event.event.value} names {name!r}, which resources does not declare{hint}"))
                    elif res.kind is not wanted:
                        out.append((where, f"{event.event.value} needs a {wanted.value}, but {name!r} is a {res.kind.value}"))
    for name, parties in barrier_parties(processes).items():
        if name in resources and parties < 2:
            out.append((("resources", name), f"barrier {name!r} is passed by {parties} thread; a barrier needs two or more"))
    for name in sorted(used.get(EventKind.SUSPEND, set()) - used.get(EventKind.RESUME, set())):
        if name in resources and resources[name].kind is ResourceKind.QUEUE:
            out.append(
                (("resources", name), f"threads suspend on queue {name!r} but no thread resumes it; they would wait for the whole run")
            )
    for name in sorted(used.get(EventKind.RESUME, set()) - used.get(EventKind.SUSPEND, set())):
        if name in resources and resources[name].kind is ResourceKind.QUEUE:
            out.append((("resources", name), f"threads resume queue {name!r} but no thread suspends on it; every resume would be dropped"))
    waited = used.get(EventKind.WAIT, set()) & {n for n, r in resources.items() if r.kind is ResourceKind.COND}
    for name in sorted(waited - used.get(EventKind.SIGNAL, set()) - used.get(EventKind.BROADCAST, set())):
        out.append((("resources", name), f"threads wait on cond {name!r} but no thread signals or broadcasts it"))
    return out


def never_released(processes: list[AnyProcess], duration_ns: int) -> list[tuple[Path, str]]:
    """Threads whose first release (a periodic `offset`, a program's `delay`) is not before the cell ends.

    Such a thread runs no callback, misses nothing and fails no check: its cell would pass with
    nothing measured of it.  `duration_ns` is the cell's (the file's, or --duration).
    """
    out: list[tuple[Path, str]] = []
    for i, proc in enumerate(processes):
        if not isinstance(proc, ProcessSpec):
            continue
        works: list[tuple[Path, object]] = [(("processes", i, "main", "work"), proc.main.work)]
        works += [(("processes", i, "threads", j, "work"), t.work) for j, t in enumerate(proc.threads)]
        for path, work in works:
            key, wait = ("offset", work.offset) if isinstance(work, PeriodicWork) else ("delay", getattr(work, "delay", 0))
            if wait and wait >= duration_ns:
                shown, cell = units.format_duration(wait), units.format_duration(duration_ns)
                why = f"{key} {shown} is not before the cell ends ({cell}): the thread would never be released, and nothing measured"
                out.append((path + (key,), why))
    return out


def deadline_problems(processes: list[AnyProcess]) -> list[tuple[Path, str]]:
    """SCHED_DEADLINE rules the kernel enforces: full affinity, and no threads created by a deadline thread."""
    out: list[tuple[Path, str]] = []
    why_cpus = (
        "a SCHED_DEADLINE thread must be allowed on every CPU of its root domain (the kernel refuses the policy or the "
        "affinity otherwise); remove cpus, or run it in an exclusive cpuset"
    )

    def deadline(sched: Sched | None) -> bool:
        return sched is not None and sched.policy is Policy.DEADLINE

    def check(path: Path, sched: Sched | None, cpus: object, work: object) -> None:
        if deadline(sched) and cpus is not None:
            out.append((path + ("cpus",), why_cpus))
        if isinstance(work, PhasesWork) and (deadline(sched) or any(deadline(p.sched) for p in work.phases)):
            for k, phase in enumerate(work.phases):  # the thread is deadline, or turns deadline in some phase
                if phase.cpus is not None:
                    out.append((path + ("work", "phases", k, "cpus"), why_cpus))

    for i, proc in enumerate(processes):
        if not isinstance(proc, ProcessSpec):
            continue
        main = proc.main
        check(("processes", i, "main"), main.sched, main.cpus, main.work)
        if main.sched is not None and main.sched.policy is Policy.DEADLINE and proc.threads and main.apply is ApplyWhen.BEFORE_THREADS:
            out.append(
                (
                    ("processes", i, "main", "sched"),
                    "a SCHED_DEADLINE thread cannot create threads (the kernel refuses the clone); use apply: after_threads",
                )
            )
        for j, spec in enumerate(proc.threads):
            check(("processes", i, "threads", j), spec.sched, spec.cpus, spec.work)
    return out


def deadline_asks(scenario: Scenario) -> list[tuple[str, float]]:
    """The SCHED_DEADLINE bandwidth (runtime/period, in CPUs) each thread of the cell asks the kernel to admit.

    A thread counts once, at the most it asks (its own sched, or a phase's): the kernel holds one
    reservation per thread.  Programs the user started are not counted (their own doing).
    """
    asks: list[tuple[str, float]] = []

    def most(scheds: list[Sched | None]) -> float:
        return max((s.bandwidth for s in scheds if s is not None and s.policy is Policy.DEADLINE), default=0.0)

    for proc in scenario.workers:
        main_work = proc.main.work
        main = most([proc.main.sched, *(p.sched for p in main_work.phases)] if isinstance(main_work, PhasesWork) else [proc.main.sched])
        per_instance = [(proc.name, main)] if main else []
        for spec in proc.threads:
            phases = [p.sched for p in spec.work.phases] if isinstance(spec.work, PhasesWork) else []
            if b := most([spec.sched, *phases]):
                per_instance += [(spec.name, b)] * spec.count
        asks += per_instance * proc.instances
    return asks


def asked_words(asks: list[tuple[str, float]]) -> str:
    """`2.70 CPUs of bandwidth (greedy 0.90, greedy 0.90, greedy 0.90)`: what deadline_asks asks, in words."""
    parts = ", ".join(f"{name} {b:.2f}" for name, b in asks[:6]) + (", ..." if len(asks) > 6 else "")
    return f"{sum(b for _, b in asks):.2f} CPUs of bandwidth ({parts})"


def admitted_words(rt_runtime_us: int, rt_period_us: int, cpus: int) -> str:
    """`at most 0.95 per CPU x 2 CPUs = 1.90 (sched_rt_runtime_us 950000 / sched_rt_period_us 1000000)`."""
    share = rt_runtime_us / rt_period_us
    return (
        f"at most {share:.2f} per CPU x {cpus} CPUs = {share * cpus:.2f} "
        f"(sched_rt_runtime_us {rt_runtime_us} / sched_rt_period_us {rt_period_us})"
    )


@dataclass(frozen=True)
class SpawnSite:
    """Where a spawn event stands: the spawning thread spec (None: the main thread), its phase, the event's path."""

    spawner: Optional[int]  # index in the process's threads; None for the main thread
    phase: int
    path: Path


def spawn_sites(proc: ProcessSpec, i: int) -> dict[str, list[SpawnSite]]:
    """The spawn events of one process (index i in the scenario), by the thread name they spawn."""
    out: dict[str, list[SpawnSite]] = {}
    works: list[tuple[Optional[int], Path, object]] = [(None, ("processes", i, "main", "work"), proc.main.work)]
    works += [(j, ("processes", i, "threads", j, "work"), spec.work) for j, spec in enumerate(proc.threads)]
    for spawner, path, work in works:
        if not isinstance(work, PhasesWork):
            continue
        for k, phase in enumerate(work.phases):
            for e, event in enumerate(phase.events):
                if event.event is EventKind.SPAWN:
                    site = SpawnSite(spawner, k, path + ("phases", k, "events", e))
                    out.setdefault(event.thread or "", []).append(site)
    return out


def spawn_problems(processes: list[AnyProcess]) -> list[tuple[Path, str]]:
    """Spawns that name no spawnable thread of their process, spawned threads nothing starts, and deadline spawners."""
    out: list[tuple[Path, str]] = []
    for i, proc in enumerate(processes):
        if not isinstance(proc, ProcessSpec):
            continue
        sites = spawn_sites(proc, i)
        specs = {spec.name: (j, spec) for j, spec in enumerate(proc.threads)}
        for name, found in sites.items():
            if name not in specs:
                hint = did_you_mean(name, sorted(specs)) or ""
                for site in found:
                    out.append((site.path, f"spawn names {name!r}, which is not a thread of process {proc.name!r}{hint}"))
            elif not specs[name][1].spawned:
                for site in found:
                    out.append(
                        (site.path, f"thread {name!r} is created at the start; declare it spawned: true to have spawn events create it")
                    )
        reached = _reachable(proc, sites)
        for j, spec in enumerate(proc.threads):
            if not spec.spawned:
                continue
            where = ("processes", i, "threads", j, "spawned")
            if spec.name not in sites:
                out.append((where, f"thread {spec.name!r} is spawned: true but no spawn event of process {proc.name!r} names it"))
            elif j not in reached:
                out.append((where, f"thread {spec.name!r} is spawned only by spawned threads that nothing started creates"))
            elif spec.inherit and (spec.sched is None or spec.cpus is None):
                origins = {(site.spawner, site.phase) for site in sites[spec.name]}
                if len(origins) > 1:
                    out.append(
                        (
                            where,
                            f"thread {spec.name!r} inherits its settings from whoever spawns it, and it is spawned from "
                            f"{len(origins)} places whose settings may differ; give it its own sched and cpus, or inherit: false",
                        )
                    )
        for found in sites.values():
            for site in found:
                sched = _spawner_sched(proc, site)
                if sched is not None and sched.policy is Policy.DEADLINE:
                    out.append((site.path, "a SCHED_DEADLINE thread cannot create threads (the kernel refuses the clone)"))
    return out


def _reachable(proc: ProcessSpec, sites: dict[str, list[SpawnSite]]) -> set[int]:
    """Indexes of spawned thread specs that a chain of spawns from a thread started at the start reaches."""
    index = {spec.name: j for j, spec in enumerate(proc.threads)}
    reached: set[int] = set()
    grew = True
    while grew:
        grew = False
        for name, found in sites.items():
            j = index.get(name)
            if j is None or j in reached or not proc.threads[j].spawned:
                continue
            if any(s.spawner is None or not proc.threads[s.spawner].spawned or s.spawner in reached for s in found):
                reached.add(j)
                grew = True
    return reached


def _spawner_sched(proc: ProcessSpec, site: SpawnSite) -> Optional[Sched]:
    """The scheduling a spawner has asked for when it reaches the spawn: its phase's, an earlier phase's, or its own."""
    own = proc.main.sched if site.spawner is None else proc.threads[site.spawner].sched
    work = proc.main.work if site.spawner is None else proc.threads[site.spawner].work
    if isinstance(work, PhasesWork):
        for phase in reversed(work.phases[: site.phase + 1]):
            if phase.sched is not None:
                return phase.sched
    return own
