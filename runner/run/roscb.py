"""The shell side of the libtracetools interposer: a program's capture file, its environment, and decoding the file.

The interposer (runner/run/roscb.c, built by `pip install` as runner/run/_roscb*.so) is
preloaded into a `command:` program (`callbacks:` on, the default) and writes what the
program's ROS 2 callbacks did into a file the runner made for that program alone
(`Capture`): per process a block, per thread a ring of records (layout: runner/run/roscb.h,
read here by field name from the native core's table, as runner/run/records.py reads the
sample buffer).  At the cell's end the runner decodes it into `roscbdata.RosCapture` and
removes it.

The runner reads the file with pread through the descriptor it made it with, never through a
mapping: the file is the program's memory too, and a program that truncates it (or a /dev/shm
with no room for a page a mapped read would allocate) would make a mapped read a SIGBUS that
kills the runner; pread reads what is gone as zeros.  Nothing read is trusted: sizes are this
runner's own, every offset is bounded, and a header that changes after the first read is
another layout.

Why a file in /dev/shm and not an inherited memfd: `ros2 run` starts the node with
`subprocess.run(..., close_fds=True)`, so a descriptor would not reach it; a path in the
environment does, through any number of execs and forks.  The file is new (O_EXCL), never
reached through a link (O_NOFOLLOW), its owner's alone (0600) and sparse: only the threads
and processes that reach a hook take memory (their ring or block, backed when they claim it).

Bounds (what one program's file can hold, whatever the program does):
- MAX_PROCS processes that reach a hook (later ones are counted as refused),
- MAX_THREADS threads that reach a hook (likewise),
- CAPACITY records per thread's ring: a thread that writes more between two drains (the runner
  drains once a second while the program runs, and at its end) loses its oldest, counted as lost,
- a 63.5 KiB string arena per process (names, topics, symbols; a full one is counted).
So the file is at most MAX_PROCS * 64 KiB + MAX_THREADS * (128 + CAPACITY * 96) bytes
(98 MiB with the defaults, sparse: each thread that reaches a hook takes its 1.5 MiB ring, a process
its 64 KiB block; where /dev/shm has no room for one, that thread or process is refused, counted) and the
records kept at most MAX_RECORDS (262,144: about 90 MB decoded) for the whole program: beyond, they
are counted lost (a 1 kHz timer that publishes keeps 65 s).
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import os
import secrets
import stat
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Optional, Union

from runner.run import _probe
from runner.run.records import RECORDS
from runner.run.roscbdata import (
    CallbackRecord,
    ClockType,
    Meta,
    MetaKind,
    ProcessFlag,
    PublishRecord,
    RosCapture,
    RosProcess,
    RosThread,
)

MAX_PROCS = 32
MAX_THREADS = 64
CAPACITY = 16384  # records per thread between two drains (the runner drains once a second)
MAX_RECORDS = 1 << 18  # records the runner keeps of one program, all threads together (about 350 B and 5 µs to decode each)
FOLDER = "/dev/shm"
ENV = "RUNNER_ROSCB"
PREFIX = "runner-roscb-"  # then the runner's PID: a file whose runner is gone is removed by the next (`sweep`)

FILE = RECORDS["roscb_file"]
PROC = RECORDS["roscb_proc"]
SLOT = RECORDS["roscb_slot"]
CALLBACK = RECORDS["roscb_callback"]
PUBLISH = RECORDS["roscb_publish"]
META = RECORDS["roscb_meta"]
RECORD_SIZE = CALLBACK.size
ARENA = _probe.ROSCB_PROC_BYTES - PROC.size
assert PUBLISH.size == META.size == RECORD_SIZE == 96, "the interposer's records are one size (roscb.h)"
assert all(getattr(_probe, f"ROSCB_META_{kind.name}") == kind.value for kind in MetaKind), "roscb.h's meta kinds are roscbdata's"

TYPE = struct.Struct("<H")
CALLBACK_TYPE, PUBLISH_TYPE = 1, 2
CB_INTRA, CB_TAKE, CB_UNTERMINATED, CB_RELEASE = 1, 2, 4, 8  # roscb.h ROSCB_CB_*
PUB_EXACT, PUB_RCL = 1, 2  # ROSCB_PUB_*
META_TRUNCATED = 1  # ROSCB_META_TRUNCATED
PROCESS_FLAGS = {  # ROSCB_P_*
    1: ProcessFlag.TRACETOOLS,
    2: ProcessFlag.ENABLED_API,
    4: ProcessFlag.PUBLISH_TIMESTAMP,
    8: ProcessFlag.SHADOWED,
    16: ProcessFlag.FORKED,
}
# what /proc/PID/maps may show of ROS 2 (by a file name's start), besides the interposer itself
ROS_LIBRARIES = ("librclcpp.so", "libtracetools.so", "librcl.so", "librmw_implementation.so", "librclpy")


def _library() -> str:
    here = os.path.dirname(os.path.abspath(__file__))
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = os.path.join(here, "_roscb" + suffix)
        if os.path.isfile(path):
            return path
    return ""


LIBRARY = _library()  # the built interposer; "" when the package was installed without it (then nothing is preloaded)


def file_size(max_procs: int, max_threads: int, capacity: int) -> int:
    """The bytes of a capture file of these bounds (sparse: most are never written)."""
    return FILE.size + max_procs * _probe.ROSCB_PROC_BYTES + max_threads * (SLOT.size + capacity * RECORD_SIZE)


@dataclass
class Capture:
    """One program's capture file while its cell runs: made before the program starts, removed at the cell's end.

    The runner keeps the descriptor it made the file with and reads through it, so the file
    it decodes is the one it made even if its name was replaced meanwhile.
    """

    path: str
    fd: int
    size: int
    loaded: Optional[bool] = None
    libraries: set[str] = field(default_factory=set)
    reader: Reader = field(default_factory=lambda: Reader())

    @classmethod
    def create(
        cls,
        name: str,
        owner: Optional[tuple[int, int]] = None,
        folder: str = FOLDER,
        max_procs: int = MAX_PROCS,
        max_threads: int = MAX_THREADS,
        capacity: int = CAPACITY,
    ) -> Capture:
        """A new file `runner-roscb-<runner's pid>-<name>-<random>` in `folder`, 0600, chowned to `owner` (uid, gid) for a
        program run as another user.  Files a killed runner left there are removed first (`sweep`)."""
        sweep(folder)
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)[:80]
        path = os.path.join(folder, f"{PREFIX}{os.getpid()}-{safe}-{secrets.token_hex(8)}")
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
        size = file_size(max_procs, max_threads, capacity)
        try:
            if owner is not None:
                os.fchown(fd, *owner)
            os.ftruncate(fd, size)
            header = {
                "magic": _probe.ROSCB_MAGIC,
                "version": _probe.ROSCB_VERSION,
                "header_size": FILE.size,
                "max_procs": max_procs,
                "max_threads": max_threads,
                "capacity": capacity,
                "record_size": RECORD_SIZE,
                "proc_size": _probe.ROSCB_PROC_BYTES,
                "slot_size": SLOT.size + capacity * RECORD_SIZE,
            }
            os.pwrite(fd, FILE.pack(header), 0)
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise
        return cls(path, fd, size)

    def environment(self, env: Mapping[str, str]) -> dict[str, str]:
        """`env` with the interposer preloaded after the user's own LD_PRELOAD, and the file's name for it."""
        return environment(env, self.path)

    def look(self, pids: Iterable[int]) -> None:
        """Note from /proc/PID/maps whether the interposer is mapped into these processes and which ROS 2 libraries are."""
        for pid in pids:
            found = mapped(pid)
            if found is None:
                continue
            ours = bool(LIBRARY) and LIBRARY in found
            self.loaded = bool(self.loaded) or ours
            self.libraries.update(os.path.basename(p) for p in found if is_ros_library(p) or p == LIBRARY)

    def drain(self) -> None:
        """Take the records the program wrote since the last drain, so a ring never has to hold a whole cell's."""
        with contextlib.suppress(OSError, ValueError, struct.error):
            self.reader.drain(FileView(self.fd, self.size))

    def read(self) -> RosCapture:
        """Everything taken from the file, drained once more, once the program is gone (a file of another layout: `error`
        says so)."""
        try:
            capture = self.reader.capture(FileView(self.fd, self.size))
        except (OSError, ValueError, struct.error) as error:
            capture = RosCapture(error=f"the capture file could not be read: {error}")
        return RosCapture(
            self.path,
            capture.processes,
            capture.processes_refused,
            capture.threads_refused,
            capture.error,
            self.loaded,
            tuple(sorted(self.libraries)),
        )

    def close(self) -> None:
        """Remove the file (whatever happened to the program) and close the descriptor; a second call does nothing.

        The name is removed only while it is still this file: a program may have put another file (its
        own) in its place, which is not the runner's to remove."""
        if self.fd >= 0:
            with contextlib.suppress(FileNotFoundError):
                mine, named = os.fstat(self.fd), os.lstat(self.path)
                if (named.st_dev, named.st_ino) == (mine.st_dev, mine.st_ino):
                    os.unlink(self.path)
            os.close(self.fd)
            self.fd = -1


