"""What each thread of a cell should end up with, by the kernel's inheritance rules.

Pure.  Given the settings a process starts with (the runner's own, unless it asks
for reset-on-fork), this walks the same steps the worker takes - main thread
settings before or after thread creation, threads inheriting from their creator
or starting from explicit defaults, threads applying their own settings - and
returns the settings each thread is expected to hold.  The runner records this as
`requested` and compares it with what the kernel reports (`applied`).
"""

from __future__ import annotations

import enum
import fnmatch
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Optional

from runner import units
from runner.figures import ThreadKind
from runner.scenario.model import (
    ApplyWhen,
    EventKind,
    PeriodicWork,
    PhasesWork,
    Policy,
    ProcessSpec,
    ProgramSpec,
    Resource,
    Scenario,
    Sched,
    ThreadRule,
    Work,
)
from runner.scenario.program import SpawnSite, spawn_sites


@dataclass(frozen=True)
class Settings:
    """Scheduling settings of one thread; `cpus` None means every CPU.

    Stored in results as `{"policy": "fifo", "priority": 80, "nice": 0, "cpus": "all"}`
    (`runner.results.document.StoredSettings` says how).
    """

    policy: Policy = Policy.OTHER
    priority: int = 0
    nice: int = 0
    cpus: Optional[tuple[int, ...]] = None
    runtime: int = 0  # SCHED_DEADLINE parameters in ns; 0 for other policies
    deadline: int = 0
    period: int = 0

    def with_sched(self, sched: Optional[Sched], cpus: Optional[tuple[int, ...]]) -> Settings:
        """These settings after applying `sched` and `cpus` (absent parts stay as they are)."""
        out = self
        if sched is not None:
            out = replace(out, policy=sched.policy, priority=sched.rt_priority, runtime=0, deadline=0, period=0)
            if sched.policy is Policy.DEADLINE:
                out = replace(out, runtime=sched.runtime or 0, deadline=sched.deadline or 0, period=sched.period or 0, nice=0)
            if sched.nice is not None:
                out = replace(out, nice=sched.nice)
        if cpus is not None:
            out = replace(out, cpus=tuple(cpus))
        return out

    def reset_on_fork(self) -> Settings:
        """What SCHED_RESET_ON_FORK gives a child: RT, deadline and idle become OTHER, negative nice becomes 0."""
        policy = self.policy if self.policy in (Policy.OTHER, Policy.BATCH) else Policy.OTHER
        return replace(self, policy=policy, priority=0, nice=max(self.nice, 0), runtime=0, deadline=0, period=0)

    def label(self) -> str:
        if self.policy is Policy.DEADLINE:
            return "deadline " + "/".join(units.format_duration(v) for v in (self.runtime, self.deadline, self.period))
        text = f"{self.policy.value}:{self.priority}" if self.policy.is_realtime else self.policy.value
        if self.nice:
            text += f" nice={self.nice}"
        return text

    def cpus_label(self, online: Optional[tuple[int, ...]] = None) -> str:
        return units.format_cpus(self.cpus if self.cpus is not None else (online or ())) or "all"


EXPLICIT_DEFAULTS = Settings()
PROGRAM_ORIGIN = "program"  # a PlannedThread's origin when it is a program's thread, found running (not created by the runner)


class CallbackKind(enum.Enum):
    """What releases a thread's callbacks (activations), if anything: worked out once, when the thread is planned."""

    NONE = "none"  # no callbacks: spin, sleep, a program without a timer or a suspend
    PERIODIC = "periodic"  # released on a period: periodic work, or a program with a timer
    RESUMED = "resumed"  # released by resumes on a queue: a program that suspends and has no timer (a chain's later stage)


