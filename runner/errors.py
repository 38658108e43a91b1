"""Errors a user can act on, and the exit codes they map to.

Every user mistake is a `RunnerError` subclass carrying what the CLI prints; the
CLI never shows a traceback for one.  An operating-system error the user can act on
(a folder that cannot be written, a full disk) becomes one through `from_os_error`.
A bug in the runner is neither: the CLI prints one line saying so, saves the
traceback to a file for the bug report, and exits with `INTERNAL_ERROR`.
"""

from __future__ import annotations

import difflib
import enum
import os
import stat
from collections.abc import Iterable
from dataclasses import dataclass


class ExitCode(enum.IntEnum):
    """The runner's exit codes, decided here and nowhere else."""

    OK = 0
    EXPECTATION_FAILED = 1
    INVALID_INPUT = 2
    PERMISSION = 3
    RUN_ERROR = 4
    INTERNAL_ERROR = 70  # a bug in the runner (EX_SOFTWARE); the traceback is saved to a file
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


class OutputError(RunnerError):
    """A file or folder the runner must write could not be written (permission, full disk, not a folder).

    During a run this is a run error (exit 4): what finished is kept, the cell in flight is
    marked `error`.  Before anything ran it is an input mistake (exit 2), see `from_os_error`.
    """

    exit_code = ExitCode.RUN_ERROR


def from_os_error(exc: OSError, what: str, before_run: bool = True, path: str | None = None) -> RunnerError:
    """A user-facing error for an OSError on a path the user chose: `runner: <what> <path>: <reason>`.

    `before_run` errors (an --out that is a file, an unwritable -o) are invalid input (exit 2);
    errors once measuring has started (a disk that fills up) are run errors (exit 4).  `path` names
    the file the user knows when the error came from a temporary one beside it.
    """
    path = path or (exc.filename if exc.filename is not None else "")
    reason = exc.strerror or str(exc)
    hint = {
        28: "; free some space or write somewhere else",  # ENOSPC: on --out, -o or --junit alike
        13: "; choose a folder you may write, or fix its permissions",  # EACCES
        30: "; choose a folder on a writable file system",  # EROFS
        20: "; a file stands where a folder is expected",  # ENOTDIR
        17: "; a file of that name is in the way",  # EEXIST
        21: "; a folder stands where a file is expected",  # EISDIR
    }.get(exc.errno or 0, "")
    error = UsageError(f"runner: {what} {path}: {reason}{hint}") if before_run else OutputError(f"runner: {what} {path}: {reason}{hint}")
    return error


def special_file(path: str) -> str:
    """What `path` is when it exists and is neither a file nor a folder ("a FIFO", "a character device"), else "".

    Reading one is never what a user meant: a named FIFO blocks until something writes to it, a
    device like /dev/zero never ends.  Readers of scenario and results files refuse these first.
    An anonymous pipe (a shell's `<(...)`, a pipe as /dev/stdin) has a writer already and is read.
    """
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return ""  # absent or unreadable: opening it says why
    if stat.S_ISFIFO(mode) and not os.path.exists(os.path.realpath(path)):
        return ""  # a pipe with a writer (`< file` as /dev/stdin, `<(zcat ...)` as /dev/fd/63): it has no name to block on
    kinds = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((words for test, words in kinds if test(mode)), "")


def closest(word: str, choices: Iterable[str]) -> str | None:
    """The choice `word` is probably a typo of, or None: what `did_you_mean` suggests."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return close[0] if close else None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """Return ` (did you mean 'x'?)` for the closest choice, or an empty string."""
    close = closest(word, choices)
    return f"; did you mean {close!r}?" if close is not None else ""
