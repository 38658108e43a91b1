"""The scenario model: what a scenario can say, as typed, validated objects.

One cell of a scenario (matrix values already substituted) validates into a
`Scenario`.  Everything here is pure: typed models (runner.scenario.typed) with enums and
integer units (nanoseconds, bytes), no I/O.  The same models export the JSON Schema that
editors use to autocomplete and underline scenario files (`runner schema`).
"""

from __future__ import annotations

import enum
import math
import os
import re
import unicodedata
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

from runner import figures, units
from runner.errors import did_you_mean
from runner.scenario.typed import Context, Field, KeyProblem, Model, Schema, Tagged, Written, text_schema

COMM_MAX = 15  # TASK_COMM_LEN - 1: the kernel truncates longer names silently
COMM_FORBIDS = "spaces, '/' or control characters"
"""What a process or thread name may not hold (ps and /proc would show it split, or as another line); the editors' words too."""

# Ceilings no real scenario comes near.  They turn absurd input (`period: 2000000h`, a 400-digit
# size) into a message that names the bound, instead of a run that fails or never ends.  What
# depends on the machine (RAM, RLIMIT_MEMLOCK, pid_max) is checked in runner.limits.
NS_PER_HOUR = 3_600_000_000_000
MIN_RUN, MAX_RUN = 100_000_000, 24 * NS_PER_HOUR  # a cell's run time
MAX_SETTLE = NS_PER_HOUR  # the pause between cells: a pause, not a way to park the runner
MAX_REPEAT = 1_000_000  # runs of each cell in one run (--repeat)
MIN_PERIOD, MAX_PERIOD = 10_000, NS_PER_HOUR  # released less than hourly is not a real-time callback
MAX_OFFSET = NS_PER_HOUR
MAX_LATENCY_LIMIT = NS_PER_HOUR  # a latency bound above an hour checks nothing
MAX_ANY_SIZE = 1 << 40  # 1 TiB: above the RAM of any machine the runner is used on
MIN_STACK, MAX_STACK = 16 << 10, 1 << 30  # per thread; the usual default is 8 MiB
MAX_THREAD_COUNT, MAX_INSTANCES, MAX_HOGS = 1024, 64, 256
MAX_LAST_SAMPLES = 1 << 22  # `samples: last N`: a ring of N samples (64 bytes each) per thread
MIN_DL_RUNTIME = 1024  # the kernel refuses SCHED_DEADLINE runtimes below 1.024 us
MAX_PHASES, MAX_EVENTS = 32, 128  # per thread, as the native core sizes its figures
MAX_MEM_EVENT = 1 << 30  # a mem event writes at most this much of its buffer
IO_CHUNK = 1 << 20  # iorun writes from the thread's buffer in chunks of at most this
# What a program's stdout and stderr keep each by default: an hour of a chatty log at INFO (100 lines a second) whole, as
# much as Kubernetes keeps of a container's (10 MiB in 5 files), and a program that prints in a loop costs a cell 128 MiB
# of disk at most, not the disk.
OUTPUT_LIMIT = 64 << 20


CPUS_CONTEXT = "cpus"
"""Key of the validation context holding the CPUs `count: cpus` and `pin: each` resolve against."""


def context_cpus(context: Context) -> tuple[int, ...]:
    """The CPUs per-CPU counts and pinning resolve against: the checking context's, else the runner's affinity.

    The loader passes this machine's CPUs (read once with its other limits) so that the model
    stays pure and tests can pretend to be a 4-CPU machine; a model checked without them
    (a script, a test of one model) falls back to the CPUs this process may use, as hogs did.
    """
    if context is not None and context.get(CPUS_CONTEXT):
        return tuple(context[CPUS_CONTEXT])
    return tuple(sorted(os.sched_getaffinity(0)))


def _unit(parse: Any, ceiling: int | None = None, fmt: Any = None) -> Any:
    """The reader of a value written with a unit, refusing values above `ceiling`.

    Durations need no ceiling here: every duration field has its own range check.
    """

    def check(value: Any, context: Context = None) -> Any:
        try:
            parsed = parse(value)
        except units.UnitError as exc:
            raise ValueError(str(exc)) from None
        if ceiling is not None and parsed > ceiling:
            raise ValueError(f"{fmt(parsed)} is too large; at most {fmt(ceiling)}")
        return parsed

    return check


def control_character(text: str, allowed: str = "") -> str | None:
    """The first control, format or line-separator character in `text` (not in `allowed`), or None.

    A newline or an escape sequence in a name or label ends up in terminals, ps output and
    report headings, where it breaks lines or injects text; such characters are refused.
    """
    if text.isprintable():  # no character of the categories below is printable: the common case is quick
        return None
    for char in text:
        if char not in allowed and (unicodedata.category(char) in ("Cc", "Cf", "Cs", "Zl", "Zp")):
            return char
    return None


def _no_control(what: str, allowed: str = "") -> Any:
    def check(value: Any) -> Any:
        if isinstance(value, str):
            char = control_character(value, allowed)
            if char is not None:
                raise ValueError(f"{what} {value!r} contains the control character {char!r}; remove it")
        return value

    return check


_DURATION_SCHEMA = {
    "anyOf": [text_schema(units.DURATION_PATTERN, units.DURATION_EXPECTED), {"const": 0}],
    "examples": ["100ms", "40ms", "1.5s"],
}
_SIZE_SCHEMA = text_schema(units.SIZE_PATTERN, units.SIZE_EXPECTED, examples=["50MiB", "200KiB"])
_CPUS_SCHEMA = {
    "anyOf": [  # text first: an editor shows the first form's message when none fits, and most are written as text
        text_schema(units.CPUS_PATTERN, units.CPUS_EXPECTED),
        {"type": "array", "items": {"type": "integer", "minimum": 0, "maximum": units.MAX_CPUS - 1}, "minItems": 1},
        {"type": "integer", "minimum": 0, "maximum": units.MAX_CPUS - 1},
    ],
    "examples": ["0-1", [1], "0b10", "0-7:2", "all"],
}


def _cpus(value: Any, context: Context) -> Any:
    """A CPU set as written; `all` is every CPU the runner may use (the checking context's, see context_cpus)."""
    try:
        return units.parse_cpus(value, context_cpus(context))
    except units.UnitError as exc:
        raise ValueError(str(exc)) from None


Duration = Annotated[int, Written(_unit(units.parse_duration), units.format_duration, _DURATION_SCHEMA)]
"""A duration in nanoseconds, written with a unit (`100ms`)."""