class FileView:
    """The first `size` bytes of a file, sliced as bytes are, read with pread (never mapped: see the module's docstring).

    What the file no longer holds (cut short by the program) reads as zeros.
    """

    def __init__(self, fd: int, size: int) -> None:
        self.fd = fd
        self.size = size

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, index: slice) -> bytes:
        start, stop, _ = index.indices(self.size)
        if stop <= start:
            return b""
        data = os.pread(self.fd, stop - start, start)
        return data + bytes(stop - start - len(data))


Buffer = Union[bytes, bytearray, FileView]


def renamed(capture: RosCapture, names: Mapping[int, str]) -> RosCapture:
    """The capture with each thread named as the runner's monitor last saw it (by TID), where it saw it.

    A thread's slot keeps its name from its first hook, and programs often name a thread just
    after creating it (std::thread, then pthread_setname_np from its parent): its first hook can
    come first.  The monitor follows renames; the library does not (that would be a system call).
    """
    processes = tuple(replace(p, threads=tuple(replace(t, comm=names.get(t.tid) or t.comm) for t in p.threads)) for p in capture.processes)
    return replace(capture, processes=processes)


def sweep(folder: str = FOLDER) -> list[str]:
    """Remove the capture files of runners that are gone (killed before their cell's end could remove them); their names.

    A file is the sweeper's to remove only when it is a regular file of this user whose name
    carries the PID of a runner no process has any more; the name is never followed.
    """
    removed: list[str] = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        pid = name[len(PREFIX) :].split("-", 1)[0]
        if not name.startswith(PREFIX) or not pid.isdecimal() or os.path.exists(f"/proc/{pid}"):
            continue
        path = os.path.join(folder, name)
        try:
            info = os.lstat(path)
            if stat.S_ISREG(info.st_mode) and info.st_uid == os.geteuid():
                os.unlink(path)
                removed.append(name)
        except OSError:
            continue
    return removed


