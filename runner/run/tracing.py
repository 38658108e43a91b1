"""The scheduler, measured from the kernel's own trace: who woke when, who took the CPU from whom.

`TraceInstances.open(pids)` starts tracing the scheduler events of those processes
(their threads, and every thread or child they create later) in a private tracefs
instance, `instances/runner-<pid>-<n>`, so a user's own tracing in the global buffer is
left alone.  The events are read and folded into per-thread aggregates by the native
reader (runner/run/_trace.c), in a thread of its own that never takes the GIL and
keeps bounded memory however long the run; `stop()` turns tracing off and reads what
is left.  A run keeps its instances from its first cell to its end (setting one up
and removing it cost the kernel 130 ms); `open_trace(pids)` is a one-off trace that
removes its own.  Nothing here fails the caller: whatever is missing
(no tracefs, no permission, an event this kernel lacks) makes `open_trace` return
`TraceUnavailable` with the reason in words.

What the trace holds: the instance's `set_event_pid` lists every thread of the
processes, and `options/event-fork` adds the threads and children they create.  The
kernel then keeps a sched_switch when the task switched out or the one switched in is
listed, a sched_waking when the woken task is listed (or the waker is), and every other
event by the task that runs when it fires: so the switches and wake-ups of the listed
threads and the switches of whatever preempted them (checked on 6.18: no switch with
neither side listed).  sched_migrate_task would be kept only when the task running is
listed, and migrations are done by others (the migration/N stopper after
sched_setaffinity, a waker, the load balancer): on 6.18 a thread moved 400 times
between CPUs showed none.  So migrations are traced in a second instance,
`runner-<pid>-<n>-migrate`, with no pid filter and only that event; the reader keeps
those of the listed threads.  `cpu_changes` counts the switch-ins on another CPU than
the one before, whoever moved the thread.

Not every switch is traced, filter or not: on the 6.18 development VM (haltpoll idle),
CPU 1's switches out of idle never are (0 in 1 s of an unfiltered instance, where CPU
0 had 29), so a thread woken on an idle CPU 1 runs with no switch-in traced.  The
reader notices at its switch-out (it was not known to run), drops the wake-up
pending (its latency is unknown, and measured from it the next one would be wrong)
and counts it in `unseen_switch_ins`: the wake-ups measured are then fewer than those
that happened, never wrong.

A SIGKILLed runner cannot stop its tracing; the guard (runner/run/guard.py) does: the
instance is registered with it while it exists, and instances of runners that died
without a guard are removed by the next `open_trace`.

Which instances are a dead runner's is the kernel's to say, not the PID in their name.
PIDs are not unique across PID namespaces: a runner in a container sees no process with
the PID of a runner on the host (or in another container) and took its instance for a
dead one, turned its tracing off and tried to remove it, and the other run's scheduler
figures silently stopped.  A lock file would need a folder every runner sees (a
container need not share /run or /dev/shm with the host), and a PID with its start time
and namespace inode would need the owner's /proc, which other namespaces do not see.
tracefs itself is shared by every namespace that mounts it, and the kernel refuses to
remove an instance (EBUSY) while any of its files is open, whoever holds it.  So each
runner holds one file of each of its instances open (`tracing_on`, read-only) from the
moment it creates it until it removes it itself; its death closes it.  Another runner
touches an instance it did not create only with rmdir: the kernel removes it if no one
holds it (its runner is dead) and refuses otherwise, and its tracing is never written.
The PID in the name still spares the instances of a live process of the sweeper's own
namespace (a runner from before the held file, between two cells).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import itertools
import os
import re
import threading
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, Optional

from runner.run import traceformat
from runner.run.guard import Guard, remove_instance
from runner.run.traceformat import EventFormat, FormatError
from runner.units import human_duration

try:
    from runner.run import _trace
except ImportError as error:  # a source tree without the extension built
    _trace = None  # type: ignore[assignment]
    _IMPORT_ERROR = str(error)

TRACEFS_DIRS = ("/sys/kernel/tracing", "/sys/kernel/debug/tracing")
INTERVAL_NS = 50_000_000  # how often the reader drains the buffers
MAX_THREADS = 8192
_STALE = re.compile(r"runner-(\d+)-\d+(-migrate)?$")
_serial = itertools.count()


class Preemptor(NamedTuple):
    """A task that took the CPU from a thread while it was runnable."""

    tid: int
    comm: str
    prio: int  # as sched_switch reports it: -1 deadline, 0..98 RT (99 - rtprio), 100..139 normal (120 + nice)
    times: int  # its preemptions of the thread (not `count`: a tuple's method)


class LateWakeup(NamedTuple):
    """One of a thread's worst wake-ups."""

    latency_ns: int  # from its sched_waking (sched_wakeup when waking is absent) to the sched_switch onto a CPU
    at_ns: int  # CLOCK_MONOTONIC of that switch-in
    cpu: int
    delayer_tid: int  # the task switched out by that switch-in (0, "swapper/N": the CPU was idle)
    delayer_comm: str
    delayer_prio: int