Size = Annotated[int, Written(_unit(units.parse_size, MAX_ANY_SIZE, units.format_size), units.format_size, _SIZE_SCHEMA)]
"""A size in bytes, written with a unit (`50MiB`)."""

CpuSet = Annotated[tuple[int, ...], Written(_cpus, units.format_cpus, _CPUS_SCHEMA)]
"""A set of CPU numbers, written as a list, a cpulist `0-1,3` / `0-7:2` / `all`, or a mask `0b1100`."""


class Strict(Model):
    """Base of every scenario model: unknown keys are errors, objects are immutable."""

    @classmethod
    def _peer_word(cls, key: str) -> Optional[tuple[Optional[str], str]]:
        """What `key`, unknown here, means in this model when it is a word of rt-app's or cyclictest's (`PEER_WORDS`)."""
        return PEER_WORDS.get(cls.__name__, {}).get(key)


class Policy(str, enum.Enum):
    """Linux scheduling policies, by the kernel's numbers (see sched(7))."""

    OTHER = "other"
    FIFO = "fifo"
    RR = "rr"
    BATCH = "batch"
    IDLE = "idle"
    DEADLINE = "deadline"

    @property
    def kernel_id(self) -> int:
        return {"other": 0, "fifo": 1, "rr": 2, "batch": 3, "idle": 5, "deadline": 6}[self.value]

    @property
    def is_realtime(self) -> bool:
        return self in (Policy.FIFO, Policy.RR)

    @classmethod
    def from_kernel(cls, number: int) -> Policy:
        for policy in cls:
            if policy.kernel_id == number:
                return policy
        raise ValueError(f"unknown kernel scheduling policy {number}")


POLICY_WORDS = ["other", "fifo", "rr", "batch", "idle", "deadline"]
_POLICY_ALIASES = {"normal": "other"}  # SCHED_NORMAL is the kernel's name for SCHED_OTHER
_RTLA_LETTERS = {"f": "fifo", "r": "rr", "o": "other", "d": "deadline"}
"""rtla's -P forms (`f:80`, `r:40`, `o:NICE`, `d:RUNTIME:PERIOD`, any case): the letter takes its colon and value."""
SCHED_FORMS = (
    "other, batch, idle, fifo:1..99, rr:1..99, deadline:RUNTIME[/DEADLINE[/PERIOD]] (any case, SCHED_ prefix allowed), "
    "rtla's f:80, r:40, o:NICE, d:RUNTIME:PERIOD, or a mapping {policy: other, nice: -5}"
)
_PRIORITY_DIGITS = 9  # more digits than any priority or nice value: refused before int() (4300 digits would raise)


def _anycase(word: str) -> str:
    """`fifo` -> `[fF][iI][fF][oO]`: case-insensitive without an inline flag, which JavaScript's RegExp refuses."""
    return "".join(f"[{c.lower()}{c.upper()}]" if c.isalpha() else re.escape(c) for c in word)


def _policy_words(*names: str) -> str:
    """A pattern (unanchored) for the policy words `names` in any case, with or without SCHED_."""
    return f"(?:{_anycase('sched_')})?(?:" + "|".join(_anycase(n) for n in names) + ")"


def policy_pattern(*names: str) -> str:
    """The anchored pattern of the policy words `names` as a mapping's `policy:` may write them (SCHED_FIFO, Fifo, normal)."""
    return f"^{_policy_words(*names)}$"


def _sched_patterns() -> tuple[str, str]:
    """The sched text forms and policy words as patterns valid in Python and JavaScript: (written form, policy word).

    The written form is as strict as a pattern can be: fifo and rr with 1..99, other, batch and idle with
    nothing or 0, rtla's o: with a nice value -20..19, deadline with one to three durations.  What needs
    arithmetic (runtime <= deadline <= period, the 1.024us minimum) is left to the model.
    """
    words = _policy_words
    duration = units.DURATION_PATTERN[1:-1]
    rt_priority = "0*[1-9][0-9]?"
    nice = "(?:-?0*1?[0-9]|-0*20)"
    rtla_ns = f"(?:[0-9]+|{duration})"  # rtla reads a bare number as nanoseconds
    written = "|".join(
        (
            f"(?:{words('fifo', 'rr')}|[fFrR]):{rt_priority}",
            f"{words('other', 'normal', 'batch', 'idle')}(?::-?0+)?",
            f"[oO]:{nice}",
            f"{words('deadline')}:{duration}(?:/{duration}){{0,2}}",
            f"[dD]:{rtla_ns}:{rtla_ns}",
        )
    )
    return f"^(?:{written})$", policy_pattern(*POLICY_WORDS, *_POLICY_ALIASES)


SCHED_PATTERN, POLICY_PATTERN = _sched_patterns()


def _policy_name(text: str) -> str:
    word = text.strip().lower()
    if word.startswith("sched_"):
        word = word[len("sched_") :]
    return _POLICY_ALIASES.get(word, word)


def _sched_text(value: str) -> dict[str, Any]:
    """`fifo:80`, `SCHED_RR:40`, `normal`, `f:80`, `o:-5`, `deadline:2ms/8ms/10ms`, `d:2ms:10ms` as the mapping form."""
    match = re.fullmatch(r"([A-Za-z_]+)(?::(.*))?", value, re.DOTALL)
    word = match.group(1).lower() if match else ""
    arg = match.group(2) if match else None
    rtla = word in _RTLA_LETTERS
    policy = _RTLA_LETTERS[word] if rtla else _policy_name(word)
    if rtla and arg is None:
        raise ValueError(f"{value!r}: rtla's one-letter forms take a value: f:80, r:40, o:0 (a nice value), d:2ms:10ms")
    if policy not in POLICY_WORDS:
        shown = word or value
        raise ValueError(f"{shown!r} is not a policy{did_you_mean(shown, POLICY_WORDS)}; expected {SCHED_FORMS}")
    out: dict[str, Any] = {"policy": policy}
    if arg is None:
        return out
    if policy == "deadline":
        parts = arg.split(":" if rtla else "/")
        if rtla:  # rtla's d:RUNTIME:PERIOD, a bare number in ns; the deadline is the period
            if len(parts) != 2:
                raise ValueError(f"{value!r}: write d:RUNTIME:PERIOD as rtla does, e.g. 'd:2ms:10ms'")
            runtime, period = (p + "ns" if p.strip().isdecimal() else p for p in parts)
            return {**out, "runtime": runtime, "deadline": period, "period": period}
        if len(parts) > 3:
            raise ValueError(f"{value!r}: write deadline:RUNTIME/DEADLINE/PERIOD, e.g. 'deadline:2ms/8ms/10ms'")
        out.update(zip(("runtime", "deadline", "period"), parts))
        return out
    number = arg
    if not re.fullmatch(r"-?[0-9]+", number):
        raise ValueError(f"priority {arg!r} in {value!r} is not an integer; write e.g. 'fifo:80'")
    if len(number.lstrip("-0")) > _PRIORITY_DIGITS:
        raise ValueError(f"{number[:12]}… in {value!r} is far out of range; priorities are 1..99, nice values -20..19")
    if rtla and policy == "other":  # rtla's o:N is SCHED_OTHER at nice N
        if not -20 <= int(number) <= 19:
            raise ValueError(f"{value!r}: rtla's o: takes a nice value -20..19, e.g. 'o:-5'")
        return {**out, "nice": int(number)}
    out["priority"] = int(number)
    return out


