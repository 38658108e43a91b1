"""Every file and folder the runner writes, made without following a link it did not make.

A results folder can come from anywhere: a CI artifact downloaded and unpacked, a colleague's
copy, a folder another user can write.  A link inside it (`report.md -> /etc/passwd`, `plots ->
/usr/bin`, a dangling `results.json -> /root/.bashrc`) must never carry the runner's writes out
of it, least of all when it runs as root.  So every write of the runner goes through here:

- `write_atomic(path, data)`: a new temporary file made beside `path` (O_EXCL|O_NOFOLLOW, by
  mkstemp: never an existing file, never what a link names), synced, then renamed onto `path`;
  a rename replaces the name itself, never what a link of that name points to.
- `open_write(path, flags)`: os.open with O_NOFOLLOW|O_CLOEXEC, refused unless what it opened
  is a regular file (opened with O_NONBLOCK, so a FIFO planted there never blocks the open).
- `make_folders(root, relative)`: `root` as the user named it, made if absent (a link at or
  above it is the user's choice: `--out` through a symlinked home); each folder below it the
  runner makes with mkdir, or finds, must be a folder, never a link.
- `copy_file(source, target)`: `write_atomic` of a file's content, streamed.
- `write_named(path, data)`: a file the user named on the command line (`-o FILE`, `--junit
  FILE`), by the rule docs/permissions.md states under "Files the runner writes": a link there is refused as
  anywhere else, except the paths of the runner's own descriptors (`/dev/stdout`, `/dev/fd/N`),
  which are written into; so is a device or FIFO named as it is (`/dev/null`, a named pipe).

Paths, not descriptors of each folder (openat with dir_fd), are what these take: a folder below the
results folder is checked as the runner makes or enters it, files are made new (O_EXCL) or opened
with O_NOFOLLOW, and renames replace names; a link swapped in between would need someone who may
write the results folder already, who could change the results themselves.

A link (or a FIFO, device or socket where a regular file is written, or a file of several names
where one is written into) is refused with an OSError naming the path: errno ELOOP for a link,
EINVAL or EMLINK for the others, worded by `errors.from_os_error`,
which also decides the exit code (2 before a run, 4 once it ran).  Only the standard library is
imported: the guard (runner/run/guard.py) writes through here too.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Iterable

LINK_WORDS = "a symbolic link, which the runner never writes through"
_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


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


def link_refused(path: str) -> OSError:
    """The error for a link found where the runner would write."""
    return OSError(errno.ELOOP, LINK_WORDS, path)


def _kind(mode: int) -> str:
    """What a file that is neither a regular file nor a folder is, in words ("" for those two)."""
    return next((words for test, words in _KINDS if test(mode)), "")


def check_target(path: str) -> None:
    """Refuse (OSError naming `path`) what stands at `path` unless it is nothing yet or a regular file.

    A link is refused, not followed nor replaced; a folder, FIFO, device or socket too: the
    runner replaces only regular files in the folders it writes.
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISLNK(mode):
        raise link_refused(path)
    if stat.S_ISDIR(mode):
        raise OSError(errno.EISDIR, "Is a directory", path)
    if not stat.S_ISREG(mode):
        raise OSError(errno.EINVAL, f"{_kind(mode)}, not a regular file, which the runner does not write into here", path)


def open_write(path: str, flags: int = os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode: int = 0o666) -> int:
    """os.open(path, flags) for writing a regular file, never through a link (O_NOFOLLOW) nor into anything else.

    Opened with O_NONBLOCK, so a FIFO found there (no reader: ENXIO) or one with a reader does not
    hold the runner up; what was opened is checked to be a regular file of one name (a hard link
    planted in an unpacked archive, as root, could be any file of the machine), and only then
    truncated (O_TRUNC) and O_NONBLOCK taken off.
    """
    check_target(path)  # refuse before the open: opening a device can do something of its own
    try:
        fd = os.open(path, (flags & ~os.O_TRUNC) | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP:  # a link made since the check
            raise link_refused(path) from None
        if exc.errno == errno.ENXIO:  # a FIFO without a reader, made since the check
            check_target(path)
        raise
    try:
        found = os.fstat(fd)
        if not stat.S_ISREG(found.st_mode):
            raise OSError(errno.EINVAL, f"{_kind(found.st_mode)}, not a regular file, which the runner does not write into here", path)
        if found.st_nlink > 1:
            raise OSError(errno.EMLINK, f"a file of {found.st_nlink} names (hard links), which the runner does not write into", path)
        if flags & os.O_TRUNC:
            os.ftruncate(fd, 0)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _folder_of(path: str) -> str:
    return os.path.dirname(path) or os.curdir


def write_atomic(path: str, data: str | bytes, mode: int = FILE_MODE) -> None:
    """Write `data` to `path` so that readers see the old or the new file, never half of one, nor a link's target.

    The new file gets `mode` (by default the mode any new file would get: 0666 less the umask,
    not mkstemp's 0600).  On failure (a full disk, a read-only or forbidden folder, a link at
    `path`) the old file is untouched, no temporary file is left behind, and the OSError raised
    names `path`, for the caller to word.
    """
    blob = data.encode("utf-8") if isinstance(data, str) else data
    _replace(path, [blob], mode)


def copy_file(source: str, target: str, mode: int = FILE_MODE) -> None:
    """Copy the regular file `source` to `target` as `write_atomic` writes (an OSError names whichever failed)."""
    try:
        handle = open(source, "rb")  # noqa: SIM115  # closed by the with below
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), source) from exc
    with handle:
        _replace(target, iter(lambda: handle.read(1 << 20), b""), mode)