class PreemptedRun(NamedTuple):
    """One of a thread's most preempted runs: from the switch-in that ended a wake-up to its next
    voluntary switch-out (a callback, for a periodic thread of the runner's)."""

    start_ns: int  # CLOCK_MONOTONIC of that switch-in
    end_ns: int  # of the switch-out
    preempted_ns: int  # runnable but off its CPU, within the run
    preemptions: int
    taker_tid: int  # the task that held the CPU longest meanwhile (of the first four distinct ones)
    taker_comm: str
    taker_prio: int  # as sched_switch reports it
    taker_count: int  # the run's preemptions by it
    taker_ns: int  # how long it held the CPU from this thread, within the run


@dataclass(frozen=True)
class TracedThread:
    """One thread's scheduling, from the trace, inside the window."""

    tid: int
    comm: str  # as last seen in the trace
    wakeups: int
    latency: tuple[tuple[int, int], ...]  # (bucket, count) of runner/histogram.py's layout (index()), empty buckets left out
    latency_min: int
    latency_max: int
    preemptions: int  # switched out while runnable (prev_state R / R+)
    voluntary: int  # switched out in any other state (sleeping, blocked, exiting)
    preemptors: tuple[Preemptor, ...]  # most frequent first, at most 32 distinct
    other_preemptors: int  # preemptions by tasks beyond those 32
    migrations: int  # sched_migrate_task of this tid, as traced (see the module's docstring)
    cpus: tuple[int, ...]  # CPUs it was switched in on
    run_ns: int  # time on CPU between its switch-in and switch-out events, inside the window
    worst: tuple[LateWakeup, ...]  # its 64 largest wake-up latencies, largest first
    cpu_changes: int = 0  # switch-ins on another CPU than its previous one, whatever moved it
    latency_sum: int = 0  # of all its wake-up latencies (the mean is latency_sum / wakeups)
    exited: bool = False  # its sched_process_exit was traced
    unseen_switch_ins: int = 0  # switch-outs with no traced switch-in before them (a wake-up then goes unmeasured)
    runs: tuple[PreemptedRun, ...] = ()  # its 16 most preempted runs (preempted_ns), most first


@dataclass(frozen=True)
class TraceData:
    """What `Tracer.stop` hands back."""

    threads: dict[int, TracedThread]  # every tid that woke, ran or was preempted, that the pid filter kept
    events: int  # events parsed
    lost: int  # events the kernel dropped or overwrote (per_cpu/cpuN/stats, missed-events page flags)
    untracked: int  # events for tids beyond the table's bound
    reader_cpu_ns: int  # CPU time the reader thread spent
    duration_ns: int = 0  # from tracing on to tracing off
    out_of_order: int = 0  # events applied after a later one (held back too short a time; 0 expected)
    unseen_switch_ins: int = 0  # of all threads: switches in the kernel did not trace (see the module's docstring)
    notes: tuple[str, ...] = ()  # what the caller may want to say in a report (a stale instance removed, ...)


