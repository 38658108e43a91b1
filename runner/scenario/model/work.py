"""What a thread runs: periodic callbacks, a spin, sleep, or a program of phases of events.

`Work` is the tagged union a thread's `work:` reads into (`kind` selects it); a phases
program is rt-app's task, its phases entered with their own scheduling and CPUs.
"""

from __future__ import annotations

import enum
from typing import Annotated, Any, Literal, Optional, Union

from runner import units
from runner.scenario.model.base import IO_CHUNK, MAX_EVENTS, MAX_OFFSET, MAX_PERIOD, MAX_PHASES, MIN_PERIOD, CpuSet, Duration, Size, Strict
from runner.scenario.model.events import Event, Resource
from runner.scenario.model.sched import Sched
from runner.scenario.model.vocabulary import EventKind
from runner.scenario.typed import Context, Field, KeyProblem, Tagged, Written


class BurnClock(str, enum.Enum):
    """What a callback's burn measures: the thread's own CPU time (as the seed) or wall time."""

    THREAD_CPU = "thread_cpu"
    WALL = "wall"


class Wait(str, enum.Enum):
    """How a periodic thread waits for its next release."""

    SLEEP = "sleep"  # clock_nanosleep(TIMER_ABSTIME), as cyclictest and ROS 2 timers
    SPIN = "spin"  # busy-wait on the clock: no wake-up path, but the CPU is never given up


class PeriodicWork(Strict):
    """A periodic callback on absolute deadlines, as a ROS 2 wall timer: wake, burn, allocate, sleep."""

    kind: Literal["periodic"] = "periodic"
    period: Duration = Field(description="time between callback releases")
    burn: Duration = Field(default=0, description="CPU time burned per callback (0: wake-up only, as cyclictest)")
    burn_clock: BurnClock = Field(default=BurnClock.THREAD_CPU, description="thread_cpu (the seed's burn) or wall")
    alloc: Size = Field(default=0, description="memory to allocate, touch page by page and free per callback")
    offset: Duration = Field(default=0, description="delay of the first release after the common start")
    wait: Wait = Field(
        default=Wait.SLEEP,
        description="sleep: clock_nanosleep to each release; spin: busy-wait on the clock (short periods; the CPU is never given up)",
    )

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave `wait` out while it is the default, so a cell's spec hash reads as before it existed: old baselines still compare."""
        if self.wait is Wait.SLEEP:
            data.pop("wait", None)
        return data

    def _after(self, written: Any, context: Context) -> None:
        if self.period < MIN_PERIOD:
            raise ValueError(f"period {units.format_duration(self.period)} is too short; at least {units.format_duration(MIN_PERIOD)}")
        if self.period > MAX_PERIOD:
            raise ValueError(
                f"period {units.format_duration(self.period)} is too long; at most "
                f"{units.format_duration(MAX_PERIOD)} (a callback released less often is not real-time work)"
            )
        if self.offset > MAX_OFFSET:
            raise ValueError(f"offset {units.format_duration(self.offset)} is too long; at most {units.format_duration(MAX_OFFSET)}")
        if self.burn >= self.period:
            raise ValueError(
                f"burn {units.format_duration(self.burn)} does not fit in period {units.format_duration(self.period)};"
                " use kind: spin for a thread that never sleeps"
            )


class SpinWork(Strict):
    """Busy spinning for the whole run: a thread that never sleeps (a hog, a polling loop)."""

    kind: Literal["spin"] = "spin"


class SleepWork(Strict):
    """No work: the thread blocks until the run ends (idle middleware threads, a main thread that joins)."""

    kind: Literal["sleep"] = "sleep"


class Phase(Strict):
    """A named, ordered list of events run `loop` times, with scheduling and CPUs applied when it is entered."""

    name: Optional[str] = Field(default=None, description="phase name (default p0, p1, ...)")
    loop: int = Field(default=1, ge=1, le=1 << 40, description="passes over the events before the next phase")
    sched: Optional[Sched] = Field(default=None, description="scheduling applied when the phase is entered")
    cpus: Optional[CpuSet] = Field(default=None, description="CPU affinity applied when the phase is entered")
    events: list[Event] = Field(min_items=1, description="what the phase does, in order")

    def _after(self, written: Any, context: Context) -> None:
        """Locks balance within the phase, and a wait holds its mutex: what pthreads would refuse or deadlock on."""
        held: list[str] = []
        for i, ev in enumerate(self.events):
            if ev.event is EventKind.LOCK:
                if ev.resource in held:
                    raise KeyProblem(
                        ("events", i), f"lock {ev.resource} while this thread already holds it would deadlock; unlock it first"
                    )
                held.append(ev.resource or "")
            elif ev.event is EventKind.UNLOCK:
                if ev.resource not in held:
                    raise KeyProblem(("events", i), f"unlock {ev.resource} without a lock {ev.resource} before it in this phase")
                held.remove(ev.resource or "")
            elif ev.event is EventKind.WAIT and ev.mutex not in held:
                raise KeyProblem(("events", i), f"wait on {ev.cond} needs its mutex {ev.mutex} held; add {{lock: {ev.mutex}}} before it")
        if held:
            raise KeyProblem("events", f"the phase ends holding {', '.join(held)}; unlock in the same phase (a phase may loop)")


