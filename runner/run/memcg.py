"""A memory limit for a program: a memory cgroup of its own, under the runner's, as systemd's MemoryMax= or docker --memory.

The program is moved into it while it waits at its gate before exec, so it and every
thread and child it creates are charged there.  The kernel reclaims the group's memory
as it nears the limit and, when it cannot, its OOM killer ends a task of the group; the
group's own counters say how high it went and how many tasks the OOM killer took.  The
limit is read back from the cgroup's file after it is written, never echoed.

cgroup v2 (`memory.max`, `memory.peak`, `memory.events`) is used where the runner's cgroup
has the memory controller and can hand it to a child; a v1 memory hierarchy
(`memory.limit_in_bytes`, `memory.max_usage_in_bytes`, `memory.oom_control`) otherwise.
Folders are named `runner-<pid>-ns<inode>-<program>`, the runner's PID and its PID namespace;
those of runners that died without removing theirs are emptied (SIGKILL) and removed by the next
`create` (a cgroup without tasks is removed by rmdir).  A PID says whether its runner lives only
in the namespace it was given in: runners in containers, or started with `unshare --pid`, share
the cgroup folder of the shell or service that started them, and one that saw no process with
another's PID killed that live runner's programs.  So only folders of the sweeper's own PID
namespace whose PID is not a live process are swept; a folder of another namespace (or of an
older runner, whose name says none) is left to the runners of its namespace and its guard.  A
folder is made 0755 whatever the umask (FOLDER_MODE): one that others may write could be
given a cgroup of theirs inside it, and a cgroup with a child is never removed.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import time
from dataclasses import dataclass
from typing import Optional

_STALE = re.compile(r"runner-(\d+)-ns(\d+)-")
REMOVE_WAIT_S = 0.5  # a killed group's last tasks leave it within this
FOLDER_MODE = 0o755  # the runner's alone to write (its files, cgroup.procs among them, are the kernel's 0644)


@dataclass(frozen=True)
class Hierarchy:
    """Where the runner's memory cgroup is: its folder, and which cgroup version it is."""

    version: int  # 1 or 2
    folder: str

    @property
    def limit_file(self) -> str:
        return "memory.max" if self.version == 2 else "memory.limit_in_bytes"

    @property
    def peak_file(self) -> str:
        return "memory.peak" if self.version == 2 else "memory.max_usage_in_bytes"

    @property
    def events_file(self) -> str:
        return "memory.events" if self.version == 2 else "memory.oom_control"


def _mounts(mountinfo: str) -> list[tuple[str, str, str, set[str]]]:
    """(root, mount point, fs type, super options) of each mount in /proc/self/mountinfo's text."""
    out = []
    for line in mountinfo.splitlines():
        fields = line.split()
        if "-" not in fields:
            continue
        dash = fields.index("-")
        if dash < 5 or len(fields) < dash + 4:
            continue
        root, point = fields[3], fields[4].replace("\\040", " ")
        out.append((root, point, fields[dash + 1], set(fields[dash + 3].split(","))))
    return out


def _inside(point: str, root: str, path: str) -> Optional[str]:
    """The folder of cgroup `path` under a mount of the hierarchy's `root` at `point`; None when the mount does not show it."""
    if root != "/" and path != root and not path.startswith(root.rstrip("/") + "/"):
        return None
    rel = path[len(root) :] if root != "/" else path
    return os.path.normpath(os.path.join(point, rel.lstrip("/")))


def locate(mountinfo: str, self_cgroup: str) -> list[Hierarchy]:
    """The runner's memory cgroup folders, v2 first, from /proc/self/mountinfo and /proc/self/cgroup (pure: no files read)."""
    paths: dict[str, str] = {}  # "2" or the v1 controllers' name list -> path
    for line in self_cgroup.splitlines():
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        if parts[0] == "0" and parts[1] == "":
            paths["2"] = parts[2]
        elif "memory" in parts[1].split(","):
            paths["1"] = parts[2]
    found = []
    for root, point, fstype, options in _mounts(mountinfo):
        if fstype == "cgroup2" and "2" in paths:
            folder = _inside(point, root, paths["2"])
            if folder is not None:
                found.append(Hierarchy(2, folder))
        elif fstype == "cgroup" and "memory" in options and "1" in paths:
            folder = _inside(point, root, paths["1"])
            if folder is not None:
                found.append(Hierarchy(1, folder))
    return sorted(found, key=lambda h: -h.version)