@dataclass(frozen=True)
class TraceUnavailable:
    """Why the trace could not be taken, in words."""

    reason: str


class Tracer:
    """A running trace; `stop()` hands back the data, `close()` (or the with-block's end) cleans up in any case."""

    def __init__(self, instances: TraceInstances, reader: Any, lost_before: int, notes: list[str], owns: bool) -> None:
        self.instances = instances
        self.paths = instances.paths  # the instance of the pid-filtered events first, then the migrations' one
        self.path = self.paths[0]
        self._reader = reader
        self._lost_before = lost_before  # the instances' loss counters when this trace began: they are not reset
        self._notes = notes
        self._started_ns = 0
        self._data: Optional[TraceData] = None
        self._teardown = weakref.finalize(self, _end_trace, instances, reader, owns)

    @property
    def notes(self) -> tuple[str, ...]:
        """What the caller may want to report so far (a stale instance removed, tracefs mounted)."""
        return tuple(self._notes)

    def __enter__(self) -> Tracer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def add_pids(self, pids: Sequence[int]) -> None:
        """Follow processes started after `open_trace` (every thread they have now; event-fork adds later ones)."""
        _follow(self.path, self._reader, pids)

    def window(self, start_ns: int, end_ns: Optional[int]) -> None:
        """Count only events from `start_ns` to `end_ns` (CLOCK_MONOTONIC; None: to the end).

        Events are folded in as they are read, held back only 10 ms: set the start before
        it comes and the end within 10 ms of it (then stop()).  Events a late window
        excludes are still counted, and a note says for how long.
        """
        self._reader.window(start_ns, -1 if end_ns is None else end_ns)

    def stop(self) -> TraceData:
        """Tracing off, the reader's final drain, the reader joined, the instances handed back: the aggregates."""
        if self._data is not None:
            return self._data
        if not self._teardown.alive:
            raise RuntimeError("the trace was closed before it was stopped")
        self.instances.tracing_off()
        stopped_ns = time.monotonic_ns()
        try:
            self._reader.stop()
        except OSError as error:
            self._notes.append(f"reading the trace failed: {error.strerror or error}; the figures may be incomplete")
        lost = self.instances.lost() - self._lost_before
        result = self._reader.result()
        self._teardown()
        self._data = _trace_data(result, lost, stopped_ns - self._started_ns, self._notes)
        return self._data

    def close(self) -> None:
        """Stop tracing and the reader, without a result; does nothing the second time."""
        self._teardown()


def _end_trace(instances: TraceInstances, reader: Any, owns: bool) -> None:
    """Tracing off and the reader stopped, once, whoever calls first (a finalizer holds this, not the Tracer)."""
    instances.tracing_off()
    try:
        reader.stop()
    except OSError:
        pass
    instances.release(remove=owns)


@dataclass(frozen=True)
class _Layout:
    """What the native reader needs to know of this kernel's buffers and events: read once per instance pair."""

    header: traceformat.PageHeader
    switch: EventFormat
    layouts: Any


