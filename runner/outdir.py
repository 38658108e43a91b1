"""An output folder held by one runner at a time.

A run (or a merge) writes results.json, samples and reports into one folder; two
runs writing into the same folder would mix their cells and share sample buffers.
`claim` creates the folder, refuses one that holds another run's results (unless
that run is being resumed), and holds an exclusive `flock` on a lock file inside
it for as long as the claim lives.  The kernel drops the lock when the process
dies, however it dies, so a crashed run never leaves its folder locked.

The folder itself is the user's to name, through links if they like (`--out ~/r` with a
symlinked home); inside it, a link where the run would write (results.json, the lock, the
journal, report.md, plots, cells) is refused before anything is written: a folder that came
from elsewhere must not carry the run's writes out of it (runner/safefs.py).
"""

from __future__ import annotations

import errno
import fcntl
import os
from dataclasses import dataclass
from typing import Optional

from runner.errors import UsageError, from_os_error
from runner.results.files import JOURNAL
from runner.safefs import LINK_WORDS, make_folders, open_write, own_descriptor, written_into

LOCK_NAME = ".runner.lock"
REPORT_NAME = "report.md"  # what a run or a merge writes beside its results
WRITTEN = ("results.json", JOURNAL, LOCK_NAME, REPORT_NAME, "comparison.md", "plots", "cells")  # what a run writes at the top


@dataclass
class Claim:
    """A folder this process writes into alone, until `release` (or its exit)."""

    folder: str
    fd: Optional[int]

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing the descriptor drops the flock
            self.fd = None


def claim(folder: str, what: str = "results folder", resume: bool = False) -> Claim:
    """Create `folder` if needed and hold it exclusively; raise a UsageError (exit 2) naming why not.

    A folder that already holds a results.json is refused unless `resume` is set: a new run
    into it would overwrite or mix with the results of an earlier one.  So is one that holds
    a report.md without results (the user's own, say): the run would replace it.
    """
    folder = os.path.abspath(folder)
    try:
        make_folders(folder)
    except OSError as exc:
        if exc.errno == errno.ENOTDIR:
            raise UsageError(f"runner: {what} {folder}: a file stands where a folder is expected") from None
        raise from_os_error(exc, what) from None
    links = [name for name in WRITTEN if os.path.islink(os.path.join(folder, name))]
    if links:  # refused before the lock is made: a dangling .runner.lock link would make its target
        shown = ", ".join(links)
        raise UsageError(
            f"runner: {what} {folder} holds {shown}, {LINK_WORDS}; remove {'it' if len(links) == 1 else 'them'}, or choose a new folder"
        )
    try:
        fd = open_write(os.path.join(folder, LOCK_NAME), os.O_RDWR | os.O_CREAT)
    except OSError as exc:
        raise from_os_error(exc, what) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise UsageError(f"runner: {what} {folder} is in use by another runner; give each run its own --out") from None
        raise from_os_error(exc, what) from None
    if not resume and os.path.exists(os.path.join(folder, "results.json")):
        os.close(fd)
        raise UsageError(
            f"runner: {what} {folder} already holds the results of another run; choose a new folder, or finish that run with --resume"
        )
    if not resume and os.path.lexists(os.path.join(folder, JOURNAL)):
        os.close(fd)  # its cells would be read as this run's
        raise UsageError(
            f"runner: {what} {folder} holds the cells journal ({JOURNAL}) of a run whose results.json is gone; choose a new folder"
        )
    if not resume and os.path.lexists(os.path.join(folder, REPORT_NAME)):
        os.close(fd)  # a run writes its report.md after its results.json: this one is not a run's
        raise UsageError(
            f"runner: {what} {folder} holds a {REPORT_NAME} of no run (no results.json beside it), which the run would replace; "
            "choose a new folder"
        )
    return Claim(folder, fd)


def is_results_file(path: str) -> bool:
    """Whether `path` is (or, by its name, would be) a results file or journal: results.json, cells.jsonl, or a file
    that starts as one does.  Links are followed: the file a link names is what a write would replace."""
    real = os.path.realpath(path)
    if os.path.basename(real) in ("results.json", "cells.jsonl"):
        return True
    if not os.path.isfile(real):  # a FIFO would block the open until something wrote to it
        return False
    try:
        with open(real, "rb") as handle:
            head = handle.read(256)
    except OSError:
        return False
    return b'"runner.results/' in head


def writable_file(path: str, option: str) -> str:
    """An output file an option names (`--junit FILE`), checked before anything runs: not a folder, and its folder
    either exists and may be written or can be created (as `--out` is) under one that may; else a UsageError (exit 2).

    Checked up front so a file that cannot be written is said at once, not after an hour of cells.
    A results file is never an output: `--junit DIR/results.json` would replace a run's only copy.
    """
    if is_results_file(path):
        raise UsageError(f"runner: {option} {path}: that is a results file, which only a run writes; choose another file")
    if os.path.islink(path) and not own_descriptor(path):  # a link planted in a downloaded folder must not lead the write
        raise UsageError(f"runner: {option} {path}: {LINK_WORDS}; name the file itself, or another path")
    if written_into(path):  # /dev/stdout, a device, a FIFO: written into where it is, no file made beside it
        return path
    if os.path.isdir(path):
        raise UsageError(f"runner: {option} {path}: a folder stands where a file is expected")
    if path.endswith(os.sep):  # no folder there yet: it would have been written as a file of that name
        raise UsageError(f"runner: {option} {path}: names a folder (it ends in {os.sep}); expected a file")
    folder = os.path.dirname(os.path.abspath(path))
    existing = folder
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise UsageError(f"runner: {option} {path}: {existing} is a file, not a folder; choose another path")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UsageError(f"runner: {option} {path}: the folder {existing} may not be written; choose a folder you may write")
    return path