def _sched_shorthand(value: Any) -> Any:
    """Accept the text forms (see _sched_text) as well as the mapping form, whose policy may be `SCHED_FIFO` or `normal`."""
    if isinstance(value, str):
        return _sched_text(value)
    if isinstance(value, dict) and isinstance(value.get("policy"), str):
        return {**value, "policy": _policy_name(value["policy"])}
    if not isinstance(value, dict):  # `sched: 80`: say what a policy is written as, not only that a mapping is expected
        shown = repr(value) if isinstance(value, (int, float)) else "a list" if isinstance(value, list) else type(value).__name__
        raise ValueError(f"{shown} is not a policy; expected {SCHED_FORMS}")
    return value


def _not_an_rt_policy(policy: Policy, priority: int) -> str:
    """Why `other:80`, `other:-5` or `idle:3` is refused, and what was probably meant (fifo:N, or nice N)."""
    niceable = policy in (Policy.OTHER, Policy.BATCH) and -20 <= priority <= 19
    nice = f"{{policy: {policy.value}, nice: {priority}}}" + (f" (rtla: o:{priority})" if policy is Policy.OTHER else "")
    if 1 <= priority <= 99:
        text = f"an RT priority ({priority}) needs a real-time policy; use fifo:{priority} or rr:{priority}"
        if policy is Policy.IDLE:
            return text + "; idle takes neither a priority nor a nice value"
        return text + (f", or for nice {priority} write {nice}" if niceable else f", or a nice value for {policy.value}")
    if niceable:
        return f"priority {priority} is not for {policy.value}, which takes a nice value instead: write {nice}"
    takes = "a nice value -20..19" if policy in (Policy.OTHER, Policy.BATCH) else "neither a priority nor a nice value"
    return f"priority {priority} is not for {policy.value}, which takes {takes}; RT priorities 1..99 are for fifo and rr"


class Sched(Strict):
    """Scheduling settings: a policy with its RT priority (fifo, rr) or nice value (other, batch)."""

    policy: Policy = Field(description="other, batch, idle, fifo, rr or deadline (SCHED_ prefix and upper case accepted)")
    priority: Optional[int] = Field(default=None, description="RT priority 1..99 for fifo and rr; 0 or absent otherwise")
    nice: Optional[int] = Field(default=None, ge=-20, le=19, description="nice value -20..19 for other and batch")
    runtime: Optional[Duration] = Field(default=None, description="deadline: CPU time granted every period (sched_runtime)")
    deadline: Optional[Duration] = Field(default=None, description="deadline: relative deadline (default: the period, as rt-app)")
    period: Optional[Duration] = Field(default=None, description="deadline: period (default: the runtime, as rt-app)")
    util_min: Optional[int] = Field(default=None, ge=0, le=1024, description="uclamp minimum utilisation 0..1024 (kernels with uclamp)")
    util_max: Optional[int] = Field(default=None, ge=0, le=1024, description="uclamp maximum utilisation 0..1024 (kernels with uclamp)")

    @classmethod
    def _schema(cls, schema: dict[str, Any]) -> None:
        schema["examples"] = ["fifo:80", "SCHED_RR", {"policy": "other", "nice": -5}]

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave the deadline and uclamp keys out while unset, so a cell's spec hash reads as before they existed."""
        for key in ("runtime", "deadline", "period", "util_min", "util_max"):
            if getattr(self, key) is None:
                data.pop(key, None)
        return data

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _sched_shorthand(value)

    def _after(self, written: Any, context: Context) -> None:
        policy = self.policy
        if self.util_min is not None and self.util_max is not None and self.util_min > self.util_max:
            raise ValueError(f"util_min {self.util_min} is above util_max {self.util_max}")
        if policy is Policy.DEADLINE:
            self._deadline_consistent()
            return
        if self.runtime is not None or self.deadline is not None or self.period is not None:
            raise ValueError(f"runtime, deadline and period are for policy deadline, not {policy.value}")
        if policy.is_realtime:
            if self.priority is None:
                raise ValueError(f"policy {policy.value} needs a priority 1..99, e.g. '{policy.value}:80'")
            if not 1 <= self.priority <= 99:
                raise ValueError(f"priority {self.priority} is out of range for {policy.value}; expected 1..99")
            if self.nice is not None:
                raise ValueError(f"nice does not apply to {policy.value}; nice is for other and batch")
        elif self.priority not in (None, 0):
            raise ValueError(_not_an_rt_policy(policy, self.priority))
        elif policy is Policy.IDLE and self.nice not in (None, 0):
            raise ValueError("policy idle takes no nice value")

    def _deadline_consistent(self) -> None:
        """SCHED_DEADLINE: runtime <= deadline <= period, defaults as rt-app (period = runtime, deadline = period)."""
        if self.runtime is None:
            raise ValueError(
                "policy deadline needs a runtime: write deadline:RUNTIME[/DEADLINE[/PERIOD]] such as 'deadline:2ms/8ms/10ms', "
                "rtla's 'd:2ms:10ms', or {policy: deadline, runtime: 2ms, period: 10ms}"
            )
        if self.priority not in (None, 0) or self.nice not in (None, 0):
            raise ValueError("policy deadline takes runtime, deadline and period, not a priority or nice value")
        period = self.period if self.period is not None else (self.deadline if self.deadline is not None else self.runtime)
        deadline = self.deadline if self.deadline is not None else period
        if self.runtime < MIN_DL_RUNTIME:
            raise ValueError(f"runtime {units.format_duration(self.runtime)} is below the kernel's minimum of 1.024us")
        if not self.runtime <= deadline <= period:
            raise ValueError(
                f"deadline needs runtime <= deadline <= period; got runtime {units.format_duration(self.runtime)}, "
                f"deadline {units.format_duration(deadline)}, period {units.format_duration(period)}"
            )
        if period > MAX_PERIOD:
            raise ValueError(f"period {units.format_duration(period)} is too long; at most {units.format_duration(MAX_PERIOD)}")
        object.__setattr__(self, "period", period)  # frozen: the resolved defaults are set once, while validating
        object.__setattr__(self, "deadline", deadline)

    @property
    def rt_priority(self) -> int:
        return self.priority or 0

    @property
    def bandwidth(self) -> float:
        """A deadline thread's share of one CPU (runtime / period); 0 for other policies."""
        return self.runtime / self.period if self.policy is Policy.DEADLINE and self.runtime and self.period else 0.0

    def label(self) -> str:
        """Compact form: `fifo:80`, `other`, `other nice=-5`, `deadline 2ms/8ms/10ms`."""
        if self.policy is Policy.DEADLINE:
            parts = (self.runtime or 0, self.deadline or 0, self.period or 0)
            return "deadline " + "/".join(units.format_duration(v) for v in parts)
        text = f"{self.policy.value}:{self.priority}" if self.policy.is_realtime else self.policy.value
        if self.nice:
            text += f" nice={self.nice}"
        return text