def environment(env: Mapping[str, str], path: str) -> dict[str, str]:
    """`env` with LIBRARY appended to its LD_PRELOAD (the user's own entries first: theirs are found first) and RUNNER_ROSCB=path."""
    out = dict(env)
    if not LIBRARY:
        return out
    preload = [p for p in out.get("LD_PRELOAD", "").replace(" ", ":").split(":") if p and p != LIBRARY]
    out["LD_PRELOAD"] = ":".join([*preload, LIBRARY])
    out[ENV] = path
    return out


def is_ros_library(path: str) -> bool:
    name = os.path.basename(path)
    return any(name.startswith(lib) for lib in ROS_LIBRARIES)


def mapped(pid: int) -> Optional[set[str]]:
    """The files mapped into a process (its /proc/PID/maps), or None when it is gone or unreadable."""
    try:
        with open(f"/proc/{pid}/maps", "rb") as handle:
            lines = handle.read().splitlines()
    except OSError:
        return None
    out = set()
    for line in lines:
        parts = line.split(None, 5)
        if len(parts) == 6 and parts[5].startswith(b"/"):
            out.add(os.fsdecode(parts[5].removesuffix(b" (deleted)")))
    return out


ELF_HEAD = struct.Struct("<4sBBBBB7xHHIQQQIHHHHHH")  # a 64-bit little-endian ELF header (e_ident, ..., e_phnum)
ELF_PHDR = struct.Struct("<II")  # a program header's p_type (and p_flags): PT_INTERP is 3
PT_INTERP = 3


