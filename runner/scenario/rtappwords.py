"""rt-app's vocabulary as the conversion reads it: its event keys, task and phase keys, policies, limits.

Event keys are recognised by prefix in rt-app's own order (`runtime2` is a runtime, `run0`
a run); the keys of rt-app's old grammar and of its events after 1.0 are named so that
the notes can say what was left out.  See `runner.scenario.rtapp` for the whole mapping.
"""

from __future__ import annotations

from typing import Any, Optional

MAX_BYTES = 1 << 20  # rt-app files are a few KiB; a megabyte is not a workload
DEFAULT_DURATION_S = 10
MAX_DURATION_S = 24 * 3600  # the scenario's bound on a cell's duration
MAX_INT = 2**31 - 1  # rt-app reads every number as a C int
FOREVER = MAX_INT  # a phase loop that never ends before the run does
FORK_INSTANCES = 16  # how many threads a forked task can have here (rt-app: 1,024 forks of it in all, then it exits)
MAX_US = 24 * 3600 * 1_000_000  # no event lasts longer than a run

# rt-app's event names, in the order it tests them: a key is the first event it starts with
EVENTS = (
    "lock",
    "unlock",
    "wait",
    "signal",
    "broad",
    "sync",
    "sleep",
    "runtime",
    "run",
    "timer",
    "suspend",
    "resume",
    "mem",
    "iorun",
    "yield",
    "barrier",
    "fork",
    "alloc",
)
SCHED_KEYS = ("policy", "priority", "dl-runtime", "dl-period", "dl-deadline", "util_min", "util_max")
TASK_KEYS = {"instance", "cpus", "delay", "loop", "phases", *SCHED_KEYS}
PHASE_KEYS = {"loop", "cpus", *SCHED_KEYS}
TASK_UNSUPPORTED = {
    "taskgroup": "cgroup task groups have no equivalent here",
    "nodes_membind": "NUMA memory binding has no equivalent here",
    "numa": "NUMA memory binding has no equivalent here",
}
LEGACY = ("exec", "period", "deadline", "lock_order", "resources")
LEGACY_NOTE = "{keys}: rt-app's old grammar (exec, period, deadline, lock_order, resources), which rt-app no longer reads; left out"
POLICIES = {
    "SCHED_OTHER": "other",
    "SCHED_NORMAL": "other",
    "SCHED_BATCH": "batch",
    "SCHED_IDLE": "idle",
    "SCHED_FIFO": "fifo",
    "SCHED_RR": "rr",
    "SCHED_DEADLINE": "deadline",
}
RT_POLICIES = ("fifo", "rr")
NICE_POLICIES = ("other", "batch")


class Pairs(list[tuple[str, Any]]):
    """A JSON object as rt-app reads it: every (key, value) pair in order, repeated keys included."""

    def names(self) -> list[str]:
        """The keys, in order, repeats included."""
        return [key for key, _ in self]


def event_kind(key: str) -> Optional[str]:
    """The rt-app event a key names (`run0` -> run, `runtime2` -> runtime, `timer_a` -> timer), or None.

    `lock_order`, of rt-app's old grammar, is not taken for a lock.
    """
    if key in LEGACY:
        return None
    for name in (*NEWER_EVENTS, *EVENTS):  # memrun before mem, as rt-app looks them up
        if key.startswith(name):
            return name
    return None


NEWER_EVENTS = {  # events of rt-app after 1.0 that a scenario has no counterpart for: left out, with a note
    "memrun": "a memory-bandwidth load of rt-app after 1.0",
    "sem_post": "a semaphore of rt-app after 1.0",
    "sem_wait": "a semaphore of rt-app after 1.0",
}