# --------------------------------------------------------------------------- work


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
_EVENT_ALIASES = {"broad": "broadcast"}
_EVENT_EXAMPLES = {
    "duration": "{run: 200us}",
    "size": "{mem: 64KiB}",
    "resource": "{lock: name}",
    "wait": "{wait: {cond: name, mutex: name}}",
    "timer": "{timer: {period: 1ms}} or {timer: name}",
    "thread": "{spawn: worker}",
    "nothing": "yield",
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


def _unknown(key: object, vocabulary: str, allowed: list[str]) -> str:
    """`unknown key 'mode'; ...`: what a key unknown in `vocabulary` (a PEER_WORDS entry) means here, or the closest allowed."""
    peer = PEER_WORDS.get(vocabulary, {}).get(str(key))
    hint = f"; {peer[1]}" if peer else did_you_mean(str(key), allowed) or f"; expected one of: {', '.join(allowed)}"
    return f"unknown key {str(key)!r}{hint}"


_MAPPING_KEYS = {"timer": ["period", "overrun"], "wait": ["cond", "mutex"]}  # what an event's mapping value holds


def _event_shorthand(value: Any) -> Any:
    """`{run: 200us}`, `yield`, `{timer: {period: 1ms}}` as the typed form `{event: run, duration: 200us}`."""
    if isinstance(value, str):
        value = {value: None}
    if not isinstance(value, dict):
        raise ValueError(f"an event is a one-key mapping such as {{run: 200us}} or the word yield, got {type(value).__name__}")
    if "event" in value:
        return value
    if len(value) != 1:
        keys = ", ".join(repr(k) for k in value)
        raise ValueError(f"an event has exactly one key (its kind), got {len(value)}: {keys}; write each event as its own list item")
    ((word, arg),) = value.items()
    word = _EVENT_ALIASES.get(str(word), str(word))
    try:
        kind = EventKind(word)
    except ValueError:
        names = [k.value for k in EventKind]
        peer = PEER_WORDS["event"].get(word)
        hint = f"; {peer[1]}" if peer else did_you_mean(word, names)
        raise ValueError(f"unknown event {word!r}{hint or '; events: ' + ', '.join(names)}") from None
    takes = kind.takes
    if takes == "nothing":
        if arg not in (None, "", 0):
            raise ValueError(f"{word} takes no value; write it as the bare word `{word}`")
        return {"event": word}
    if arg is None:
        raise ValueError(f"{word} needs a value, e.g. {_EVENT_EXAMPLES[takes]}")
    if takes in _MAPPING_KEYS and isinstance(arg, dict):  # its keys said at their place, in this mapping's own words
        for key in arg:
            if key not in _MAPPING_KEYS[takes]:
                raise KeyProblem((word, key), _unknown(key, takes, _MAPPING_KEYS[takes]))
    if takes == "wait":
        if not isinstance(arg, dict):
            raise ValueError(f"wait needs its condition and mutex, e.g. {_EVENT_EXAMPLES['wait']}")
        return {"event": word, **arg}
    named = takes in ("resource", "thread") or (takes == "timer" and not isinstance(arg, dict))
    if named and not isinstance(arg, str):  # the typed form's key (resource, thread) is not what the user wrote
        raise ValueError(f"{word} takes one name, e.g. {_EVENT_EXAMPLES[takes]}; got {type(arg).__name__} {arg!r}")
    if takes == "timer":
        return {"event": word, **arg} if isinstance(arg, dict) else {"event": word, "timer": arg}
    if takes == "thread":
        return {"event": word, "thread": arg}
    return {"event": word, takes: arg}


def _event_schema() -> dict[str, Any]:
    """How events are written (one-key mappings or a bare word), for editors; the typed form is internal."""
    name = {"type": "string", "description": "a name declared in resources"}
    timer = {
        "anyOf": [
            name,
            {
                "type": "object",
                "properties": {"period": _DURATION_SCHEMA, "overrun": {"enum": [o.value for o in Overrun]}},
                "required": ["period"],
                "additionalProperties": False,
            },
        ]
    }
    wait = {"type": "object", "properties": {"cond": name, "mutex": name}, "required": ["cond", "mutex"], "additionalProperties": False}
    thread = {"type": "string", "description": "a thread of the same process declared with spawned: true"}
    by_takes = {"duration": _DURATION_SCHEMA, "size": _SIZE_SCHEMA, "resource": name, "timer": timer, "wait": wait, "thread": thread}
    words = [k.value for k in EventKind if k.takes == "nothing"]
    properties = {k.value: by_takes[k.takes] for k in EventKind if k.takes != "nothing"}
    properties.update({alias: properties[target] for alias, target in _EVENT_ALIASES.items()})
    return {
        "anyOf": [
            {"enum": words},
            {"type": "object", "properties": properties, "minProperties": 1, "maxProperties": 1, "additionalProperties": False},
        ],
        "description": "one event: {run: 200us}, {lock: name}, {timer: {period: 1ms}}, {wait: {cond: c, mutex: m}}, yield, ...",
        "examples": ["yield", {"run": "200us"}, {"lock": "data"}, {"timer": {"period": "1ms"}}],
    }


class Event(Strict):
    """One step of a program, written `{run: 200us}`, `{lock: name}`, `{timer: {period: 1ms}}` or `yield`."""

    event: EventKind
    duration: Optional[Duration] = None
    size: Optional[Size] = None
    resource: Optional[str] = None
    cond: Optional[str] = None
    mutex: Optional[str] = None
    timer: Optional[str] = Field(default=None, description="a named timer of resources")
    period: Optional[Duration] = None
    overrun: Optional[Overrun] = None
    thread: Optional[str] = Field(default=None, description="spawn: a thread of the same process declared with spawned: true")

    @classmethod
    def _schema(cls, schema: dict[str, Any]) -> None:
        """How events are written, not the typed form the model keeps."""
        schema.clear()
        schema.update(_event_schema())

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _event_shorthand(value)

    def _after(self, written: Any, context: Context) -> None:
        kind = self.event
        if kind is EventKind.WAIT and (self.cond is None or self.mutex is None):
            raise ValueError(f"wait needs both a cond and a mutex, e.g. {_EVENT_EXAMPLES['wait']}")
        if kind is EventKind.TIMER:
            if (self.timer is None) == (self.period is None):
                raise ValueError("a timer event names a timer of resources or has its own period, e.g. {timer: {period: 1ms}}")
            if self.period is not None and not MIN_PERIOD <= self.period <= MAX_PERIOD:
                raise ValueError(
                    f"timer period {units.format_duration(self.period)} is out of range; expected "
                    f"{units.format_duration(MIN_PERIOD)} to {units.format_duration(MAX_PERIOD)}"
                )
        elif self.overrun is not None or self.period is not None or self.timer is not None:
            raise ValueError("period, overrun and timer belong to timer events")
        if (kind is EventKind.SPAWN) != (self.thread is not None):
            raise ValueError(f"thread belongs to spawn events, and a spawn names its thread, e.g. {_EVENT_EXAMPLES['thread']}")
        if kind in (EventKind.RUN, EventKind.RUNTIME, EventKind.SLEEP) and self.duration is not None and self.duration > MAX_PERIOD:
            raise ValueError(
                f"{kind.value} {units.format_duration(self.duration)} is too long; at most {units.format_duration(MAX_PERIOD)}"
            )
        if kind in (EventKind.MEM, EventKind.IORUN) and self.size is not None and self.size > MAX_MEM_EVENT:
            raise ValueError(f"{kind.value} {units.format_size(self.size)} is too large; at most {units.format_size(MAX_MEM_EVENT)}")

    def _dumped(self, data: dict[str, Any]) -> Any:
        """The event as written: `{run: 200us}`, `yield`, `{wait: {cond: c, mutex: m}}` (what the spec hash covers)."""
        kind = self.event
        takes = kind.takes
        if takes == "nothing":
            return kind.value
        if takes == "wait":
            return {kind.value: {"cond": self.cond, "mutex": self.mutex}}
        if takes == "timer":
            if self.timer is not None:
                return {kind.value: self.timer}
            body: dict[str, Any] = {"period": units.format_duration(self.period or 0)}
            if self.overrun is not None:
                body["overrun"] = self.overrun.value
            return {kind.value: body}
        if takes == "duration":
            return {kind.value: units.format_duration(self.duration or 0)}
        if takes == "size":
            return {kind.value: units.format_size(self.size or 0)}
        if takes == "thread":
            return {kind.value: self.thread}
        return {kind.value: self.resource}

    def names(self) -> list[tuple[str, ResourceKind]]:
        """The resources this event names, with the kind each must be."""
        kind = self.event
        if kind is EventKind.WAIT:
            return [(self.cond or "", ResourceKind.COND), (self.mutex or "", ResourceKind.MUTEX)]
        if kind is EventKind.TIMER:
            return [(self.timer, ResourceKind.TIMER)] if self.timer is not None else []
        wanted = kind.resource_kind
        return [(self.resource or "", wanted)] if wanted is not None else []

    def label(self) -> str:
        """`lock data`, `run 200us`, `timer 1ms`, `wait ready (data)`: how the report names the event."""
        kind = self.event
        if kind is EventKind.WAIT:
            return f"wait {self.cond} ({self.mutex})"
        if kind is EventKind.TIMER:
            return f"timer {self.timer}" if self.timer else f"timer {units.format_duration(self.period or 0)}"
        if self.duration is not None:
            return f"{kind.value} {units.format_duration(self.duration)}"
        if self.size is not None:
            return f"{kind.value} {units.format_size(self.size)}"
        if self.thread is not None:
            return f"{kind.value} {self.thread}"
        return f"{kind.value} {self.resource}" if self.resource else kind.value


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


class Resource(Strict):
    """A synchronisation object or a named timer, declared once and shared by every thread that names it."""

    kind: ResourceKind
    protocol: Protocol = Field(default=Protocol.NONE, description="mutex: none, or inherit (priority inheritance)")
    period: Optional[Duration] = Field(default=None, description="timer: the period of its release grid")
    overrun: Overrun = Field(default=Overrun.SKIP, description="timer: skip, rebase or catchup on a late release")
    pending: Pending = Field(
        default=Pending.KEEP,
        description="queue: keep (a resume no thread waits for is kept for the next suspend, 32 at most; each wakes one "
        "thread) or drop (rt-app's resume: it wakes every thread suspended at that moment, and is lost, counted, when none is)",
    )

    def _after(self, written: Any, context: Context) -> None:
        if self.kind is ResourceKind.TIMER:
            if self.period is None:
                raise ValueError("a timer needs a period, e.g. {kind: timer, period: 10ms}")
            if not MIN_PERIOD <= self.period <= MAX_PERIOD:
                raise KeyProblem(
                    "period",
                    f"period {units.format_duration(self.period)} is out of range; expected "
                    f"{units.format_duration(MIN_PERIOD)} to {units.format_duration(MAX_PERIOD)}",
                )
        elif self.period is not None:
            raise KeyProblem("period", f"period is for timers, not a {self.kind.value}")
        if self.protocol is not Protocol.NONE and self.kind is not ResourceKind.MUTEX:
            raise KeyProblem("protocol", f"protocol is for mutexes, not a {self.kind.value}")
        if self.pending is not Pending.KEEP and self.kind is not ResourceKind.QUEUE:
            raise KeyProblem("pending", f"pending is for queues, not a {self.kind.value}")

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave pending out while it is keep, so a cell's spec (and the hash stored baselines hold) reads as before it existed."""
        if self.pending is Pending.KEEP:
            data.pop("pending", None)
        return data


def _work_shorthand(value: Any, context: Context) -> Any:
    if isinstance(value, str):
        return {"kind": value}
    return value


Work = Annotated[Union[PeriodicWork, SpinWork, SleepWork, PhasesWork], Tagged(key="kind"), Written(_work_shorthand)]
"""What a thread runs; `kind` selects it."""


# ------------------------------------------------------------------------ threads


def _check_comm(name: str) -> str:
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
            _check_comm(name)
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

    name: str = Field(description="process name as ps shows it (COMMAND), 15 bytes at most", check=_check_comm)
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


# ----------------------------------------------------------------------- programs


def _argv_list(key: str) -> Any:
    """A reader: `key` is a list of arguments, never a shell string (no shell runs it)."""

    def check(value: Any) -> Any:
        if isinstance(value, str):
            raise ValueError(f"{key} must be a list such as ['stress-ng', '--cpu', '2'], not the string {value!r} (no shell runs it)")
        return value

    return check


def _argv_items(key: str) -> Any:
    """A check: the program (`key`[0]) is named and no argument holds a NUL byte, which exec cannot pass."""

    def check(value: list[str]) -> list[str]:
        if not value[0]:
            raise ValueError(f"{key}[0], the program, is empty")
        for arg in value:
            if "\x00" in arg:
                raise ValueError(f"argument {arg!r} contains a NUL byte, which no program can receive")
        return value

    return check


class Until(str, enum.Enum):
    """When a program's cell ends."""

    END = "end"  # the program runs the whole cell and is stopped at its end
    EXIT = "exit"  # the cell ends when the program exits; the duration is its limit


MAX_GRACE = 60_000_000_000  # SIGTERM to SIGKILL: a program gets at most a minute to exit
MIN_MEMORY_MAX = 4 << 20  # below this the exec itself (the loader, libc) fails in the cgroup, not the program


def _program_cwd(value: str) -> str:
    if not value or "\x00" in value:
        raise ValueError(f"cwd {value!r} is not a path")
    return value


def _program_env(value: dict[str, str]) -> dict[str, str]:
    for key, text in value.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", key):
            raise ValueError(f"env: {key!r} is not a variable name; expected letters, digits and _, not starting with a digit")
        if "\x00" in text:
            raise ValueError(f"env: {key} contains a NUL byte, which no program can receive")
    return value


def _program_grace(value: int) -> int:
    if value > MAX_GRACE:
        raise ValueError(f"grace {units.format_duration(value)} is too long; at most {units.format_duration(MAX_GRACE)}")
    return value


def _program_memory_max(value: int) -> int:
    if value < MIN_MEMORY_MAX:
        raise ValueError(
            f"memory_max {units.format_size(value)} is too small for any program to start; at least {units.format_size(MIN_MEMORY_MAX)}"
        )
    return value


def _match_pattern(value: str) -> str:
    """A thread rule's `match`: a name or shell pattern, not empty, without control characters."""
    if not value:
        raise ValueError("match is empty; expected a thread name or a pattern such as 'rt_sub*'")
    char = control_character(value)
    if char is not None:
        raise ValueError(f"match {value!r} contains the control character {char!r}; thread names cannot hold one")
    return value


class ThreadRule(Strict):
    """Settings the runner gives the threads a program creates itself, chosen by name, the moment each appears."""

    match: str = Field(description="thread name (comm) as a shell pattern: `ctl_loop`, `rt_sub*`, `worker-[0-3]`", check=_match_pattern)
    sched: Optional[Sched] = Field(default=None, description="scheduling applied to each matching thread")
    cpus: Optional[CpuSet] = Field(default=None, description="CPU affinity applied to each matching thread")

    def _after(self, written: Any, context: Context) -> None:
        if self.sched is None and self.cpus is None:
            raise KeyProblem("match", f"the rule for {self.match!r} sets nothing; give it sched, cpus or both")


class ProgramSpec(Strict):
    """A program of the user's own, run as a measured process: settings applied before exec, thread rules after.

    The runner does not own its threads, so settings are given at the process level
    (inherited by every thread it creates, as `chrt` and `taskset` in front of a
    command) and per thread by name; everything is read back from the kernel.
    """

    name: str = Field(description="the process's label in reports and expectations (`name/thread`), 15 bytes at most", check=_check_comm)
    command: list[str] = Field(
        min_items=1,
        before=_argv_list("command"),
        check=_argv_items("command"),
        description="program and arguments as a list (never a shell string); the program is looked up in PATH",
    )
    cwd: Optional[str] = Field(default=None, description="working directory (default: the cell's folder)", check=_program_cwd)
    env: dict[str, str] = Field(default_factory=dict, description="environment variables added to the runner's", check=_program_env)
    sched: Optional[Sched] = Field(default=None, description="scheduling applied before exec: every thread the program creates inherits it")
    cpus: Optional[CpuSet] = Field(default=None, description="CPU affinity applied before exec, inherited likewise")
    reset_on_fork: bool = Field(
        default=False, description="set SCHED_RESET_ON_FORK before exec: threads and children the program creates start from SCHED_OTHER"
    )
    threads: list[ThreadRule] = Field(
        default_factory=list,
        description="settings for the program's own threads by name, applied as each appears (first match wins)",
    )
    until: Until = Field(
        default=Until.END, description="end: stopped at the end of the cell; exit: the cell ends when it exits (duration is the limit)"
    )
    grace: Duration = Field(
        default=1_000_000_000, description="time between SIGTERM and SIGKILL when the program is stopped", check=_program_grace
    )
    memory_max: Optional[Size] = Field(
        default=None,
        description="a memory limit for the program and all it starts, in a memory cgroup of its own (systemd's MemoryMax=, "
        "docker --memory): past it the kernel reclaims, then its OOM killer ends the program",
        check=_program_memory_max,
    )
    output_limit: Size = Field(
        default=OUTPUT_LIMIT,
        description="bytes of its stdout, and of its stderr, kept in NAME.stdout and NAME.stderr: what it writes beyond is "
        "counted and dropped, never held up (the results and a warning say how much); 0B keeps none, and there is no "
        "'unlimited' (a program that prints in a loop would fill the disk): write the size you need",
    )

    def _after(self, written: Any, context: Context) -> None:
        if self.sched is not None and self.sched.policy is Policy.DEADLINE:
            raise KeyProblem(
                "sched",
                "a SCHED_DEADLINE process cannot create threads or children (the kernel refuses its clone); "
                "give deadline to a thread rule (threads: - match: ...) instead",
            )

    @property
    def main_name(self) -> str:
        return self.name


def _process_kind(value: Any) -> type:
    """A process with a `command` runs the user's program; any other runs the runner's own threads."""
    if isinstance(value, ProgramSpec) or (isinstance(value, dict) and "command" in value):
        return ProgramSpec
    return ProcessSpec


_PROGRAM_SNIPPET = {
    "label": "command: a program of yours",
    "description": "a process that runs your program (command: its argv, as a list) instead of the runner's threads",
    "body": {"name": "${1:app}", "command": ["${2:program}", "${3:argument}"]},
}
AnyProcess = Annotated[
    Union[ProcessSpec, ProgramSpec],
    Tagged(choose=_process_kind),
    Schema({"defaultSnippets": [_PROGRAM_SNIPPET]}),  # an editor completes only the keys of the form `name:` fits first
]
"""A scenario process: the runner's own threads (`threads:` with work), or the user's program (`command:`)."""


# --------------------------------------------------------------------- background


class HogKind(str, enum.Enum):
    THREAD = "thread"
    PROCESS = "process"


class Hog(Strict):
    """Busy loops that compete for the CPUs while the scenario runs."""

    count: int = Field(description="how many hogs; 'cpus' writes one per online CPU", ge=1, le=MAX_HOGS)
    kind: HogKind = Field(default=HogKind.PROCESS, description="process: one process each; thread: threads of one process")
    name: str = Field(default="hog", description="process and thread name", check=_check_comm)
    sched: Optional[Sched] = Field(default=None, description="policy of the hogs (default: inherited, normally SCHED_OTHER)")
    cpus: Optional[CpuSet] = Field(default=None, description="CPUs the hogs may run on (default: all)")

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        if isinstance(value, dict) and value.get("count") == "cpus":
            return {**value, "count": len(context_cpus(context))}
        return value


class Command(Strict):
    """An external program run as background load, started before and stopped after the cell."""

    argv: list[str] = Field(
        min_items=1,
        before=_argv_list("argv"),
        check=_argv_items("argv"),
        description="program and arguments as a list (never a shell string)",
    )
    name: Optional[str] = Field(default=None, description="label in reports; default: the program", check=_no_control("name"))


class Background(Strict):
    """Contention that runs during each cell and is stopped after it."""

    hogs: list[Hog] = Field(default_factory=list)
    commands: list[Command] = Field(default_factory=list)


# ------------------------------------------------------------------- expectations


class _MetricValue(str):
    """What every expectation metric knows: its declaration in the figure registry."""

    value: str

    @property
    def figure(self) -> figures.Figure:
        return figures.figure(self.value)

    @property
    def is_latency(self) -> bool:
        return self.figure.is_duration

    @property
    def needs_callbacks(self) -> bool:
        return self.figure.needs_callbacks


Metric = enum.Enum(  # type: ignore[misc]  # built from the registry: every figure is an expectation metric
    "Metric", {f.name.upper().replace(".", "_"): f.name for f in figures.REGISTRY}, type=_MetricValue, module=__name__
)
Metric.__doc__ = "Figures an expectation can check, named as in results.json (runner/figures.py declares them)."


def metric_figure(metric: Metric) -> figures.Figure:
    """The registry's declaration of an expectation's metric: unit, scope, words."""
    return figures.figure(metric.value)


def _limit(value: Any, context: Context = None) -> Any:
    """Latency limits are durations (kept as ns), negative for slack (`-2ms`); counts are plain numbers."""
    if isinstance(value, str):
        text = value.strip()
        negative = text[:1] in ("-", "\u2212")
        try:
            parsed = units.parse_duration(text[1:] if negative else text)
            return -parsed if negative else parsed
        except units.UnitError as exc:
            raise ValueError(str(exc)) from None
    if isinstance(value, bool):  # a bool is an int to Python: `max: true` would be a limit of 1
        raise ValueError(f"{str(value).lower()} is not a limit; expected a number, or a duration such as 2ms for latency figures")
    return value


SIGNED_DURATION_SCHEMA = text_schema(  # -2ms for slack
    units.DURATION_PATTERN.replace("^", "^\\s*[-\u2212]?", 1), f"{units.DURATION_EXPECTED}, or below zero (-2ms) for slack"
)
_LIMIT_SCHEMA = {
    "anyOf": [  # text first: an editor shows the first form's message when none fits
        SIGNED_DURATION_SCHEMA,
        {"type": "number", "minimum": -1.7976931348623157e308, "maximum": 1.7976931348623157e308},  # finite: .inf is refused
    ]
}
Limit = Annotated[float, Written(_limit, None, _LIMIT_SCHEMA)]
MatrixValue = Union[str, int, float, bool]


class Expectation(Strict):
    """A check on one measured figure of the named thread(s), in every cell or in selected cells."""

    thread: str = Field(description="thread name, or process/thread")
    metric: Metric = Field(description="figure to check, as named in results.json")
    max: Optional[Limit] = Field(default=None, description="upper bound (a duration for latency metrics)")
    min: Optional[Limit] = Field(default=None, description="lower bound (a duration for latency metrics)")
    cells: dict[str, Union[MatrixValue, Annotated[list[MatrixValue], Schema({"minItems": 1})]]] = Field(
        default_factory=dict, description="only in cells whose matrix values match, e.g. {policy: [fifo, rr]}"
    )

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        if isinstance(value, dict):
            metric = str(value.get("metric", ""))
            if metric not in figures.BY_NAME:
                return value  # the metric reports its own problem (with a "did you mean"); its unit is unknown
            latency = figures.figure(metric).is_duration
            for bound in ("max", "min"):
                given = value.get(bound)
                if given is None:
                    continue
                if latency and not isinstance(given, str):
                    raise ValueError(f"{bound}: bare number {given!r} for {metric}; expected {units.DURATION_EXPECTED}")
                if not latency and isinstance(given, str):
                    raise ValueError(f"{bound}: {metric or 'this metric'} is a count; expected a number, got {given!r}")
        return value

    def _after(self, written: Any, context: Context) -> None:
        if self.max is None and self.min is None:
            raise ValueError("an expectation needs max, min or both")
        for name, bound in (("min", self.min), ("max", self.max)):
            if bound is None:
                continue
            if not math.isfinite(bound):
                raise ValueError(f"{name}: {bound!r} is not a finite number")
            fig = metric_figure(self.metric)
            if bound < 0 and not fig.signed:
                raise ValueError(f"{name}: {self.describe_bound(bound)} is negative; {self.metric.value} is never below 0")
            if fig.is_duration and abs(bound) > MAX_LATENCY_LIMIT:
                raise ValueError(
                    f"{name}: {units.format_duration(int(bound))} is too large for a latency bound; "
                    f"at most {units.format_duration(MAX_LATENCY_LIMIT)}"
                )
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"min {self.describe_bound(self.min)} is above max {self.describe_bound(self.max)}; no run can meet both")

    def describe_bound(self, value: float) -> str:
        """A bound as written back: a duration for latency metrics, a number otherwise."""
        return units.format_duration(int(value)) if metric_figure(self.metric).is_duration else f"{value:g}"

    def describe_limit(self) -> str:
        parts = []
        if self.min is not None:
            parts.append(f">= {self.describe_bound(self.min)}")
        if self.max is not None:
            parts.append(f"<= {self.describe_bound(self.max)}")
        return " and ".join(parts)