class TraceInstances:
    """The runner's pair of tracefs instances, set up once and reused by every trace it opens, one at a time.

    Creating an instance, setting its clock and sizing its buffers cost about 60 ms on the
    development VM and removing it 70 ms (the kernel waits for RCU each time), so a run
    keeps its pair from the first cell to its end: a cell only rewrites the pid filter,
    starts a new reader and turns tracing on.  Between traces tracing is off and the
    reader has drained the buffers, so nothing of a cell reaches the next; the kernel's
    loss counters are not reset (that waits for RCU too) but read before each trace.
    `close()` (or the finalizer, or the guard should the runner die) removes the pair.
    """

    def __init__(self, buffer_kb: int = 4096, guard: Optional[Guard] = None) -> None:
        self.buffer_kb = buffer_kb
        self.guard = guard
        self.paths: tuple[str, ...] = ()
        self._layout: Optional[_Layout] = None
        self._unavailable: Optional[TraceUnavailable] = None
        self._notes: list[str] = []  # said by the first trace only
        self._busy = False
        self._held: list[int] = []  # a file of each instance, open while the instance is ours (the module's docstring says why)
        self._remove = weakref.finalize(self, _remove_all, self.paths, guard, [], self._held)

    def open(
        self, pids: Sequence[int], *, max_threads: int = MAX_THREADS, interval_ns: int = INTERVAL_NS, owns: bool = False
    ) -> Tracer | TraceUnavailable:
        """Trace the scheduler for `pids` (every thread, and what they create later); never raises for the system's state.

        The first call sets the instances up; if that fails, every call says why.  `owns`:
        the tracer removes the instances when it ends (a one-off trace).
        """
        if self._busy:
            raise RuntimeError("a trace is already running in these instances")
        self.prepare()
        if self._unavailable is not None:
            return self._unavailable
        try:
            return self._start(pids, max_threads, interval_ns, owns)
        except (OSError, ValueError) as error:
            self.tracing_off()
            if isinstance(error, OSError):
                return TraceUnavailable(_why(error, f"cannot start tracing in {self.paths[0]}"))
            return TraceUnavailable(f"cannot start the trace reader: {error}")

    def prepare(self, seed: Sequence[int] = ()) -> None:
        """Set the instances up now, ahead of the first trace (a run does it while it prepares).

        `seed`: processes whose children every trace follows from their fork on (the
        zygote).  The kernel adds such a child and its threads to the pid filter as it
        forks them and removes them as they exit, so a trace of them writes nothing to
        the filter: every write to a filter that is not empty makes the kernel wait for
        RCU, about 35 ms on the development VM.
        """
        if self._layout is None and self._unavailable is None:
            self._unavailable = self._set_up()
            if self._unavailable is None and seed:
                try:
                    _write_pids(os.path.join(self.paths[0], "set_event_pid"), seed)
                except OSError:
                    pass  # each trace then writes its own pids

    def tracing_off(self) -> None:
        """Stop recording in every instance (the events stay enabled, the pid filter as it is)."""
        for path in self.paths:
            try:
                _write(path, "tracing_on", "0")
            except OSError:
                pass

    def lost(self) -> int:
        """Events lost so far on every CPU of the instances, as the kernel counts them."""
        return sum(_stats_lost(path) for path in self.paths)

    def release(self, remove: bool) -> None:
        """A trace ended: the instances are free again (removed, for a one-off trace)."""
        self._busy = False
        if remove:
            self.close()

    def close(self) -> None:
        """Tracing off and the instances removed; does nothing the second time."""
        self._remove()

    def _set_up(self) -> Optional[TraceUnavailable]:
        """Create and configure the pair; None, or why not (and nothing is left behind)."""
        if _trace is None:
            return TraceUnavailable(f"the native trace reader runner.run._trace is not built ({_IMPORT_ERROR})")
        root = find_tracefs()
        if isinstance(root, TraceUnavailable):
            return root
        if root.mounted_here:
            self._notes.append(f"mounted tracefs at {root.path}")
        for name in remove_stale(root.path):
            self._notes.append(f"removed the tracing instance {name} of a runner that died")
        paths: list[str] = []
        held = self._held
        try:
            paths.append(_new_instance(root.path, self.guard, held))
            if os.path.isdir(os.path.join(root.path, "events", "sched", "sched_migrate_task")):
                paths.append(paths[0] + "-migrate")  # listed before it exists, so a failure takes it back from the guard too
                if self.guard is not None:
                    self.guard.watch_trace(paths[-1])  # before it exists, as _new_instance does
                os.mkdir(paths[-1])
                held.append(_hold(paths[-1]))
            self._layout = _configure(paths, self.buffer_kb)
        except (OSError, FormatError, ValueError) as error:
            _remove_all(paths, self.guard, [], held)
            if isinstance(error, OSError):
                where = f"the tracing instance {paths[-1]}" if paths else f"a tracing instance in {root.path}/instances"
                return TraceUnavailable(_why(error, f"cannot set up {where}"))
            return TraceUnavailable(f"cannot read the kernel's event formats: {error}")
        self.paths = tuple(paths)
        self._remove.detach()
        self._remove = weakref.finalize(self, _remove_all, self.paths, self.guard, [], held)
        return None

    def _start(self, pids: Sequence[int], max_threads: int, interval_ns: int, owns: bool) -> Tracer:
        assert _trace is not None and self._layout is not None
        layout, path = self._layout, self.paths[0]
        reader = _trace.Reader(
            layout.header.page_size,
            (layout.header.timestamp_offset, layout.header.commit_offset, layout.header.commit_size, layout.header.data_offset),
            traceformat.common_type(layout.switch),
            layout.layouts,
            traceformat.switch_state_mask(layout.switch.print_fmt),
            max_threads,
        )
        _follow(path, reader, pids)
        files = []
        for each in self.paths:
            for entry in sorted(os.listdir(os.path.join(each, "per_cpu")), key=lambda e: (len(e), e)):
                if entry.startswith("cpu") and entry[3:].isdigit():
                    files.append((int(entry[3:]), os.path.join(each, "per_cpu", entry, "trace_pipe_raw")))
        lost_before = self.lost()
        reader.start(files, interval_ns)
        self._busy = True
        notes, self._notes = self._notes, []
        tracer = Tracer(self, reader, lost_before, notes, owns)
        try:
            tracer._started_ns = time.monotonic_ns()
            for each in reversed(self.paths):
                _write(each, "tracing_on", "1")
        except OSError:
            tracer.close()
            raise
        return tracer


