"""The words of a program's events, and the words users bring from rt-app and cyclictest.

`EventKind` and the enums its events take (overrun, resource kind, protocol, pending) are the
vocabulary the native core, rt-app conversion and the report share.  `PEER_WORDS` says what a
key of rt-app's or cyclictest's means here, looked up before any "did you mean" (which guessed
`distance` for rt-app's `instance`): one table, read by every model's unknown-key message.
"""

from __future__ import annotations

import enum
from typing import Optional

from runner.errors import did_you_mean


class EventKind(str, enum.Enum):
    """What one event of a program does (rt-app's event names; `broad` is read as broadcast)."""

    RUN = "run"  # burn thread CPU time
    RUNTIME = "runtime"  # busy for wall time
    SLEEP = "sleep"  # relative sleep
    TIMER = "timer"  # sleep to the next release of a timer
    LOCK = "lock"
    UNLOCK = "unlock"
    WAIT = "wait"  # wait on a condition, with its mutex held
    SIGNAL = "signal"
    BROADCAST = "broadcast"
    BARRIER = "barrier"
    SUSPEND = "suspend"  # block until a resume on a queue
    RESUME = "resume"
    YIELD = "yield"
    MEM = "mem"  # write N bytes of a per-thread buffer
    ALLOC = "alloc"  # malloc, touch every page, free
    SPAWN = "spawn"  # create a thread of this process declared `spawned: true` (rt-app's fork)
    IORUN = "iorun"  # write N bytes to /dev/null (rt-app's iorun on its default io_device)

    @property
    def takes(self) -> str:
        """What the event's value is: a duration, a size, a resource name, a wait mapping, a timer, or nothing."""
        return _EVENT_TAKES[self]

    @property
    def resource_kind(self) -> Optional[ResourceKind]:
        """The kind of resource the event names, if it names one."""
        return _EVENT_RESOURCE.get(self)


class Overrun(str, enum.Enum):
    """What a timer does with a release that came too late."""

    SKIP = "skip"  # keep the grid, skip releases already past and count them missed (ROS 2 timers, kind: periodic)
    REBASE = "rebase"  # run now; the next release is one period later (rt-app "relative")
    CATCHUP = "catchup"  # keep the grid and run every late release at once (rt-app "absolute")


class ResourceKind(str, enum.Enum):
    """Synchronisation objects a scenario declares once and its threads share, across processes too."""

    MUTEX = "mutex"
    COND = "cond"
    BARRIER = "barrier"
    QUEUE = "queue"
    TIMER = "timer"


class Protocol(str, enum.Enum):
    """A mutex's protocol: plain, or priority inheritance (PTHREAD_PRIO_INHERIT, the kernel's rt_mutex)."""

    NONE = "none"
    INHERIT = "inherit"


class Pending(str, enum.Enum):
    """What a queue does with a resume that comes while no thread is suspended on it."""

    KEEP = "keep"  # counted: the next suspend takes it (32 at most); each resume wakes one thread
    DROP = "drop"  # rt-app's resume: it wakes every thread suspended at that moment, and is lost (counted) when none is


_EVENT_TAKES = {
    EventKind.RUN: "duration",
    EventKind.RUNTIME: "duration",
    EventKind.SLEEP: "duration",
    EventKind.TIMER: "timer",
    EventKind.LOCK: "resource",
    EventKind.UNLOCK: "resource",
    EventKind.WAIT: "wait",
    EventKind.SIGNAL: "resource",
    EventKind.BROADCAST: "resource",
    EventKind.BARRIER: "resource",
    EventKind.SUSPEND: "resource",
    EventKind.RESUME: "resource",
    EventKind.YIELD: "nothing",
    EventKind.MEM: "size",
    EventKind.ALLOC: "size",
    EventKind.SPAWN: "thread",
    EventKind.IORUN: "size",
}
_EVENT_RESOURCE = {
    EventKind.LOCK: ResourceKind.MUTEX,
    EventKind.UNLOCK: ResourceKind.MUTEX,
    EventKind.WAIT: ResourceKind.COND,
    EventKind.SIGNAL: ResourceKind.COND,
    EventKind.BROADCAST: ResourceKind.COND,
    EventKind.BARRIER: ResourceKind.BARRIER,
    EventKind.SUSPEND: ResourceKind.QUEUE,
    EventKind.RESUME: ResourceKind.QUEUE,
}