# ------------------------------------------------------------------------ samples


class SamplesMode(str, enum.Enum):
    """Which per-callback samples are written to samples.csv.gz (the figures always cover every callback)."""

    ALL = "all"
    NONE = "none"
    OUTLIERS = "outliers"  # callbacks that skipped releases, overran, or woke later than latency_bound
    LAST = "last"  # the last N callbacks of each thread


SAMPLES_EXPECTED = "all, none, outliers or 'last N'"


def _samples_text(value: Any) -> Any:
    if isinstance(value, str):
        word, _, count = value.strip().partition(" ")
        if word == "last":
            try:
                n = units.parse_whole(count, -(1 << 63), (1 << 63) - 1)  # ASCII digits, bounded; the field checks the range
                return {"mode": "last", "last": n}
            except units.UnitError:
                raise ValueError(f"samples {value!r}: expected 'last N' with a whole number N, e.g. 'last 10000'") from None
        return {"mode": word}
    if not isinstance(value, (dict, Samples)):  # null, a number: the model's own message would name its class
        raise ValueError(f"samples {'null' if value is None else repr(value)}: expected {SAMPLES_EXPECTED}")
    return value


class Samples(Strict):
    """What goes to the samples file: `all`, `none`, `outliers` or `last N`."""

    mode: SamplesMode = SamplesMode.ALL
    last: Optional[int] = Field(default=None, ge=1, le=MAX_LAST_SAMPLES, description="with mode last: how many callbacks per thread")

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _samples_text(value)

    def _after(self, written: Any, context: Context) -> None:
        if (self.mode is SamplesMode.LAST) != (self.last is not None):
            raise ValueError("write 'last N' (e.g. 'last 10000'); N goes only with last")

    def label(self) -> str:
        return f"last {self.last}" if self.mode is SamplesMode.LAST else self.mode.value