def open_trace(
    pids: Sequence[int],
    buffer_kb: int = 4096,
    *,
    guard: Optional[Guard] = None,
    max_threads: int = MAX_THREADS,
    interval_ns: int = INTERVAL_NS,
) -> Tracer | TraceUnavailable:
    """A one-off trace of `pids` in instances of its own, removed when it ends (a run reuses a `TraceInstances`).

    `buffer_kb` is the ring buffer per CPU; `guard`, when given, removes the instances
    should this process die without doing it; `max_threads` bounds the reader's table.
    """
    instances = TraceInstances(buffer_kb, guard)
    opened = instances.open(pids, max_threads=max_threads, interval_ns=interval_ns, owns=True)
    if isinstance(opened, TraceUnavailable):
        instances.close()
    return opened


@dataclass(frozen=True)
class TracefsRoot:
    path: str
    mounted_here: bool  # this process mounted it


def tracefs_mounts(mounts: str) -> list[str]:
    """Mount points of tracefs in /proc/mounts text, the usual places first."""
    points = [fields[1] for fields in (line.split() for line in mounts.splitlines()) if len(fields) > 2 and fields[2] == "tracefs"]
    return sorted(points, key=lambda p: TRACEFS_DIRS.index(p) if p in TRACEFS_DIRS else len(TRACEFS_DIRS))


def find_tracefs() -> TracefsRoot | TraceUnavailable:
    """Where tracefs is mounted; mounted at /sys/kernel/tracing when it is not; or why neither works."""
    for point in tracefs_mounts(_read_or("/proc/mounts", "")):
        if os.path.isdir(os.path.join(point, "instances")):
            return TracefsRoot(point, False)
    if "tracefs" not in _read_or("/proc/filesystems", ""):
        return TraceUnavailable("this kernel has no tracefs (built without CONFIG_TRACING / CONFIG_FTRACE)")
    target = TRACEFS_DIRS[0]
    err = _mount("nodev", target, "tracefs")
    if err == 0:
        return TracefsRoot(target, True)
    if err in (errno.EPERM, errno.EACCES):
        return TraceUnavailable(f"tracefs is not mounted and mounting it needs CAP_SYS_ADMIN ({errno.errorcode[err]})")
    code = errno.errorcode.get(err, str(err))
    return TraceUnavailable(f"tracefs is not mounted and mounting it at {target} failed: {os.strerror(err)} ({code})")


