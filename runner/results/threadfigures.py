"""What was measured for one thread, as results.json stores it: typed records, durations in integer ns.

`ThreadFigures` is what the evaluation core produces and the results document stores; the
registry that names each of its values (`latency.p99` is `latency_ns.p99`) is runner.figures.
The records live apart from the registry because reading a scenario needs the names (an
expectation's `metric`) but never the records: `runner validate` does not build them.
"""

from __future__ import annotations

from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

Count = Annotated[int, Field(ge=0)]  # what the kernel and the native core count: never below 0 (a file that says so is refused)


class _Figures(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Involuntary(_Figures):
    """Involuntary context switches (preemptions): the thread was runnable and lost the CPU."""

    total: Count
    per_callback_mean: Optional[float] = None
    per_callback_max: Optional[Count] = None
    callbacks_with_any: Optional[Count] = None
    per_second: Optional[float] = None  # over the time the thread was measured (programs' threads)


class Voluntary(_Figures):
    total: Count
    per_second: Optional[float] = None


class Spread(_Figures):
    """Order statistics of durations, in ns: min and max exact, percentiles by nearest rank to the histogram bucket."""

    min: int
    p50: int
    p90: int
    p99: int
    p999: int
    max: int
    mean: Optional[int] = None  # exact (a running mean), rounded to the ns
    stddev: Optional[int] = None  # population standard deviation, rounded to the ns
    above_bound: Optional[Count] = None  # values above the scenario's latency_bound, when one is set
    count: Optional[Count] = Field(
        None, description="how many values the figures stand on (a p99 of 1 wake-up is that one); null in files from before it was kept"
    )


class Slack(_Figures):
    """Time from the end of each callback to its next release, in ns: negative when the callback overran."""

    min: int
    p1: int
    p50: int
    max: int
    mean: int


class Faults(_Figures):
    minor: Count
    major: Count
    minor_first_callback: Optional[Count] = None
    minor_after_first: Optional[Count] = None
    minor_per_callback_max: Optional[Count] = None


class ThreadFigures(_Figures):
    """What was measured for one thread; durations in integer nanoseconds."""

    callbacks: Count
    missed_releases: Count
    releases: Count = 0  # releases due in the cell (callbacks + missed), for periodic threads and stages released by resumes
    overruns: Optional[Count] = None  # callbacks that ended after their next release; None: not recorded (files before it was)
    missed_consecutive_max: Optional[Count] = None  # the most releases missed in a row, periodic threads; None: not recorded
    involuntary: Involuntary
    voluntary: Voluntary
    latency_ns: Optional[Spread] = None  # wake-up latency: actual wake minus scheduled release
    callback_wall_ns: Optional[Spread] = None  # wake to end of the callback, preemptions included
    slack_ns: Optional[Slack] = None  # end of each callback to its next release
    faults: Faults
    cpus_seen: tuple[int, ...] = ()
    complete: bool  # False when the thread did not finish (killed, crashed, interrupted)
    lock_wait_ns: Optional[Spread] = None  # programs: time to acquire a mutex, every lock event of the thread
    cond_wait_ns: Optional[Spread] = None  # programs: time blocked in wait on a condition
    barrier_wait_ns: Optional[Spread] = None  # programs: time waiting at a barrier
    resume_latency_ns: Optional[Spread] = None  # programs: from a resume (or the suspend, if later) to running again
    chain_ns: Optional[Spread] = None  # programs: from the release that started a chain to the end of this thread's part
    cpu_time_ns: Optional[Count] = None  # time on a CPU over the measured window (programs' threads, from schedstat)
    migrations: Optional[Count] = None  # moves between CPUs (the kernel's se.nr_migrations, or the trace's)
    wakeup_ns: Optional[Spread] = None  # scheduler trace: from each sched_waking to the switch onto a CPU
    preemptions: Optional[Count] = None  # scheduler trace: switched out while runnable
    message_age_ns: Optional[Spread] = None  # ROS 2 callbacks that took messages: from the message's source timestamp to the start

    @model_validator(mode="after")
    def _releases(self) -> ThreadFigures:
        """Files from before `releases` was recorded: every release was either served or missed."""
        if "releases" not in self.model_fields_set:
            object.__setattr__(self, "releases", self.callbacks + self.missed_releases)  # frozen: set once, while validating
        return self
