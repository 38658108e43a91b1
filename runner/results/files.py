"""The results folder on disk: cell folder names, atomic writes, and the rule that stored paths stay inside it."""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import stat
import tempfile
from typing import Any

INT64 = 2**63


SLUG_MAX = 120  # characters of the readable part; a file name stays well under NAME_MAX (255 bytes)
JOURNAL = "cells.jsonl"  # beside results.json: the cells a run finished since it last wrote results.json whole (results/journal.py)
_UNSAFE = re.compile(r"[^A-Za-z0-9_.=,+-]")


def slug(exact: str) -> str:
    """A file-system safe name that stands for `exact` alone: deterministic, injective, bounded.

    An id that is already a safe name (letters, digits and `_.=,+-`, not starting with a dot,
    at most SLUG_MAX characters) is its own name, so folders read as the cell ids they hold.
    Any other id keeps a readable version (unsafe characters as `_`, cut to SLUG_MAX) and adds
    `~` and a hash of the exact id: `a/b`, `a_b` and `a:b` get three folders, never one.
    Names of the first kind never contain `~`, so the two kinds cannot meet.
    """
    if exact and len(exact) <= SLUG_MAX and not exact.startswith(".") and not _UNSAFE.search(exact):
        return exact
    readable = _UNSAFE.sub("_", exact)[:SLUG_MAX].lstrip(".") or "_"
    digest = hashlib.sha256(exact.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return f"{readable}~{digest}"


def cell_dir(cell_id: str, repeat: int, repeated: bool) -> str:
    """A cell run's folder, relative to the results folder: `cells/<id>`, or `cells/<id>/repeat-<n>` with repeats."""
    base = os.path.join("cells", slug(cell_id))
    return os.path.join(base, f"repeat-{repeat + 1}") if repeated else base


def results_file(path: str) -> str:
    """The results.json that `path` names: the file itself, or the one inside a results folder."""
    return os.path.join(path, "results.json") if os.path.isdir(path) else path


def _umask() -> int:
    """The process umask, read without changing it (Linux reports it in /proc/self/status)."""
    try:
        with open("/proc/self/status", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)  # at import, before any thread of ours exists: not racy in practice
    os.umask(old)
    return old


FILE_MODE = 0o666 & ~_umask()  # what open() would give a new file: output files are ordinary files


def write_atomic(path: str, data: str | bytes) -> None:
    """Write `data` to `path` so that readers see the old or the new file, never half of one.

    The new file gets the mode any new file would get (0666 less the umask), not mkstemp's 0600.
    On failure (a full disk, a read-only or forbidden folder) the old file is untouched, no
    temporary file is left behind, and the OSError raised names `path`, for the caller to word.
    A symbolic link stays a link: the file it points to is written.  A device, FIFO or socket
    (`/dev/null`, `/dev/stdout`, a named pipe) is written into as it is, never replaced by a
    regular file: renaming over `/dev/null` as root would replace the machine's own.
    """
    blob = data.encode("utf-8") if isinstance(data, str) else data
    if written_through(path):
        try:
            with open(path, "ab") as handle:  # append: `>> log` behind /dev/stdout keeps what it holds
                handle.write(blob)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), path) from exc
        return
    target = os.path.realpath(path)
    folder = os.path.dirname(target)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=folder)
        with os.fdopen(fd, "wb") as handle:
            os.fchmod(handle.fileno(), FILE_MODE)
            handle.write(blob)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
        tmp = None
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), path) from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    sync_folder(folder)


def written_through(path: str) -> bool:
    """Whether `path` is to be written into, never replaced: a device, FIFO or socket, or one of this process's
    descriptors (`/dev/stdout`, `/dev/fd/N`), whatever it is open on (a pipe, a file the shell opened)."""
    if path in ("/dev/stdout", "/dev/stderr") or path.startswith(("/dev/fd/", "/proc/")):
        return True
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False  # absent (to be made), or the write names the problem
    return stat.S_ISCHR(mode) or stat.S_ISBLK(mode) or stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)


def sync_folder(folder: str) -> None:
    """Make a rename or a new file in `folder` durable (best effort: some file systems cannot fsync a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def samples_path_problem(relative: str | None, folder: str) -> str:
    """Why a stored samples path may not be followed ("" when it may): it must stay in `folder`.

    Pure (no file access): absolute paths and `..` that climbs out are refused here; a symlink
    that leads out is caught when the file is about to be opened (`RunDocument.samples_path`).
    """
    if not relative:
        return ""
    expected = f"expected a path inside {folder or os.curdir}"
    if "\x00" in relative:
        return f"contains a NUL character; {expected}"
    if os.path.isabs(relative):
        return f"{relative!r} is an absolute path; {expected}"
    if os.path.normpath(relative).split(os.sep)[0] == os.pardir:
        return f"{relative!r} leaves the results folder; {expected}"
    return ""


def show_value(value: Any) -> str:
    """A value as a message quotes it: repr, or `dict of 3`, cut to 60 characters."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value).bit_length() > 64 * 8:
        return f"an integer of about {int(abs(value).bit_length() * 0.30103) + 1:,} digits"  # repr refuses past 4,300 digits
    text = repr(value) if not isinstance(value, (dict, list)) else f"{type(value).__name__} of {len(value)}"
    return text if len(text) <= 60 else text[:57] + "..."