def remove_stale(root: str, owner: Optional[int] = None) -> list[str]:
    """Remove the instances of runners that died without removing them; their names.

    An instance is removed only by rmdir, which the kernel refuses while its runner lives
    (it holds a file of it open, whatever its PID namespace: see the module's docstring);
    its tracing is never written.  Those named for a live process of this namespace are
    left alone without asking.  `owner`: only the instances named for that PID (tests,
    which must not sweep the instances of other runners on the machine).
    """
    removed: list[str] = []
    try:
        names = os.listdir(os.path.join(root, "instances"))
    except OSError:
        return removed
    for name in sorted(names):
        m = _STALE.match(name)
        if m is None or int(m[1]) == os.getpid() or (owner is not None and int(m[1]) != owner):
            continue
        if os.path.exists(f"/proc/{m[1]}"):
            continue  # a live process of this namespace has that PID
        try:
            os.rmdir(os.path.join(root, "instances", name))
        except FileNotFoundError:
            continue  # removed meanwhile, by its guard or another runner
        except OSError:
            continue  # EBUSY: a runner, perhaps in another PID namespace, holds it
        removed.append(name)
    return removed


def named_tasks(data: TraceData) -> dict[int, tuple[int, str]]:
    """(pid, class as ps writes it) of each task the trace names as a preemptor or a delayer, read from /proc now:
    call it while they live (hogs and programs are still running)."""
    from runner.run import kernel

    tids = {p.tid for t in data.threads.values() for p in t.preemptors} | {w.delayer_tid for t in data.threads.values() for w in t.worst}
    return {tid: task for tid in tids if (task := kernel.task_of(tid)) is not None}


def thread_ids(pid: int) -> list[int]:
    """The threads of process `pid` now ([] once it has gone)."""
    try:
        return sorted(int(t) for t in os.listdir(f"/proc/{pid}/task") if t.isdigit())
    except OSError:
        return []


def read_formats(events_dir: str) -> dict[str, Optional[EventFormat]]:
    """Each kind's event format, from the first of its events this kernel has (None when it has none)."""
    formats: dict[str, Optional[EventFormat]] = {}
    for kind, names in traceformat.KIND_EVENTS.items():
        formats[kind] = None
        for name in names:
            path = os.path.join(events_dir, "sched", name, "format")
            if os.path.exists(path):
                formats[kind] = traceformat.parse_format(_read(path), path)
                break
    return formats


# ---- the instance ----


def _configure(paths: Sequence[str], buffer_kb: int) -> _Layout:
    """Set up new instances once: tracing off, the mono clock, buffer size, overwrite, event-fork, the events enabled."""
    assert _trace is not None
    path = paths[0]
    for each in paths:
        _write(each, "tracing_on", "0")  # a new instance records from the start
    header = traceformat.parse_header_page(_read(os.path.join(path, "events", "header_page")), "events/header_page")
    formats = read_formats(os.path.join(path, "events"))
    switch = formats["switch"]
    if switch is None:
        raise FormatError("this kernel has no sched/sched_switch event")
    layouts = traceformat.layouts(formats, _trace.FIELDS)
    clocks = _read(os.path.join(path, "trace_clock")).replace("[", " ").replace("]", " ").split()
    if "mono" not in clocks:
        raise FormatError(f"trace_clock has no 'mono' (has {', '.join(clocks)}): timestamps would not compare with CLOCK_MONOTONIC")
    for each in paths:
        _write(each, "trace_clock", "mono")
        _write(each, "buffer_size_kb", str(buffer_kb))
        _write(each, "options/overwrite", "1")  # a full buffer overwrites: the gap is flagged on the page that follows it
    _write(path, "options/event-fork", "1")
    for kind, fmt in formats.items():
        if fmt is not None:
            # migrations in their own instance (the module's docstring says why), when there is one
            where = paths[1] if kind == "migrate" and len(paths) > 1 else path
            _write(where, f"events/sched/{fmt.name}/enable", "1")
    return _Layout(header, switch, layouts)