def _read(path: str) -> str:
    with open(path) as handle:
        return handle.read()


def _write(path: str, text: str) -> None:
    """Write a control file of a cgroup: one that is there (never made) and not a link."""
    fd = os.open(path, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        os.write(fd, text.encode())
    finally:
        os.close(fd)


def _usable(h: Hierarchy) -> str:
    """'' when a child of `h` can have its own memory limit, else why not, in words."""
    if not os.path.isdir(h.folder):
        return f"{h.folder} is not there"
    if h.version == 1:
        return "" if os.access(h.folder, os.W_OK) else f"{h.folder} is not writable by this user"
    try:
        if "memory" not in _read(os.path.join(h.folder, "cgroup.controllers")).split():
            return f"the memory controller is not enabled for {h.folder}"
        control = os.path.join(h.folder, "cgroup.subtree_control")
        if "memory" not in _read(control).split():
            _write(control, "+memory")
    except OSError as error:
        return (
            f"{h.folder} cannot hand the memory controller to a child ({error.strerror}: cgroup v2 allows it only in a "
            "cgroup without processes of its own); start the runner in a delegated cgroup, e.g. "
            "`systemd-run --scope -p Delegate=yes runner ...`"
        )
    return ""


def hierarchy(limit: bool = True) -> tuple[Optional[Hierarchy], str]:
    """The hierarchy a program's memory limit goes in, or (None, why there is none) in words.

    Without `limit`, one that only has to hold the program's processes (a leash: no controller
    needed, so cgroup v2 serves even where it cannot limit memory, as on hybrid machines).
    """
    try:
        found = locate(_read("/proc/self/mountinfo"), _read("/proc/self/cgroup"))
    except OSError as error:
        return None, f"the runner's cgroups cannot be read ({error.strerror})"
    if not found:
        return None, "this machine has no cgroup the runner is in (neither cgroup v2 nor a v1 memory hierarchy is mounted)"
    reasons = []
    for h in found:
        why = _usable(h) if limit else _holds(h)
        if not why:
            return h, ""
        reasons.append(f"cgroup v{h.version}: {why}")
    return None, "; ".join(reasons)


def _holds(h: Hierarchy) -> str:
    """'' when the runner may make a child of `h` to hold processes, else why not."""
    if not os.path.isdir(h.folder):
        return f"{h.folder} is not there"
    return "" if os.access(h.folder, os.W_OK) else f"{h.folder} is not writable by this user"


def pid_namespace() -> int:
    """The inode of this process's PID namespace (the same number in every namespace that looks at it); 0 if unknown."""
    try:
        return os.stat("/proc/self/ns/pid").st_ino
    except OSError:
        return 0


def _remove_stale(h: Hierarchy, owner: Optional[int] = None) -> None:
    """Remove the cgroups of runners of this PID namespace that died without removing theirs, killing what they still
    hold (and their guard missed); the module's docstring says why no other.  `owner`: only the cgroups named for
    that PID (tests, which must not sweep those of other runners on the machine)."""
    ours = pid_namespace()
    for name in os.listdir(h.folder):
        match = _STALE.match(name)
        if match is None or not ours or int(match[2]) != ours or (owner is not None and int(match[1]) != owner):
            continue
        if not os.path.exists(f"/proc/{match[1]}"):
            kill_all(os.path.join(h.folder, name))
            remove(os.path.join(h.folder, name))


@dataclass
class MemoryCgroup:
    """One program's memory cgroup: created with its limit, given the program, read, removed."""

    hierarchy: Hierarchy
    folder: str

    @classmethod
    def create(cls, h: Hierarchy, name: str, limit: Optional[int]) -> MemoryCgroup:
        """A new cgroup `runner-<pid>-ns<inode>-<name>` with `limit` bytes (None: no limit, it only holds); OSError when
        the kernel refuses."""
        _remove_stale(h)
        own = f"runner-{os.getpid()}-ns{pid_namespace()}"
        folder = os.path.join(h.folder, f"{own}-{name}")
        for n in itertools.count(2):  # an earlier cell's group still leaving, or another of the same name: a name of its own
            try:
                os.mkdir(folder, FOLDER_MODE)  # never more than 0755, whatever the umask (it can only take bits away)
                break
            except FileExistsError:
                if n > 100:
                    raise
                folder = os.path.join(h.folder, f"{own}-{name}-{n}")
        group = cls(h, folder)
        try:
            os.chmod(folder, FOLDER_MODE)  # and exactly 0755 under a umask that took more
            if limit is not None:
                _write(os.path.join(folder, h.limit_file), str(limit))
        except OSError:
            group.remove()
            raise
        return group

    def add(self, pid: int) -> None:
        _write(os.path.join(self.folder, "cgroup.procs"), str(pid))

    def processes(self) -> list[int]:
        """The processes in the group now (its program and all they started, in the kernel's order); [] once gone."""
        try:
            return [int(n) for n in _read(os.path.join(self.folder, "cgroup.procs")).split()]
        except (OSError, ValueError):
            return []

    def limit(self) -> Optional[int]:
        """The limit as the kernel holds it (rounded down to pages); None when unlimited or unreadable."""
        try:
            text = _read(os.path.join(self.folder, self.hierarchy.limit_file)).strip()
        except OSError:
            return None
        return None if text == "max" or not text.isdigit() or int(text) >= 1 << 62 else int(text)

    def peak(self) -> Optional[int]:
        """The most memory the group was charged with (memory.peak needs Linux 5.19 on cgroup v2)."""
        try:
            return int(_read(os.path.join(self.folder, self.hierarchy.peak_file)))
        except (OSError, ValueError):
            return None

    def oom_kills(self) -> Optional[int]:
        """Tasks of the group the OOM killer ended (Linux 4.13 and later)."""
        try:
            for line in _read(os.path.join(self.folder, self.hierarchy.events_file)).splitlines():
                key, _, value = line.partition(" ")
                if key == "oom_kill":
                    return int(value)
        except (OSError, ValueError):
            return None
        return None

    def kill_all(self) -> None:
        """SIGKILL every task still in the group: what the program started and left behind, even outside its process group."""
        kill_all(self.folder)

    def remove(self) -> None:
        """rmdir, once its last task has left (a killed program's group empties within moments)."""
        remove(self.folder)


def kill_all(folder: str) -> None:
    """SIGKILL every task in the cgroup at `folder`, and wait (REMOVE_WAIT_S at most) until none is left.

    cgroup v2's `cgroup.kill` (Linux 5.14) has the kernel do it at once, a task forking as it is
    killed included; elsewhere each task listed is killed, again while new ones appear.
    """
    until = time.monotonic() + REMOVE_WAIT_S
    try:
        _write(os.path.join(folder, "cgroup.kill"), "1")
        killed = True
    except OSError:
        killed = False  # cgroup v1, or before Linux 5.14
    while True:
        try:
            pids = [int(p) for p in _read(os.path.join(folder, "cgroup.procs")).split()]
        except (OSError, ValueError):
            return
        for pid in [] if killed else pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        if not pids or time.monotonic() >= until:
            return
        time.sleep(0.005)


def remove(folder: str) -> None:
    """rmdir the cgroup at `folder` once its last task has left (killed tasks leave within moments)."""
    until = time.monotonic() + REMOVE_WAIT_S
    while True:
        try:
            os.rmdir(folder)
            return
        except FileNotFoundError:
            return
        except OSError:
            if time.monotonic() >= until:
                return
            time.sleep(0.01)