def callback_kind(work: Work) -> CallbackKind:
    """What releases the callbacks of a thread doing `work`.

    A program with a timer is periodic even if it also suspends.  A program released by
    resumes (a pipeline's later stage) has an activation from each resume to its next
    suspend, measured as a callback: latency from the resume, wall time, switches, faults and
    waits, but no slack or missed releases, since no period says when the next one is due.
    """
    if isinstance(work, PeriodicWork):
        return CallbackKind.PERIODIC
    if not isinstance(work, PhasesWork):
        return CallbackKind.NONE
    kinds = {e.event for _, e in work.events()}
    if EventKind.TIMER in kinds:
        return CallbackKind.PERIODIC
    return CallbackKind.RESUMED if EventKind.SUSPEND in kinds else CallbackKind.NONE


@dataclass(frozen=True)
class PlannedThread:
    """One thread to create: its name, its work, and the settings it should end up with.

    `callbacks` is worked out from `work` once, here: every stage after the plan reads it
    (`periodic`, `released`, `has_callbacks`) instead of asking the work again.
    """

    process: str
    instance: int
    index: int  # 0 = main thread, then creation order
    name: str
    spec_name: str
    work: Work
    settings: Settings
    origin: str  # how it gets them: "main", "inherited", "own", "explicit", "explicit+own"
    periods: tuple[int, ...] = ()  # the periods its callbacks are released at (periodic work's, its program's timers'), shortest first
    spawned: bool = False  # created mid-run by a spawn event of another thread, not at the start
    callbacks: CallbackKind = field(init=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "callbacks", callback_kind(self.work))  # frozen: set once, as it is made

    @property
    def period(self) -> Optional[int]:
        """The shortest period its callbacks are released at (the rate its ring is sized for); None without a timer."""
        return self.periods[0] if self.periods else None

    @property
    def periodic(self) -> bool:
        """Its callbacks are released on a period: periodic work, or a program with a timer."""
        return self.callbacks is CallbackKind.PERIODIC

    @property
    def released(self) -> bool:
        """Its callbacks are released by resumes on a queue (a chain's later stage), not by a period."""
        return self.callbacks is CallbackKind.RESUMED

    @property
    def has_callbacks(self) -> bool:
        """It runs callbacks (activations): released by a period or by resumes."""
        return self.callbacks is not CallbackKind.NONE


def work_periods(work: Work, resources: Optional[dict[str, Resource]] = None) -> tuple[int, ...]:
    """The periods a thread's callbacks are released at, shortest first: periodic work's, or its program's timers'."""
    if isinstance(work, PeriodicWork):
        return (work.period,)
    if isinstance(work, PhasesWork):
        return work.timer_periods(resources or {})
    return ()


def plan_process(
    proc: ProcessSpec, start: Settings, instance: int = 0, resources: Optional[dict[str, Resource]] = None
) -> list[PlannedThread]:
    """Expected settings of every thread of one process instance, main thread first."""
    base = start.reset_on_fork() if proc.reset_on_fork else start
    main_final = base.with_sched(proc.main.sched, proc.main.cpus)
    creator = main_final if proc.main.apply is ApplyWhen.BEFORE_THREADS else base
    main_periods = work_periods(proc.main.work, resources)
    out = [PlannedThread(proc.name, instance, 0, proc.main_name, proc.main_name, proc.main.work, main_final, "main", main_periods)]
    index = 1
    sites = spawn_sites(proc, 0)

    def initial_of(j: int, seen: frozenset[int] = frozenset()) -> Settings:
        """What spec j's threads start with: their creator's settings (a spawned one's: its first spawner's at the spawn)."""
        spec = proc.threads[j]
        if not spec.inherit:
            return EXPLICIT_DEFAULTS
        seen = seen | {j}  # a spawner that is itself spawned: follow the chain, never around a cycle
        site = next((x for x in sites.get(spec.name, []) if x.spawner not in seen), None) if spec.spawned else None
        if site is None:
            return creator
        return _at_site(proc, site, main_final, lambda k: first_member(k, seen))

    def first_member(j: int, seen: frozenset[int]) -> Settings:
        member = proc.threads[j].members()[0]
        return initial_of(j, seen).with_sched(member.sched, member.cpus)

    for j, spec in enumerate(proc.threads):
        initial = initial_of(j)
        own = spec.sched is not None or spec.cpus is not None
        origin = ("inherited" if spec.inherit else "explicit") if not own else ("own" if spec.inherit else "explicit+own")
        for member in spec.members():  # each its own CPU, priority and period when the spec spreads them
            final = initial.with_sched(member.sched, member.cpus)
            periods = work_periods(member.work, resources)
            out.append(PlannedThread(proc.name, instance, index, member.name, spec.name, member.work, final, origin, periods, spec.spawned))
            index += 1
    return out