def _phases_shorthand(value: Any) -> Any:
    """`events: [...]` directly under the work is one phase."""
    if isinstance(value, dict) and "events" in value and "phases" in value:
        raise KeyProblem("events", "events and phases are both given; write events: for one phase, or phases: [{events: [...]}, ...]")
    if isinstance(value, dict) and "events" in value and "phases" not in value:
        value = dict(value)
        value["phases"] = [{"events": value.pop("events")}]
    return value


class PhasesWork(Strict):
    """A program as rt-app writes one: phases of events, looped, with per-phase scheduling.  Runs in the native core."""

    kind: Literal["phases"] = "phases"
    delay: Duration = Field(default=0, description="start this long after the common start")
    loop: int = Field(default=0, ge=0, le=1 << 40, description="passes over all phases; 0: until the run ends")
    phases: list[Phase] = Field(min_items=1, description="the phases, in order (or write events: for one phase)")

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _phases_shorthand(value)

    def _after(self, written: Any, context: Context) -> None:
        if self.delay > MAX_OFFSET:
            raise KeyProblem("delay", f"delay {units.format_duration(self.delay)} is too long; at most {units.format_duration(MAX_OFFSET)}")
        if len(self.phases) > MAX_PHASES:
            raise KeyProblem("phases", f"{len(self.phases)} phases; at most {MAX_PHASES} per thread")
        total = sum(len(p.events) for p in self.phases)
        if total > MAX_EVENTS:
            raise KeyProblem("phases", f"{total} events in all phases; at most {MAX_EVENTS} per thread")
        names = self.phase_names()
        for i, name in enumerate(names):
            if names.index(name) != i:
                raise KeyProblem(("phases", i, "name"), f"phase name {name!r} is used twice in this thread")

    def phase_names(self) -> list[str]:
        return [p.name or f"p{i}" for i, p in enumerate(self.phases)]

    def events(self) -> list[tuple[int, Event]]:
        """Every event with the index of its phase, in program order."""
        return [(k, e) for k, p in enumerate(self.phases) for e in p.events]

    def suspends_on(self) -> set[str]:
        """The queues the thread suspends on: a resume of one releases its next activation."""
        return {e.resource for _, e in self.events() if e.event is EventKind.SUSPEND and e.resource}

    def buffer_bytes(self) -> int:
        """The buffer the native core gives the thread for its mem and iorun events, resident all run long."""
        sizes = [(e.event, e.size or 0) for _, e in self.events()]
        written = [n for kind, n in sizes if kind is EventKind.MEM] + [min(n, IO_CHUNK) for kind, n in sizes if kind is EventKind.IORUN]
        return max(written, default=0)

    def resident_bytes(self) -> int:
        """What the thread holds at its peak beyond its stack: its buffer, and its largest alloc while it is touched."""
        return self.buffer_bytes() + max((e.size or 0 for _, e in self.events() if e.event is EventKind.ALLOC), default=0)

    def locked_mutexes(self) -> tuple[str, ...]:
        """The mutexes its lock events name, in the order the program first locks them: where each
        activation keeps its wait for each (its lock slots)."""
        return tuple(dict.fromkeys(e.resource for _, e in self.events() if e.event is EventKind.LOCK and e.resource is not None))

    def timer_periods(self, resources: dict[str, Resource]) -> tuple[int, ...]:
        """The periods of the thread's timers (private or named), shortest first; empty when it has none.

        Each activation's skipped releases are steps of the timer event that released it, and its
        slack runs to the next release on its grid (see the native core's ev_timer)."""
        periods = set()
        for _, e in self.events():
            if e.event is EventKind.TIMER:
                period = e.period if e.period is not None else getattr(resources.get(e.timer or ""), "period", None)
                if period is not None:
                    periods.add(period)
        return tuple(sorted(periods))


def _work_shorthand(value: Any, context: Context) -> Any:
    if isinstance(value, str):
        return {"kind": value}
    return value


Work = Annotated[Union[PeriodicWork, SpinWork, SleepWork, PhasesWork], Tagged(key="kind"), Written(_work_shorthand)]
"""What a thread runs; `kind` selects it."""
