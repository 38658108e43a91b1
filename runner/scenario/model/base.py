"""The ground every scenario model stands on: the ceilings, values written with units, the strict base.

Ceilings no real scenario comes near turn absurd input into a message that names the bound;
`Duration`, `Size` and `CpuSet` read values as people write them (`2ms`, `50MiB`, `0-3`);
`Strict` refuses unknown keys (with rt-app's and cyclictest's words explained) and freezes.
"""

from __future__ import annotations

import os
import unicodedata
from typing import Annotated, Any, Optional

from runner import units
from runner.scenario.model.vocabulary import PEER_WORDS
from runner.scenario.typed import Context, Model, Written, text_schema

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


DURATION_SCHEMA = {
    "anyOf": [text_schema(units.DURATION_PATTERN, units.DURATION_EXPECTED), {"const": 0}],
    "examples": ["100ms", "40ms", "1.5s"],
}
SIZE_SCHEMA = text_schema(units.SIZE_PATTERN, units.SIZE_EXPECTED, examples=["50MiB", "200KiB"])
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


Duration = Annotated[int, Written(_unit(units.parse_duration), units.format_duration, DURATION_SCHEMA)]
"""A duration in nanoseconds, written with a unit (`100ms`)."""

Size = Annotated[int, Written(_unit(units.parse_size, MAX_ANY_SIZE, units.format_size), units.format_size, SIZE_SCHEMA)]
"""A size in bytes, written with a unit (`50MiB`)."""

CpuSet = Annotated[tuple[int, ...], Written(_cpus, units.format_cpus, _CPUS_SCHEMA)]
"""A set of CPU numbers, written as a list, a cpulist `0-1,3` / `0-7:2` / `all`, or a mask `0b1100`."""


class Strict(Model):
    """Base of every scenario model: unknown keys are errors, objects are immutable."""

    @classmethod
    def _peer_word(cls, key: str) -> Optional[tuple[Optional[str], str]]:
        """What `key`, unknown here, means in this model when it is a word of rt-app's or cyclictest's (`PEER_WORDS`)."""
        return PEER_WORDS.get(cls.__name__, {}).get(key)