def blocked(path: str, depth: int = 0) -> str:
    """Why ld.so will not load a preload into the program at `path`, in words; "" when it will (or cannot be told).

    From the file itself, before it runs: a statically linked executable has no dynamic loader to
    read LD_PRELOAD (no PT_INTERP), a 32-bit one cannot load a 64-bit library (ld.so says "wrong ELF
    class" and ignores it), and a set-user-ID or set-group-ID one of another owner runs in ld.so's
    secure mode, which ignores a preload given by path.  A script (`#!`) is judged by its interpreter.
    """
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
            info = os.fstat(handle.fileno())
    except OSError:
        return ""
    if head.startswith(b"#!") and depth < 2:
        words = head[2:].split(b"\n", 1)[0].split()
        return blocked(os.fsdecode(words[0]), depth + 1) if words else ""
    if not head.startswith(b"\x7fELF") or len(head) < 64:
        return ""
    name = os.path.basename(path)
    if (info.st_mode & stat.S_ISUID and info.st_uid != os.geteuid()) or (info.st_mode & stat.S_ISGID and info.st_gid != os.getegid()):
        return f"{name} is set-user-ID or set-group-ID: the dynamic loader ignores LD_PRELOAD for it (secure mode)"
    if head[4] != 2:
        return f"{name} is a 32-bit program: the dynamic loader cannot load the runner's 64-bit interposer into it"
    if head[5] != 1:
        return ""
    fields = ELF_HEAD.unpack_from(head)
    phoff, phentsize, phnum = fields[10], fields[14], fields[15]
    if phoff + phnum * phentsize > len(head) or phentsize < ELF_PHDR.size:
        return ""  # its program headers are beyond what was read: not told
    types = [ELF_PHDR.unpack_from(head, phoff + i * phentsize)[0] for i in range(phnum)]
    if PT_INTERP not in types:
        return f"{name} is statically linked: no dynamic loader reads LD_PRELOAD for it, so its callbacks cannot be measured"
    return ""


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode(errors="replace")


LAYOUT = ("max_procs", "max_threads", "capacity", "slot_size")  # the header's sizes a reader keeps from its first read


def layout_error(buf: Buffer, head: Optional[Mapping[str, int]] = None) -> str:
    """Why a capture file (whose header is `head`, read from `buf` when not given) is not of this runner's layout, in
    words; "" when it is."""
    if len(buf) < FILE.size:
        return f"the capture file has {len(buf)} bytes, fewer than its {FILE.size}-byte header"
    if head is None:
        head = FILE.unpack(buf[: FILE.size])
    expected = {
        "magic": _probe.ROSCB_MAGIC,
        "version": _probe.ROSCB_VERSION,
        "header_size": FILE.size,
        "record_size": RECORD_SIZE,
        "proc_size": _probe.ROSCB_PROC_BYTES,
    }
    wrong = [f"{name} {head[name]:#x} (this runner's: {value:#x})" for name, value in expected.items() if head[name] != value]
    if head["capacity"] <= 0 or head["slot_size"] != SLOT.size + head["capacity"] * RECORD_SIZE:
        wrong.append(f"slot_size {head['slot_size']} for capacity {head['capacity']}")
    if not wrong and file_size(head["max_procs"], head["max_threads"], head["capacity"]) > len(buf):
        wrong.append(f"{len(buf)} bytes, fewer than its header's sizes need")
    return "the capture file has another layout than this runner's interposer: " + ", ".join(wrong) if wrong else ""


@dataclass
class _Ring:
    """What the runner has taken of one thread's ring so far."""

    proc: int
    taken: int = 0  # records up to here were taken (kept, or counted lost)
    lost: int = 0  # overwritten before they were taken, or beyond MAX_RECORDS
    metas: list[Meta] = field(default_factory=list)
    callbacks: list[CallbackRecord] = field(default_factory=list)
    publishes: list[PublishRecord] = field(default_factory=list)


