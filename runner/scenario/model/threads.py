"""The runner's own processes and their threads: names, counts, CPUs, pinning, memory, start.

A `ProcessSpec` is a process the runner forks; its `ThreadSpec`s are the threads it
creates, each with its work and scheduling, `count` and `pin: each` resolved against the
CPUs of the checking context.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from runner import units
from runner.scenario.model.base import (
    COMM_FORBIDS,
    COMM_MAX,
    MAX_INSTANCES,
    MAX_PERIOD,
    MAX_STACK,
    MAX_THREAD_COUNT,
    MIN_STACK,
    CpuSet,
    Duration,
    Size,
    Strict,
    context_cpus,
    control_character,
)
from runner.scenario.model.sched import Sched
from runner.scenario.model.work import PeriodicWork, PhasesWork, SleepWork, Work
from runner.scenario.typed import Context, Field, KeyProblem


def check_comm(name: str) -> str:
    if not name:
        raise ValueError("a name cannot be empty")
    if len(name.encode()) > COMM_MAX:
        raise ValueError(
            f"name {name!r} is {len(name.encode())} bytes; the kernel keeps {COMM_MAX} "
            f"(it would show as {name.encode()[:COMM_MAX].decode(errors='ignore')!r})"
        )
    char = control_character(name)
    if char is not None or re.search(r"[\s/]", name):
        found = char if char is not None else re.findall(r"[\s/]", name)[0]
        raise ValueError(f"name {name!r} may not contain {COMM_FORBIDS} (found {found!r})")
    return name


def _per_cpu_asked(value: Any) -> tuple[bool, bool]:
    """Whether a thread spec as written asks for one thread per CPU (`count: cpus`), and to pin each (`pin: each`)."""
    if not isinstance(value, dict):
        return False, False
    return value.get("count") == "cpus", value.get("pin") in (Pin.EACH, Pin.EACH.value)


class ApplyWhen(str, enum.Enum):
    """When the main thread applies its settings, relative to creating its threads."""

    BEFORE_THREADS = "before_threads"
    AFTER_THREADS = "after_threads"


class MainThread(Strict):
    """The process's main thread (named as the process): its settings, when it applies them, and its work."""

    sched: Optional[Sched] = Field(default=None, description="scheduling settings of the main thread")
    cpus: Optional[CpuSet] = Field(default=None, description="CPU affinity of the main thread")
    apply: ApplyWhen = Field(
        default=ApplyWhen.BEFORE_THREADS,
        description="before_threads: threads created later inherit (chrt, middleware_threads); "
        "after_threads: they keep the old settings (main_thread)",
    )
    work: Work = Field(default_factory=SleepWork, description="what the main thread runs after creating its threads")


class Pin(str, enum.Enum):
    """How the threads of one spec are spread over its CPUs."""

    EACH = "each"


@dataclass(frozen=True)
class ThreadMember:
    """One thread a `ThreadSpec` creates: its name, the settings it applies to itself, and its work.

    Threads of one spec differ when it pins each to its own CPU, spreads priorities or spaces
    periods apart; the plan and the worker both take each thread's settings from here.
    """

    name: str
    sched: Optional[Sched]
    cpus: Optional[tuple[int, ...]]
    work: Work