SamplesSetting = Annotated[
    Samples,
    Written(
        dump=Samples.label,
        schema=text_schema(
            "^(all|none|outliers|last [1-9][0-9]*)$",
            SAMPLES_EXPECTED,
            description="per-callback samples to write: all, none, outliers or last N",
            examples=["all", "outliers", "last 10000"],
        ),
    ),
]


# ----------------------------------------------------------------------- scenario


def _duration_range(value: int) -> int:
    if not MIN_RUN <= value <= MAX_RUN:
        raise ValueError(
            f"duration {units.format_duration(value)} is out of range; expected "
            f"{units.format_duration(MIN_RUN)} to {units.format_duration(MAX_RUN)}"
        )
    return value


RESOURCE_NAME_WORDS = "letters, digits and _ . - (64 at most), starting with a letter or _"


def _resource_names(value: dict[str, Resource]) -> dict[str, Resource]:
    for name in value:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}", name):
            raise ValueError(f"resource name {name!r} may use {RESOURCE_NAME_WORDS}")
    return value


def _bound_range(value: int) -> int:
    if not 0 < value <= MAX_LATENCY_LIMIT:
        raise ValueError(f"latency_bound {units.format_duration(value)} is out of range; expected above 0 and at most 1h")
    return value


SCENARIO_NAME_WORDS = "letters, digits and _ . + - only (it names a results folder)"