def _at_site(proc: ProcessSpec, site: SpawnSite, main: Settings, settings_of: Callable[[int], Settings]) -> Settings:
    """The settings a spawner holds when it reaches a spawn: its own, then its phases' up to the spawn's."""
    current = main if site.spawner is None else settings_of(site.spawner)
    work = proc.main.work if site.spawner is None else proc.threads[site.spawner].work
    if isinstance(work, PhasesWork):
        for phase in work.phases[: site.phase + 1]:
            if phase.sched is not None or phase.cpus is not None:
                current = current.with_sched(phase.sched, phase.cpus)
    return current


def phase_settings(work: PhasesWork, base: Settings) -> list[Optional[Settings]]:
    """What each phase of a program asks its thread to hold on entering it, None for a phase that asks nothing:
    the thread's settings (`base`) with the sched and cpus of every phase up to it applied, as the native core does."""
    out: list[Optional[Settings]] = []
    current = base
    for phase in work.phases:
        asked = current.with_sched(phase.sched, phase.cpus) if (phase.sched is not None or phase.cpus is not None) else None
        current = asked or current
        out.append(asked)
    return out


def program_settings(prog: ProgramSpec, start: Settings) -> tuple[Settings, Settings]:
    """What a program's main thread and the threads it creates hold before any thread rule: as `chrt` and `taskset` give them.

    The program starts from the runner's settings with its own applied before exec; with
    reset_on_fork (`chrt --reset-on-fork`) its main thread keeps them and the threads it
    creates start from SCHED_OTHER and a nice of 0 or more.
    """
    main = start.with_sched(prog.sched, prog.cpus)
    return main, main.reset_on_fork() if prog.reset_on_fork else main


def rule_settings(prog: ProgramSpec, rule: ThreadRule, start: Settings) -> Settings:
    """What a thread a rule matched should hold: what the program gave it, then the rule's settings."""
    return program_settings(prog, start)[1].with_sched(rule.sched, rule.cpus)


def first_rule(prog: ProgramSpec, comm: str) -> Optional[int]:
    """The index of the first rule whose pattern matches a thread name, as a shell matches file names; None without."""
    return next((i for i, rule in enumerate(prog.threads) if fnmatch.fnmatchcase(comm, rule.match)), None)


def plan_scenario(scenario: Scenario, start: Settings) -> list[PlannedThread]:
    """Every measured thread of a cell, process by process, instance by instance."""
    out: list[PlannedThread] = []
    for proc in scenario.workers:
        for instance in range(proc.instances):
            out.extend(plan_process(proc, start, instance, scenario.resources))
    return out


PROGRAM_THREAD = ThreadKind("a thread of a command: program (measured from /proc)", proc=True)


def thread_kind(t: PlannedThread) -> ThreadKind:
    """What kind of thread `t` is, for the figures it can have (figures.has)."""
    if t.origin == PROGRAM_ORIGIN:
        return PROGRAM_THREAD
    phases = isinstance(t.work, PhasesWork)
    if t.periodic:
        return ThreadKind("a kind: phases thread with a timer" if phases else "a periodic thread", True, True, phases)
    if t.released:
        return ThreadKind("a kind: phases thread released by resumes (no period)", True, False, True)
    if phases:
        return ThreadKind("a kind: phases thread without a timer or a suspend (no callbacks)", events=True)
    return ThreadKind(f"a thread without callbacks (kind: {t.work.kind})")
