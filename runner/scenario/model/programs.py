"""A user's program (`command:`): its argv, environment, limits, when it ends, the rules for its threads.

`AnyProcess` is what a scenario's `processes:` list holds: the runner's own process or a
program, told apart by `command:`.
"""

from __future__ import annotations

import enum
import re
from typing import Annotated, Any, Optional, Union

from runner import units
from runner.scenario.model.base import OUTPUT_LIMIT, CpuSet, Duration, Size, Strict, control_character
from runner.scenario.model.sched import Policy, Sched
from runner.scenario.model.threads import ProcessSpec, check_comm
from runner.scenario.typed import Context, Field, KeyProblem, Schema, Tagged


def argv_list(key: str) -> Any:
    """A reader: `key` is a list of arguments, never a shell string (no shell runs it)."""

    def check(value: Any) -> Any:
        if isinstance(value, str):
            raise ValueError(f"{key} must be a list such as ['stress-ng', '--cpu', '2'], not the string {value!r} (no shell runs it)")
        return value

    return check


def argv_items(key: str) -> Any:
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

    name: str = Field(description="the process's label in reports and expectations (`name/thread`), 15 bytes at most", check=check_comm)
    command: list[str] = Field(
        min_items=1,
        before=argv_list("command"),
        check=argv_items("command"),
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
    callbacks: bool = Field(
        default=True,
        description="measure every ROS 2 callback of the program from inside it (the runner's libtracetools interposer, preloaded); "
        "off: the program runs without it",
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