def _scenario_name(value: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9_.+-]+", value):
        raise ValueError(f"name {value!r} may use {SCENARIO_NAME_WORDS}")
    return value


class Scenario(Strict):
    """One fully resolved scenario (a matrix cell): what to spawn, for how long, and what to expect."""

    name: str = Field(description="scenario name; default: the file name without .yaml", check=_scenario_name)
    description: str = Field(
        default="", description="what the scenario reproduces and the effect to expect", check=_no_control("description", "\n\t")
    )
    duration: Duration = Field(default=10_000_000_000, description="run time of each cell (the CLI can override)", check=_duration_range)
    processes: list[AnyProcess] = Field(min_items=1, description="the runner's own processes (threads:) and the user's programs (command:)")
    background: Background = Field(default_factory=Background)
    matrix: Any = Field(default=None, description="axes, include and exclude as in GitHub Actions strategy.matrix")
    expect: list[Expectation] = Field(default_factory=list)
    latency_bound: Optional[Duration] = Field(
        default=None,
        description="wake-up latency above which a release counts as an outlier (figure latency.above_bound; samples: outliers)",
        check=_bound_range,
    )
    samples: SamplesSetting = Field(default_factory=Samples, description="per-callback samples to write: all, none, outliers or last N")
    resources: dict[str, Resource] = Field(
        default_factory=dict,
        description="mutexes, conditions, barriers, queues and named timers the threads' events share, by name",
        check=_resource_names,
    )

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave `latency_bound` and `samples` out while unset, so a cell's spec hash reads as before they existed."""
        if self.latency_bound is None:
            data.pop("latency_bound", None)
        if self.samples.mode is SamplesMode.ALL:
            data.pop("samples", None)
        if not self.resources:
            data.pop("resources", None)
        return data

    @property
    def workers(self) -> list[ProcessSpec]:
        """The processes that run the runner's own threads."""
        return workers(self.processes)

    @property
    def programs(self) -> list[ProgramSpec]:
        """The processes that run the user's programs."""
        return [p for p in self.processes if isinstance(p, ProgramSpec)]


def workers(processes: list[ProcessSpec | ProgramSpec]) -> list[ProcessSpec]:
    """The processes of a list that run the runner's own threads (programs left out)."""
    return [p for p in processes if isinstance(p, ProcessSpec)]