def _remove_all(paths: Sequence[str], guard: Optional[Guard], notes: list[str], held: list[int]) -> None:
    """Let go of the instances' held files and remove the instances, side by side: each removal waits for RCU (about
    70 ms on the development VM)."""
    while held:
        os.close(held.pop())
    gone = [False] * len(paths)

    def remove(n: int) -> None:
        gone[n] = remove_instance(paths[n])

    others = [threading.Thread(target=remove, args=(n,), name="runner-trace-rmdir") for n in range(1, len(paths))]
    for thread in others:
        thread.start()
    if paths:
        remove(0)
    for thread in others:
        thread.join()
    for path, removed in zip(paths, gone):
        if not removed:
            notes.append(f"could not remove the tracing instance {path}")
        if guard is not None:
            guard.forget_trace(path)


def _follow(path: str, reader: Any, pids: Sequence[int]) -> None:
    """Give the reader and the kernel's pid filter every thread of `pids`, until none appears between the two.

    Only the threads the filter lacks are written (the kernel adds a listed task's
    children and threads itself, and removes them as they exit), in one write: each
    write to a filter that is not empty makes the kernel wait for RCU (about 35 ms on
    the development VM), and 8,000 tids took 2 ms into an empty one.
    """
    known: set[int] = set()
    for _ in range(10):  # a thread created between listing and filtering is listed the next round
        tids = sorted({t for pid in pids for t in thread_ids(pid)} - known)
        if not tids:
            return
        reader.track(tids)  # the reader first: events of a tid may follow as soon as the kernel has it
        filtered = os.path.join(path, "set_event_pid")
        listed = {int(word) for word in _read(filtered).split() if word.isdigit()}
        missing = [tid for tid in tids if tid not in listed]
        if missing:
            _write_pids(filtered, missing)
        known.update(tids)


def _write_pids(path: str, tids: Sequence[int]) -> None:
    """Add `tids` to set_event_pid, in one write."""
    data = (" ".join(str(tid) for tid in tids) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)  # a tracefs file: never made, never a link
    try:
        while data:
            data = data[os.write(fd, data) :]
    finally:
        os.close(fd)


def _new_instance(root: str, guard: Optional[Guard], held: list[int]) -> str:
    """A new instance `runner-<pid>-<n>`, told to the guard before it exists (a runner killed between the two leaves
    none), and held from the moment it exists (its file appended to `held`)."""
    while True:
        path = os.path.join(root, "instances", f"runner-{os.getpid()}-{next(_serial)}")
        if guard is not None:
            guard.watch_trace(path)
        try:
            os.mkdir(path)
        except FileExistsError:  # not ours: an instance of a runner with this pid (before, or in another PID namespace)
            if guard is not None:
                guard.forget_trace(path)
            continue
        try:
            held.append(_hold(path))
            return path
        except FileNotFoundError:
            if os.path.isdir(path):  # no tracing_on: not an instance of tracefs
                os.rmdir(path)
                if guard is not None:
                    guard.forget_trace(path)
                raise
            if guard is not None:  # removed between its mkdir and its hold by another runner's sweep, which saw it unheld
                guard.forget_trace(path)
        except OSError:
            remove_instance(path)
            if guard is not None:
                guard.forget_trace(path)
            raise


def _hold(path: str) -> int:
    """A file of the instance, opened to be held: the kernel refuses to remove an instance while one is open."""
    return os.open(os.path.join(path, "tracing_on"), os.O_RDONLY | os.O_CLOEXEC)