class Reader:
    """Drains a capture file's rings as the program runs (`drain`) and gives what it holds (`capture`).

    A ring holds CAPACITY records; drained every so often, a thread loses none unless it writes
    more than that between two drains.  What is taken is kept in memory, MAX_RECORDS at most for
    the whole file (beyond, records are counted lost on their thread).

    The file is the program's memory: its header is read once a call and its sizes are those of
    the first read (a header whose sizes changed since is another layout), so no offset read
    from it can leave the file nor one call read two layouts.
    """

    def __init__(self, max_records: int = MAX_RECORDS) -> None:
        self.rings: dict[int, _Ring] = {}
        self.kept = 0
        self.max_records = max_records
        self.layout: Optional[dict[str, int]] = None
        self.string_bytes: dict[int, int] = {}  # bytes of strings decoded per process block

    def _head(self, buf: Buffer) -> tuple[dict, str]:
        """The file's header, read once, and why it is not this runner's layout (or not the layout first read)."""
        if len(buf) < FILE.size:
            return {}, layout_error(buf)
        head = FILE.unpack(buf[: FILE.size])
        error = layout_error(buf, head)
        if error:
            return head, error
        layout = {name: head[name] for name in LAYOUT}
        if self.layout is None:
            self.layout = layout
        elif layout != self.layout:
            changed = ", ".join(f"{name} {self.layout[name]} then {layout[name]}" for name in LAYOUT if layout[name] != self.layout[name])
            return head, f"the capture file's header changed while it was read: {changed}"
        return head, ""

    def drain(self, buf: Buffer) -> None:
        """Take every record written since the last drain, while the program may still write (a file of another layout:
        nothing)."""
        head, error = self._head(buf)
        if not error:
            self._drain(buf, head, live=True)

    def _drain(self, buf: Buffer, head: Mapping[str, int], live: bool) -> None:
        slots_at = FILE.size + head["max_procs"] * _probe.ROSCB_PROC_BYTES
        for index in range(min(head["next_thread"], head["max_threads"])):
            at = slots_at + index * head["slot_size"]
            s = SLOT.unpack(buf[at : at + SLOT.size])
            if s["state"] == 0 or s["proc"] >= head["max_procs"]:
                continue
            ring = self.rings.setdefault(index, _Ring(s["proc"]))
            self._take(buf, at, s, head["capacity"], ring, live)

    def _take(self, buf: Buffer, at: int, s: dict, capacity: int, ring: _Ring, live: bool) -> None:
        """The records of one ring since `ring.taken`, re-checked against its count after the copy (a record
        overwritten while it was copied is dropped as lost, not read torn).

        The count is stored after each record, so with `after` read once the copy was made, records
        up to after - 1 may have overwritten theirs, and record `after` may have been half-written
        over the copy's (the writer never waits): the oldest record the copy holds whole is
        after - capacity + 1.  Once nothing of the program writes any more (`live` false: the final
        read, after it was stopped), the copy is whole from after - capacity.
        """
        written = s["count"]
        if written <= ring.taken:
            return
        ring_at = at + SLOT.size
        data = bytes(buf[ring_at : ring_at + capacity * RECORD_SIZE])
        after = SLOT.get(buf[at : at + SLOT.size], 0, "count")
        first = max(ring.taken, written - capacity, after - capacity + live)
        ring.lost += first - ring.taken
        tid = s["tid"]
        for n in range(first, written):
            if self.kept >= self.max_records:
                ring.lost += written - n
                break
            offset = (n % capacity) * RECORD_SIZE
            (kind,) = TYPE.unpack_from(data, offset)
            if kind == CALLBACK_TYPE:
                ring.callbacks.append(_callback(tid, data, offset))
            elif kind == PUBLISH_TYPE:
                ring.publishes.append(_publish(tid, PUBLISH.unpack(data, offset)))
            elif kind in MetaKind._value2member_map_:
                m = META.unpack(data, offset)
                s1, cut1 = self._string(buf, ring.proc, m["s1_off"], m["s1_len"])
                s2, cut2 = self._string(buf, ring.proc, m["s2_off"], m["s2_len"])
                ring.metas.append(_meta(tid, m, s1, s2, cut1 or cut2))
            self.kept += 1
        ring.taken = written

    def _string(self, buf: Buffer, proc: int, offset: int, length: int) -> tuple[str, bool]:
        """A string of process block `proc`'s arena and whether it was left out ("", True): one the interposer cannot
        have written (longer than ROSCB_STRING_MAX, or past the arena), or once that process's strings have taken as
        many bytes as its arena holds (all its strings fit there once: a program that points many records at one long
        string cannot make the runner hold more)."""
        if length == 0:
            return "", False
        used = self.string_bytes.get(proc, 0)
        if length > _probe.ROSCB_STRING_MAX or offset + length > ARENA or used + length > ARENA:
            return "", True
        self.string_bytes[proc] = used + length
        at = FILE.size + proc * _probe.ROSCB_PROC_BYTES + PROC.size + offset
        return bytes(buf[at : at + length]).decode(errors="replace"), False

    def capture(self, buf: Buffer) -> RosCapture:
        """Drain once more, nothing of the program writing any more, then everything taken, by process (a file of another
        layout: `error` says so)."""
        head, error = self._head(buf)
        if error:
            return RosCapture(error=error)
        self._drain(buf, head, live=False)
        procs: dict[int, dict] = {}
        for index in range(min(head["next_proc"], head["max_procs"])):
            at = FILE.size + index * _probe.ROSCB_PROC_BYTES
            p = PROC.unpack(buf[at : at + PROC.size])
            if p["state"] == 1:
                procs[index] = {"head": p, "threads": [], "metas": [], "callbacks": [], "publishes": []}
        slots_at = FILE.size + head["max_procs"] * _probe.ROSCB_PROC_BYTES
        for index, ring in sorted(self.rings.items()):
            at = slots_at + index * head["slot_size"]
            s = SLOT.unpack(buf[at : at + SLOT.size])
            owner = procs.get(ring.proc)
            if owner is None or owner["head"]["pid"] != s["pid"]:
                continue
            owner["metas"] += ring.metas
            owner["callbacks"] += ring.callbacks
            owner["publishes"] += ring.publishes
            open_depth = s["open_depth"]
            owner["threads"].append(
                RosThread(
                    s["tid"],
                    _text(bytes(s["comm"])),
                    s["count"],
                    ring.lost,
                    s["lost_other"],
                    s["open_cb"] if open_depth else 0,
                    s["open_since_ns"] if open_depth else 0,
                    s["state"] == 2,
                )
            )
        processes = tuple(_process(info) for info in procs.values())
        return RosCapture(processes=processes, processes_refused=head["procs_refused"], threads_refused=head["threads_refused"])


