"""Errors a user can act on, and the exit codes they map to.

Every user mistake is a `RunnerError` subclass carrying what the CLI prints; the
CLI never shows a traceback for one.  An operating-system error the user can act on
(a folder that cannot be written, a full disk) becomes one through `from_os_error`.
A bug in the runner is neither: the CLI prints one line saying so, saves the
traceback to a file for the bug report, and exits with `INTERNAL_ERROR`.
"""

from __future__ import annotations

import enum
import errno
import os
import re
import stat
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any


class ExitCode(enum.IntEnum):
    """The runner's exit codes, decided here and nowhere else."""

    OK = 0
    EXPECTATION_FAILED = 1
    INVALID_INPUT = 2
    PERMISSION = 3
    RUN_ERROR = 4
    INTERNAL_ERROR = 70  # a bug in the runner (EX_SOFTWARE); the traceback is saved to a file
    INTERRUPTED = 130


QUOTE_KEEP = 80
"""Characters of a value a message quotes whole: a longer one keeps its first half and last quarter around `…`."""
MAX_MESSAGE = 4000  # a problem's message at most (the longest a runner writes lists 70 metric names, 1,066 characters)
MAX_PATH = 256  # a problem's key path at most


def shorten(text: str, keep: int = QUOTE_KEEP) -> str:
    """`text`, its middle cut out when it is longer than `keep` characters: `start…end` (a hostile value can be a megabyte)."""
    if len(text) <= keep:
        return text
    return text[: keep // 2] + "…" + text[-max(1, keep // 4) :]


def quoted(value: Any, keep: int = QUOTE_KEEP) -> str:
    """A value as a message quotes it: its repr, cut to `keep` characters (text is cut before it is quoted, so the quotes stay).

    An integer too long for repr (Python refuses more than 4,300 digits) is said by its size.
    """
    if isinstance(value, str):
        return repr(shorten(value, keep))
    if isinstance(value, int) and not isinstance(value, bool) and abs(value).bit_length() > 64 * 8:
        return f"an integer of about {int(abs(value).bit_length() * 0.30103) + 1:,} digits"
    return shorten(repr(value), keep)


# A quoted value in a message, as repr writes one: a quote where a word starts, then the same quote where it ends
# (an apostrophe inside a word, `thread's`, starts nothing), more than QUOTE_KEEP characters between.
_LONG_QUOTE = re.compile(r"""(?<![^\s(\[{=:,])(['"])((?:(?!\1)[^\\]|\\.){""" + str(QUOTE_KEEP + 1) + r""",}?)\1(?=$|[\s)\]},;:.!?])""")


def bounded(text: str, most: int) -> str:
    """`text` as a problem says it: each long quoted value cut to QUOTE_KEEP characters, and the whole to `most`.

    Every Problem passes here, so a value quoted whole by whatever raised it (a megabyte-long
    `sched:`, one long text aliased into a thousand places) prints as a line, not as megabytes.
    """
    if len(text) > QUOTE_KEEP:
        text = _LONG_QUOTE.sub(lambda m: m.group(1) + shorten(m.group(2)) + m.group(1), text)
    return shorten(text, most)


@dataclass(frozen=True, order=True)
class Problem:
    """One problem in an input file: where it is, which key, what is wrong and what is expected.

    Its message and key path are `bounded`: whatever a value holds, a problem is a readable line.
    """

    file: str
    line: int
    col: int
    path: str
    message: str
    severity: str = "error"

    def __post_init__(self) -> None:
        object.__setattr__(self, "message", bounded(self.message, MAX_MESSAGE))
        object.__setattr__(self, "path", bounded(self.path, MAX_PATH))

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
    """A command line or environment mistake that is not tied to a line of a file; its message is `bounded` as a problem's."""

    exit_code = ExitCode.INVALID_INPUT

    def __init__(self, message: str):
        super().__init__(bounded(message, MAX_MESSAGE))


class PermissionProblem(RunnerError):
    """The scenario asks for something this user may not do; the message says how to grant it."""

    exit_code = ExitCode.PERMISSION


class OutputError(RunnerError):
    """A file or folder the runner must write could not be written (permission, full disk, not a folder).

    During a run this is a run error (exit 4): what finished is kept, the cell in flight is
    marked `error`.  Before anything ran a path the user chose wrongly is an input mistake
    (exit 2), but a full disk never is, see `from_os_error`.
    """

    exit_code = ExitCode.RUN_ERROR


FULL_DISK = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})
"""Write errors that say the disk, not the path, is the problem: no space, a quota used up, the device failing.

Always a run error (exit 4), whatever was being written (results, journal, samples, report, plots,
an export, the --out folder itself) and whenever (before the first cell, during the run, after it):
the command and its paths were right, and the same command succeeds once there is room.  Invalid
input (exit 2) is what the user must change in the command: a path that is a file, a folder that
may not be written.  The run's own write errors (`session._run_units`) say 4 the same way.
"""


def output_hint(error_number: int | None) -> str:
    """What to do about an OSError writing a file, as the end of its one-line message ("" when there is nothing to add)."""
    return {
        errno.ENOSPC: "; the disk is full: free some space, or write somewhere else (another --out or file)",
        errno.EDQUOT: "; the disk quota is used up: free some space, or write somewhere else (another --out or file)",
        errno.EIO: "; the disk failed to write it (an I/O error): check the disk, or write somewhere else (another --out or file)",
        errno.EACCES: "; choose a folder you may write, or fix its permissions",
        errno.EROFS: "; choose a folder on a writable file system",
        errno.ENOTDIR: "; a file stands where a folder is expected",
        errno.EEXIST: "; a file of that name is in the way",
        errno.EISDIR: "; a folder stands where a file is expected",
        errno.ELOOP: ": remove the link, or choose another path (docs/permissions.md, 'Files the runner writes')",
        errno.EMLINK: ": remove it, or choose another path (docs/permissions.md, 'Files the runner writes')",
    }.get(error_number or 0, "")


def from_os_error(exc: OSError, what: str, before_run: bool = True, path: str | None = None) -> RunnerError:
    """A user-facing error for an OSError on a path the user chose: `runner: <what> <path>: <reason>; <what to do>`.

    `before_run` errors (an --out that is a file, an unwritable -o) are invalid input (exit 2);
    errors once measuring has started are run errors (exit 4), and so is a full disk at any time
    (`FULL_DISK`).  A link where the runner would write (ELOOP, or EMLINK for a hard link: runner/safefs.py)
    is invalid input at any time: the folder it is in must change, not the machine.  `path` names the file the user knows
    when the error came from a temporary one beside it.
    """
    path = path or (exc.filename if exc.filename is not None else "")
    message = f"runner: {what} {path}: {exc.strerror or exc}{output_hint(exc.errno)}"
    invalid = (before_run and exc.errno not in FULL_DISK) or exc.errno in (errno.ELOOP, errno.EMLINK)
    return UsageError(message) if invalid else OutputError(message)


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
    import difflib  # here: only a mistake needs it, and its import is a start's 2 ms

    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return close[0] if close else None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """Return ` (did you mean 'x'?)` for the closest choice, or an empty string."""
    close = closest(word, choices)
    return f"; did you mean {close!r}?" if close is not None else ""