def _stats_lost(path: str) -> int:
    """Events lost on every CPU of the instance, as per_cpu/cpuN/stats counts them (overrun, commit overrun, dropped)."""
    lost = 0
    try:
        entries = os.listdir(os.path.join(path, "per_cpu"))
    except OSError:
        return 0
    for entry in entries:
        lost += stats_lost(_read_or(os.path.join(path, "per_cpu", entry, "stats"), ""))
    return lost


def stats_lost(text: str) -> int:
    """The events a per_cpu/cpuN/stats text says were lost."""
    lost = 0
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("overrun", "commit overrun", "dropped events") and value.strip().isdigit():
            lost += int(value)
    return lost


def _trace_data(result: dict[str, Any], stats_lost: int, duration_ns: int, notes: list[str]) -> TraceData:
    threads = {}
    for t in result["threads"]:
        threads[t["tid"]] = TracedThread(
            tid=t["tid"],
            comm=t["comm"],
            wakeups=t["wakeups"],
            latency=t["latency"],
            latency_min=t["latency_min"],
            latency_max=t["latency_max"],
            preemptions=t["preemptions"],
            voluntary=t["voluntary"],
            preemptors=tuple(map(Preemptor._make, t["preemptors"])),
            other_preemptors=t["other_preemptors"],
            migrations=t["migrations"],
            cpus=t["cpus"],
            run_ns=t["run_ns"],
            worst=tuple(map(LateWakeup._make, t["worst"])),
            cpu_changes=t["cpu_changes"],
            latency_sum=t["latency_sum"],
            exited=t["exited"],
            unseen_switch_ins=t["unseen_switch_ins"],
            runs=tuple(map(PreemptedRun._make, t["runs"])),
        )
    if result["malformed"]:
        notes.append(f"{result['malformed']} trace records could not be decoded")
    if result["window_late_ns"]:
        notes.append(
            f"the window was set after {human_duration(result['window_late_ns'])} of events outside it had been counted "
            "(set its start before it begins, its end at most 10 ms after it passes)"
        )
    if result["forced"]:
        notes.append(f"{result['forced']} events were applied before every CPU's buffer was read (the reader fell behind)")
    # the kernel's counters and the pages' flags count the same losses: the larger is the better count
    lost = max(stats_lost, result["lost_stored"], result["missed_pages"])
    return TraceData(
        threads=dict(sorted(threads.items())),
        events=result["events"],
        lost=lost,
        untracked=result["untracked"],
        reader_cpu_ns=result["reader_cpu_ns"],
        duration_ns=duration_ns,
        out_of_order=result["out_of_order"],
        unseen_switch_ins=sum(t.unseen_switch_ins for t in threads.values()),
        notes=tuple(notes),
    )


def native_result(result: dict[str, Any], stats_lost: int = 0) -> TraceData:
    """TraceData from a native Reader's result() (tests feed the reader pages of their own)."""
    return _trace_data(result, stats_lost, 0, [])


# ---- files ----


def _read(path: str) -> str:
    with open(path) as handle:
        return handle.read()


def _read_or(path: str, default: str) -> str:
    try:
        return _read(path)
    except OSError:
        return default


def _write(path: str, name: str, value: str) -> None:
    fd = os.open(os.path.join(path, name), os.O_WRONLY | os.O_TRUNC | os.O_NOFOLLOW | os.O_CLOEXEC)  # never made, never a link
    try:
        os.write(fd, value.encode())
    finally:
        os.close(fd)


def _mount(source: str, target: str, fstype: str) -> int:
    """mount(2); 0 or the errno."""
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    if libc.mount(source.encode(), target.encode(), fstype.encode(), ctypes.c_ulong(0), None) == 0:
        return 0
    return ctypes.get_errno() or errno.EIO


def _why(error: OSError, what: str) -> str:
    code = errno.errorcode.get(error.errno or 0, str(error.errno))
    if error.errno in (errno.EPERM, errno.EACCES):
        return f"{what}: permission denied ({code}); tracing needs root (CAP_SYS_ADMIN)"
    where = f" ({error.filename})" if error.filename else ""
    return f"{what}: {error.strerror or error}{where} ({code})"