def decode(buf: Buffer) -> RosCapture:
    """The records of a capture file read at once, checked against this runner's layout; torn and overwritten ones left out."""
    return Reader().capture(buf)


_CB_AT = {name: i for i, name in enumerate(CALLBACK.names)}
assert CALLBACK.struct.format == "<" + "".join(CALLBACK.fields[n].format for n in CALLBACK.names), "callback: no padding, one value a field"


def _callback(tid: int, data: bytes, offset: int) -> CallbackRecord:
    """A callback record, read positionally in one unpack (a ring is drained by the thousand)."""
    v = CALLBACK.struct.unpack_from(data, offset)
    at = _CB_AT
    flags = v[at["flags"]]
    take = flags & CB_TAKE
    return CallbackRecord(
        tid,
        v[at["cb"]],
        v[at["seq"]],
        v[at["start_ns"]],
        v[at["end_ns"]],
        v[at["cpu_start"]],
        v[at["cpu_end"]],
        v[at["nivcsw"]],
        v[at["nvcsw"]],
        v[at["minflt"]],
        v[at["majflt"]],
        v[at["cpu_us"]] * 1000,
        v[at["release_ns"]] if flags & CB_RELEASE else 0,
        v[at["wake_ns"]],
        v[at["src_ts"]] if take else 0,
        v[at["age_ns"]] if take else 0,
        v[at["take_handle"]] if take else 0,
        bool(flags & CB_INTRA),
        v[at["depth"]],
        bool(flags & CB_UNTERMINATED),
    )


def _publish(tid: int, r: dict) -> PublishRecord:
    return PublishRecord(
        tid=tid,
        handle=r["handle"],
        handle_is_rcl=bool(r["flags"] & PUB_RCL),
        t_ns=r["t_ns"],
        src_ts=r["src_ts"],
        exact=bool(r["flags"] & PUB_EXACT),
        enclosing_cb=r["enclosing_cb"],
        enclosing_seq=r["enclosing_seq"],
    )


def _meta(tid: int, r: dict, s1: str, s2: str, cut: bool) -> Meta:
    clock = r["clock"]
    return Meta(
        kind=MetaKind(r["type"]),
        tid=tid,
        t_ns=r["t_ns"],
        a=r["a"],
        b=r["b"],
        c=r["c"],
        d=r["d"],
        e=r["e"],
        clock=ClockType(clock) if clock in ClockType._value2member_map_ else ClockType.UNKNOWN,
        s1=s1,
        s2=s2,
        truncated=cut or bool(r["flags"] & META_TRUNCATED),
    )


def _process(info: dict) -> RosProcess:
    p = info["head"]
    flags = frozenset(flag for bit, flag in PROCESS_FLAGS.items() if p["flags"] & bit)
    return RosProcess(
        pid=p["pid"],
        ppid=p["ppid"],
        exe=_text(bytes(p["exe"])),
        flags=flags,
        shadowed_by=_text(bytes(p["shadowed_by"])),
        first_hook_ns=p["first_hook_ns"],
        strings_dropped=p["strings_dropped"],
        threads=tuple(info["threads"]),
        metas=tuple(info["metas"]),
        callbacks=tuple(info["callbacks"]),
        publishes=tuple(info["publishes"]),
    )