def _replace(path: str, chunks: Iterable[bytes], mode: int) -> None:
    folder = _folder_of(path)
    tmp = None
    try:
        check_target(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=folder)  # O_EXCL|O_NOFOLLOW
        with os.fdopen(fd, "wb") as handle:
            os.fchmod(handle.fileno(), mode)
            for chunk in chunks:
                handle.write(chunk)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)  # replaces the name: a link put there since the check is replaced, never followed
        tmp = None
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), path) from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    sync_folder(folder)


def make_folders(root: str, relative: str = "") -> str:
    """Make `root` (as the user named it) and the folders of `relative` below it; return the path of the last.

    `root` is made with os.makedirs: links at and above it are the user's.  Each component of
    `relative` is made with mkdir (0777 less the umask, as any folder) or, when it is there, must be
    a folder and not a link: a link is refused (ELOOP), anything else too (ENOTDIR), before
    anything is made inside it.
    """
    try:
        os.makedirs(root, exist_ok=True)
    except FileExistsError:
        raise OSError(errno.ENOTDIR, "Not a directory", root) from None
    if not os.path.isdir(root):
        raise OSError(errno.ENOTDIR, "Not a directory", root)
    parts = [p for p in os.path.normpath(relative).split(os.sep) if p not in ("", os.curdir)] if relative else []
    if os.pardir in parts or os.path.isabs(relative):
        raise OSError(errno.EINVAL, "leaves the folder it is made in", os.path.join(root, relative))
    path = root
    for part in parts:
        path = os.path.join(path, part)
        make_folder(path)
    return path


def make_folder(path: str, mode: int = 0o777) -> None:
    """mkdir `path` unless a folder is there; a link there is refused (ELOOP), any other file too (ENOTDIR)."""
    try:
        os.mkdir(path, mode)
        return
    except FileExistsError:
        pass
    found = os.lstat(path).st_mode
    if stat.S_ISLNK(found):
        raise link_refused(path)
    if not stat.S_ISDIR(found):
        raise OSError(errno.ENOTDIR, "Not a directory", path)


def append(path: str, data: str | bytes) -> None:
    """Append `data` to the regular file `path` (made if absent), never through a link."""
    blob = data.encode("utf-8") if isinstance(data, str) else data
    fd = open_write(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, FILE_MODE)
    try:
        write_all(fd, blob)
    finally:
        os.close(fd)


def write_all(fd: int, blob: bytes) -> None:
    """os.write until all of `blob` is written."""
    view = memoryview(blob)
    while view:
        view = view[os.write(fd, view) :]


def own_descriptor(path: str) -> bool:
    """Whether `path` names one of this process's descriptors (`/dev/stdout`, `/dev/fd/1`, `/proc/self/fd/1`).

    The user's shell opened what these lead to (`> out.xml`, a pipe), so they are written into
    wherever they lead: the one case where the runner writes through a link (`/dev/stdout` is one).
    """
    if path in ("/dev/stdout", "/dev/stderr"):
        return True
    for prefix in ("/dev/fd/", "/proc/self/fd/", "/proc/thread-self/fd/", f"/proc/{os.getpid()}/fd/"):
        if path.startswith(prefix) and path[len(prefix) :].isdecimal():
            return True
    return False


def written_into(path: str) -> bool:
    """Whether a file the user named is written into where it is, never replaced: one of the runner's own
    descriptors (`own_descriptor`), or a device, FIFO or socket named as it is (not through a link)."""
    if own_descriptor(path):
        return True
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return False  # absent (to be made), or the write names the problem
    return bool(_kind(mode))


def write_named(path: str, data: str | bytes) -> None:
    """Write a file the user named (`-o FILE`, `--junit FILE`): made with its folders, or replaced, atomically.

    Written into, never replaced, when it is one of the runner's own descriptors or a device, FIFO or
    socket named as it is (`/dev/null` replaced by a regular file, as root, would be the machine's own):
    appended to, so `>> log` behind `/dev/stdout` keeps what it holds.  A link is refused as anywhere.
    """
    blob = data.encode("utf-8") if isinstance(data, str) else data
    if written_into(path):
        flags = os.O_WRONLY | os.O_APPEND | os.O_CLOEXEC | (0 if own_descriptor(path) else os.O_NOFOLLOW)
        try:
            fd = os.open(path, flags)
            try:
                write_all(fd, blob)
            finally:
                os.close(fd)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), path) from exc
        return
    check_target(path)
    os.makedirs(_folder_of(os.path.abspath(path)), exist_ok=True)  # the user's path: links above the file are theirs
    write_atomic(path, blob)


def sync_folder(folder: str) -> None:
    """Make a rename or a new file in `folder` durable (best effort: some file systems cannot fsync a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