_SCHED_WORDS = "sched: fifo:80 (cyclictest -p80), sched: {policy: fifo, priority: 80}, or sched: {policy: other, nice: -5}"
_DEADLINE_WORDS = "SCHED_DEADLINE's parameters are part of sched: sched: {policy: deadline, runtime: 2ms, deadline: 8ms, period: 10ms}"
_RUN_FILE = "`runner FILE.json` runs an rt-app file as it is (`runner import-rtapp FILE.json` shows it as a scenario)"

PEER_WORDS: dict[str, dict[str, tuple[Optional[str], str]]] = {
    # Where a key is unknown (by model, or an event's word, or a key of its timer or wait mapping): the words of
    # rt-app and cyclictest a user brings along, each with the field it stands for here (None: none of that model)
    # and what to write.  Looked up before any "did you mean", which guessed `distance` for rt-app's `instance`.
    "Scenario": {
        "tasks": (None, f"rt-app's tasks are the threads of a process here: processes: [{{name: app, threads: [...]}}]; {_RUN_FILE}"),
        "global": (None, f"rt-app's global settings are the scenario's own keys here (duration: 10s, resources: ...); {_RUN_FILE}"),
    },
    "ThreadSpec": {
        "instance": ("count", "rt-app's instance is count here (count: 4 makes name-0 .. name-3)"),
        "loop": (None, "a thread's loop belongs to its program: work: {kind: phases, loop: 3, events: [...]} (rt-app's task loop)"),
        "phases": (
            None,
            "phases belong to the thread's program: work: {kind: phases, phases: [{events: [...]}, ...]} (rt-app's task phases)",
        ),
        "events": (None, "events belong to the thread's program: work: {kind: phases, events: [...]}"),
        "delay": (None, "a thread's delay belongs to its program: work: {kind: phases, delay: 2ms, events: [...]} (rt-app's task delay)"),
        "policy": ("sched", f"the policy is part of sched: {_SCHED_WORDS}"),
        "priority": ("sched", f"the priority is part of sched: {_SCHED_WORDS}"),
        "dl-runtime": ("sched", _DEADLINE_WORDS),
        "dl-period": ("sched", _DEADLINE_WORDS),
        "dl-deadline": ("sched", _DEADLINE_WORDS),
        "interval": (None, "cyclictest's interval is the period of periodic work: work: {kind: periodic, period: 1ms} (-i1000)"),
        "affinity": ("cpus", "cyclictest's affinity is cpus here: cpus: [1], or pin: each for one thread per CPU (-a)"),
        **{
            kind.value: (
                None,
                f"{kind.value} is an event of the thread's program, not a key of the thread as in an rt-app task: "
                f"work: {{kind: phases, events: [...]}}",
            )
            for kind in EventKind
        },
    },
    "Phase": {
        "policy": ("sched", f"the policy is part of sched: {_SCHED_WORDS}"),
        "priority": ("sched", f"the priority is part of sched: {_SCHED_WORDS}"),
    },
    "PeriodicWork": {
        "interval": ("period", "cyclictest's interval is period here (-i1000: period: 1ms)"),
        "loops": (None, "how long it runs is the scenario's duration (cyclictest -l counts loops; duration: 10s)"),
    },
    "event": {  # an event's word
        "fork": (None, "rt-app's fork is spawn here: {spawn: job} creates the next thread of job, declared spawned: true"),
        "sync": (None, "rt-app's sync is a signal and a wait here: {signal: c}, then {wait: {cond: c, mutex: m}}"),
    },
    "timer": {  # a key of {timer: {...}}
        "mode": ("overrun", "rt-app's timer mode is overrun here: relative is overrun: rebase, absolute is overrun: catchup"),
        "ref": (
            None,
            "a timer's name is written as the event's value, {timer: tick}, with resources: {tick: {kind: timer, period: 10ms}}; "
            "{timer: {period: 10ms}} is the thread's own (rt-app's unique)",
        ),
    },
    "wait": {  # a key of {wait: {...}}
        "ref": ("cond", "rt-app's ref is cond here: {wait: {cond: c, mutex: m}}"),
    },
}


def unknown_key(key: object, vocabulary: str, allowed: list[str]) -> str:
    """`unknown key 'mode'; ...`: what a key unknown in `vocabulary` (a PEER_WORDS entry) means here, or the closest allowed."""
    peer = PEER_WORDS.get(vocabulary, {}).get(str(key))
    hint = f"; {peer[1]}" if peer else did_you_mean(str(key), allowed) or f"; expected one of: {', '.join(allowed)}"
    return f"unknown key {str(key)!r}{hint}"
