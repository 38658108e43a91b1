"""Errors a user can act on, and the exit codes they map to.

Every user mistake is a `RunnerError` subclass carrying what the CLI prints; the
CLI never shows a traceback for one.  A bug in the runner is not a RunnerError and
keeps its traceback, so it gets reported instead of hidden.
"""

from __future__ import annotations

import difflib
import enum
from dataclasses import dataclass
from typing import Iterable


class ExitCode(enum.IntEnum):
    """The runner's exit codes, decided here and nowhere else."""

    OK = 0
    EXPECTATION_FAILED = 1
    INVALID_INPUT = 2
    PERMISSION = 3
    RUN_ERROR = 4
    INTERRUPTED = 130


@dataclass(frozen=True, order=True)
class Problem:
    """One problem in an input file: where it is, which key, what is wrong and what is expected."""

    file: str
    line: int
    col: int
    path: str
    message: str
    severity: str = "error"

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}:{self.col}"
        label = "" if self.severity == "error" else f"{self.severity}: "
        key = f"{self.path}: " if self.path else ""
        return f"{where}: {label}{key}{self.message}"


class RunnerError(Exception):
    """Base of every error caused by input or environment rather than by a runner bug."""

    exit_code: ExitCode = ExitCode.RUN_ERROR


class ScenarioError(RunnerError):
    """A scenario file (or results file) that cannot be used; carries every problem found."""

    exit_code = ExitCode.INVALID_INPUT

    def __init__(self, problems: Iterable[Problem]):
        self.problems = sorted(set(problems))
        super().__init__("\n".join(str(p) for p in self.problems))


class UsageError(RunnerError):
    """A command line or environment mistake that is not tied to a line of a file."""

    exit_code = ExitCode.INVALID_INPUT


class PermissionProblem(RunnerError):
    """The scenario asks for something this user may not do; the message says how to grant it."""

    exit_code = ExitCode.PERMISSION


class RunError(RunnerError):
    """A run that could not be carried out (a worker that died, a timeout)."""

    exit_code = ExitCode.RUN_ERROR


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """Return ` (did you mean 'x'?)` for the closest choice, or an empty string."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""