class ThreadSpec(Strict):
    """A thread created by the main thread, in declared order; with `count`, that many such threads."""

    name: str = Field(description="thread name, 15 bytes at most (with count: N, names get -0, -1, ...; with pin: each, the CPU)")
    count: int = Field(
        default=1,
        ge=1,
        le=MAX_THREAD_COUNT,
        description="how many such threads; 'cpus': one per CPU of cpus, or per CPU the runner may use (cyclictest -t)",
    )
    inherit: bool = Field(
        default=True,
        description="true: start with the creator's settings (PTHREAD_INHERIT_SCHED); false: start with "
        "explicit defaults (SCHED_OTHER, nice 0, all CPUs) as PTHREAD_EXPLICIT_SCHED does",
    )
    sched: Optional[Sched] = Field(default=None, description="settings the thread applies to itself when it starts")
    cpus: Optional[CpuSet] = Field(
        default=None,
        description="CPU affinity the thread applies to itself when it starts; with pin: each, the CPUs to pin to "
        "(default: every CPU the runner may use)",
    )
    pin: Optional[Pin] = Field(
        default=None,
        description="each: thread i is pinned to the i-th CPU of cpus alone and named by it (cyclictest -t -a)",
    )
    work: Work = Field(default_factory=SleepWork)
    priospread: bool = Field(
        default=False, description="thread i runs at sched's RT priority minus i (cyclictest --priospread); the last must stay at 1 or more"
    )
    distance: Duration = Field(default=0, description="thread i's period is the work's period plus i times distance (cyclictest -d)")
    spawned: bool = Field(
        default=False,
        description="created mid-run by a spawn event of another thread of this process (rt-app's fork), not at the start; "
        "count is how many can be spawned (a spawn beyond it is counted as dropped); needs kind: phases work",
    )

    # set on each model while checking (see _after), not keys of the file
    _per_cpu: ClassVar[bool] = False  # the file wrote `count: cpus`
    _machine_cpus: ClassVar[Optional[tuple[int, ...]]] = None  # the machine's CPUs, when count or pinning was resolved against them

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        """Resolve `count: cpus` (and `pin: each` without cpus) against the CPUs of the machine.

        The resolved count and CPUs are what the model keeps (and what a cell's spec hash covers):
        the same file makes 2 threads on a 2-CPU machine and 8 on an 8-CPU one.
        """
        if not isinstance(value, dict):
            return value
        per_cpu, pinned = _per_cpu_asked(value)
        if per_cpu or (pinned and value.get("cpus") is None):
            value = dict(value)
            chosen = machine = context_cpus(context)
            if value.get("cpus") is not None:
                try:
                    chosen = units.parse_cpus(value["cpus"], machine)
                except units.UnitError:
                    pass  # the cpus key reports its own problem; count it as the machine's CPUs meanwhile
            elif pinned:
                value["cpus"] = list(machine)
            if per_cpu:
                value["count"] = len(chosen)
        return value

    def _after(self, written: Any, context: Context) -> None:
        """Note what was resolved against the machine, then check the names and the spread."""
        per_cpu, pinned = _per_cpu_asked(written)
        machine = context_cpus(context) if (per_cpu or pinned) and written.get("cpus") is None else None
        object.__setattr__(self, "_per_cpu", per_cpu)
        object.__setattr__(self, "_machine_cpus", machine)
        for name in self.names():
            check_comm(name)
        self._check_spread()

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave pin, priospread and distance out while unused, so a cell's spec (and the hash results store
        and `compare` / `--resume` check) reads as it did before they existed: old baselines still compare."""
        for key, unused in (("pin", None), ("priospread", False), ("distance", 0), ("spawned", False)):
            if getattr(self, key) == unused:
                data.pop(key, None)
        return data

    def _check_spread(self) -> None:
        """The rules that span count, cpus, sched and work: one CPU per pinned thread, priorities >= 1, periods in range."""
        if self.pin is Pin.EACH and self.cpus is not None and self.count > len(self.cpus):
            raise KeyProblem(
                "pin",
                f"pin: each gives every thread a CPU of its own, but count {self.count} is more than "
                f"{self.cpus_source()}; lower count, or write count: cpus for one thread per CPU",
            )
        if self.priospread:
            sched = self.sched
            if sched is None or not sched.policy.is_realtime:
                raise KeyProblem(
                    "priospread",
                    "priospread lowers the RT priority by one per thread; it needs this thread's own sched: fifo:N or rr:N",
                )
            lowest = sched.rt_priority - (self.count - 1)
            if lowest < 1:
                raise KeyProblem(
                    "priospread",
                    f"priospread takes thread {self.names()[-1]} to priority {lowest} (thread i runs at "
                    f"{sched.policy.value}:{sched.rt_priority} minus i) and RT priorities stop at 1; "
                    f"{self.count} threads{self.count_source()} need {sched.policy.value}:{self.count} or more, "
                    "or a lower count",
                )
        if self.distance:
            if not isinstance(self.work, PeriodicWork):
                raise KeyProblem(
                    "distance",
                    f"distance spaces the periods of periodic work apart, but this thread's work is {self.work.kind}; "
                    "remove distance or use kind: periodic",
                )
            longest = self.work.period + (self.count - 1) * self.distance
            if self.distance > MAX_PERIOD or longest > MAX_PERIOD:
                raise KeyProblem(
                    "distance",
                    f"distance {units.format_duration(self.distance)} gives thread {self.names()[-1]} a period of "
                    f"{units.format_duration(longest)}; at most {units.format_duration(MAX_PERIOD)}, lower distance or count",
                )
        if self.spawned and not isinstance(self.work, PhasesWork):
            raise KeyProblem(
                "spawned",
                f"a spawned thread runs a program from the moment it is spawned, but this thread's work is {self.work.kind}; "
                "use kind: phases (its events run once per loop, then the thread ends)",
            )

    @property
    def per_cpu(self) -> bool:
        """Whether the file wrote `count: cpus` (the count is then this machine's, already resolved)."""
        return self._per_cpu

    @property
    def machine_cpus(self) -> Optional[tuple[int, ...]]:
        """The machine's CPUs when count or pinning was resolved against them (no cpus given); None otherwise."""
        return self._machine_cpus

    def cpus_source(self) -> str:
        """The CPUs a per-CPU count or pinning uses, in words: `the 2 CPUs of cpus 2-3`, `the 2 CPUs the runner may use (0-1)`."""
        cpus = self._machine_cpus if self._machine_cpus is not None else (self.cpus or ())
        noun = f"the {len(cpus)} CPU{'s' if len(cpus) != 1 else ''}"
        if self._machine_cpus is not None:
            return f"{noun} the runner may use ({units.format_cpus(cpus)})"
        return f"{noun} of cpus {units.format_cpus(cpus)}"

    def count_source(self) -> str:
        """` (count: cpus, one per CPU: the 2 CPUs ...)` when the count was resolved per CPU; empty otherwise."""
        return f" (count: cpus, one per CPU: {self.cpus_source()})" if self._per_cpu else ""

    @property
    def varies(self) -> bool:
        """Whether its threads differ from one another, or their number depends on the machine."""
        return self._per_cpu or self.pin is not None or self.priospread or bool(self.distance)

    def names(self) -> list[str]:
        """The thread names this spec creates: by CPU when each is pinned to one, else numbered when several."""
        if self.pin is Pin.EACH and self.cpus is not None:
            return [f"{self.name}-{cpu}" for cpu in self.cpus[: self.count]]
        if self.count == 1:
            return [self.name]
        return [f"{self.name}-{i}" for i in range(self.count)]

    def members(self) -> list[ThreadMember]:
        """Every thread this spec creates, with the settings each applies to itself and its own work."""
        out = []
        for i, name in enumerate(self.names()):
            sched = self.sched
            if self.priospread and sched is not None:
                sched = sched.replace(priority=sched.rt_priority - i)
            cpus = self.cpus
            if self.pin is Pin.EACH and cpus is not None:
                cpus = (cpus[i],)
            work = self.work
            if self.distance and isinstance(work, PeriodicWork):
                work = work.replace(period=work.period + i * self.distance)
            out.append(ThreadMember(name, sched, tuple(cpus) if cpus is not None else None, work))
        return out


class Memory(Strict):
    """Memory settings of a process, as the seed's minimal_memory_lock applies them."""

    lock: bool = Field(default=False, description="mlockall(MCL_CURRENT|MCL_FUTURE) with glibc tuning (no mmap, no trim)")
    prealloc: Size = Field(default=0, description="heap to reserve after locking: allocated, faulted in, and kept")
    stack_size: Optional[Size] = Field(default=None, description="default stack size of threads the process creates")

    def _after(self, written: Any, context: Context) -> None:
        if self.prealloc and not self.lock:
            raise KeyProblem("prealloc", "prealloc only keeps memory resident together with lock: true")
        if self.stack_size is not None and self.stack_size < MIN_STACK:
            raise KeyProblem("stack_size", f"stack_size {units.format_size(self.stack_size)} is below the 16KiB minimum")
        if self.stack_size is not None and self.stack_size > MAX_STACK:
            raise KeyProblem(
                "stack_size", f"stack_size {units.format_size(self.stack_size)} is too large; at most {units.format_size(MAX_STACK)}"
            )


class Start(str, enum.Enum):
    """When a process's threads begin their work."""

    TOGETHER = "together"  # all at the common start
    IN_ORDER = "in_order"  # in the order listed, each once the one before it has begun (as rt-app creates its threads)


class ProcessSpec(Strict):
    """A process of the scenario: its name (the COMMAND ps shows), memory, main thread and threads."""

    name: str = Field(description="process name as ps shows it (COMMAND), 15 bytes at most", check=check_comm)
    instances: int = Field(default=1, ge=1, le=MAX_INSTANCES, description="how many copies of this process")
    reset_on_fork: bool = Field(
        default=False,
        description="start from SCHED_OTHER and nice >= 0 as SCHED_RESET_ON_FORK would, instead of inheriting the runner's settings",
    )
    memory: Memory = Field(default_factory=Memory)
    main: MainThread = Field(default_factory=MainThread)
    threads: list[ThreadSpec] = Field(default_factory=list, description="threads the main thread creates, in order")
    start: Start = Field(
        default=Start.TOGETHER,
        description="together: every thread begins its work at the common start; in_order: the threads (not the main "
        "thread, nor spawned ones) begin in the order listed, each once the one before it has begun, as rt-app creates its "
        "threads one after the other (delays count from the common start still)",
    )

    @property
    def main_name(self) -> str:
        """The main thread's name is the process name: the kernel keeps one comm for both."""
        return self.name

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave start out while it is together, so a cell's spec (and the hash stored baselines hold) reads as before."""
        if self.start is Start.TOGETHER:
            data.pop("start", None)
        return data
