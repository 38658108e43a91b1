"""The user's own programs as measured processes: settings before exec, thread rules as threads appear, /proc read-back.

The runner does not own a program's threads, so everything about them comes from the
kernel, from outside.  A program is forked by the native core, which applies the
process's settings to itself (the way `chrt` and `taskset` do in front of a command)
and waits at a gate before exec, so the runner knows its PID before it runs a single
instruction of its own.  While the cell runs, a monitor thread of the runner lists the
program's threads: each new thread is recorded with its settings, the first thread rule
its name matches is applied to it (by TID, from outside, with the time it took), and its
counters (switches, faults, CPU time, migrations, the CPU it ran on) are read from
/proc at the start gate and every few milliseconds, so a thread that exits mid-cell keeps
what it did up to its last reading.  None of this costs the program anything but the
reads of its /proc files.

What the monitor keeps is bounded, so an hour of `runner watch` costs the runner no more
memory than a minute: a thread's settings history keeps its first and latest snapshots and
counts the changes between, and once a program holds MAX_THREADS thread records (programthreads.py), its
threads that exit are counted together (with their summed counters) instead of kept one by
one.  Threads still alive are always kept and measured.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import shutil
import signal
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Optional

from runner.run import _probe, kernel, memcg, roscb
from runner.run.output import FINISH_WAIT_S, CappedOutput
from runner.run.procevents import Kind, ProcEvents
from runner.run.programthreads import ThreadRecord, ThreadRegistry
from runner.run.rawcell import (
    ApplyErrors,
    OutputCount,
    RawProgram,
    RawProgramThread,
    Snapshot,
)
from runner.run.roscbdata import RosCapture
from runner.scenario.model import Policy, ProgramSpec, Sched
from runner.scenario.plan import Settings, first_rule

if TYPE_CHECKING:
    from runner.run.guard import Watcher

LIST_EVERY_S = 0.002  # without process events, how often the monitor lists a program's threads (a new thread's wait for its rule)
COUNT_EVERY_S = 0.05  # how often it reads every thread's counters (what a thread that exits loses at most), and lists them with events
EVENT_WAIT_S = 0.05  # the listener's longest wait for an event before it looks whether to stop
SEEN_BY_EVENTS = "events"
SEEN_BY_LISTING = "listing"
OpenEvents = Callable[[frozenset[int]], tuple[Optional[ProcEvents], str]]  # subscribes to the events of these processes
RENAME_WATCH_NS = 1_000_000_000  # a new thread's name is re-read this long (programs name threads after creating them)
TAIL_LINES = 10  # lines of a program's output shown when it fails
MAPS_EVERY_NS = 1_000_000_000  # how often a program's maps are read and its interposer's rings drained (while the cell runs)


def sched_json(sched: Optional[Sched]) -> Optional[list[Any]]:
    """[policy, priority, nice, extra]: extra is (runtime, deadline, period, util_min, util_max) for deadline or uclamp, else None."""
    if sched is None:
        return None
    extra = None
    if sched.policy is Policy.DEADLINE or sched.util_min is not None or sched.util_max is not None:
        extra = (
            sched.runtime or 0,
            sched.deadline or 0,
            sched.period or 0,
            -1 if sched.util_min is None else sched.util_min,
            -1 if sched.util_max is None else sched.util_max,
        )
    return [sched.policy.kernel_id, sched.rt_priority, sched.nice, extra]


def settings_args(sched: Optional[Sched], cpus: Optional[tuple[int, ...]]) -> _probe.SettingsTuple:
    """(policy, priority, nice, cpus, extra) as the native core applies them; None leaves a setting as it is."""
    policy, priority, nice, extra = sched_json(sched) or (None, None, None, None)
    return policy, priority, nice, list(cpus) if cpus is not None else None, extra


def _environment(extra: dict[str, str]) -> dict[str, str]:
    return {**os.environ, **extra}


def resolve(spec: ProgramSpec) -> tuple[str, str]:
    """(path, "") for the program as the exec will find it, or ("", why not) in words."""
    program = spec.command[0]
    env = _environment(spec.env)
    if "/" in program:
        where = program if os.path.isabs(program) or spec.cwd is None else os.path.join(spec.cwd, program)
        if not os.path.exists(where):
            return "", f"program {program!r} does not exist"
        if not os.access(where, os.X_OK) or os.path.isdir(where):
            return "", f"program {program!r} is not an executable file"
        return os.path.abspath(where), ""
    found = shutil.which(program, path=env.get("PATH", os.defpath))
    if found is None:
        return "", f"program {program!r} is not in PATH ({env.get('PATH', os.defpath)})"
    return os.path.abspath(found), ""


def _exec_hint(path: str, stage: int, error: int) -> str:
    """Why an exec of a file that exists said ENOENT: the interpreter its `#!` line names is missing."""
    if stage == _probe.STAGE_CWD or error != errno.ENOENT or not os.path.isfile(path):
        return ""
    try:
        with open(path, "rb") as handle:
            first = handle.readline(256)
    except OSError:
        return ""
    if not first.startswith(b"#!"):
        return ""
    words = first[2:].split()
    interpreter = os.fsdecode(words[0]) if words else ""
    if interpreter and not os.path.exists(interpreter):
        return f" (the file exists; the interpreter its #! line names, {interpreter!r}, does not)"
    return ""


class ProgramRun:
    """One program from its fork to its reaping; the monitor updates its threads while it runs."""

    def __init__(self, spec: ProgramSpec, folder: str, start: Settings, online: tuple[int, ...]):
        self.spec, self.folder, self.start_settings, self.online = spec, folder, start, online
        self.pid = 0
        self.path = ""
        self.failure = ""
        self.start_errors = ApplyErrors()
        self.released_ns: Optional[int] = None
        self.exited_ns: Optional[int] = None
        self.status: Optional[int] = None  # the wait status once it exited
        self._reaped = False  # its PID given back to the kernel (`reap`): no signal to its group may follow
        self.stopped = ""
        self.stdout = f"{spec.name}.stdout"
        self.stderr = f"{spec.name}.stderr"
        self._outputs: tuple[CappedOutput, ...] = ()  # stdout's and stderr's, from its launch to its stop
        self.output: tuple[OutputCount, ...] = ()  # what they took, once it was stopped: stdout's, stderr's
        self.registry = ThreadRegistry(spec, start)  # its threads as the monitor found them
        self._report = -1
        self._gate = -1
        self.attached = False
        self._pidfd = -1  # an attached process's pidfd: its exit, never a later process given its PID
        self.seen_by = ""  # how its new threads were found: SEEN_BY_EVENTS or SEEN_BY_LISTING
        self.seen_note = ""  # why not (or not always) by events, in words
        self.cgroup: Optional[memcg.MemoryCgroup] = None  # its cgroup while it runs: memory_max's, or one that only holds it
        self.memory_note = ""  # why it has no cgroup of its own (so no memory_max either), in words
        self.memory_limit: Optional[int] = None  # the limit as read back from the cgroup
        self.memory_peak: Optional[int] = None
        self.oom_kills: Optional[int] = None
        self.halted_ns: Optional[int] = None  # when it was first seen stopped (SIGSTOP, a debugger)
        self._stopped_seen: Optional[int] = None  # when a tick first found it stopped (one more says it stayed so)
        self.capture: Optional[roscb.Capture] = None  # the interposer's file while it runs (`callbacks:` on)
        self.callbacks: Optional[RosCapture] = None  # what that file held once the program was stopped
        self._maps_read = 0  # when its maps were last read for the interposer (CLOCK_MONOTONIC ns)

    def attach(self, pid: int) -> None:
        """Follow a process the runner did not start (`runner watch`): never signalled, never reaped.

        Held by a pidfd where the kernel has them: a PID is free for another process once its own
        has exited, and /proc alone would then follow the newcomer for an exited program."""
        self.pid, self.attached = pid, True
        try:
            self._pidfd = os.pidfd_open(pid)
        except (OSError, AttributeError):  # gone already (found so by /proc), or no pidfds here: /proc alone says
            self._pidfd = -1

    def _attached_exited(self) -> bool:
        """Whether the attached process has exited: its pidfd readable, or without one, /proc finding it gone."""
        if self._pidfd < 0:
            return not kernel.process_alive(self.pid)
        poller = select.poll()  # not select(): it refuses descriptors from 1024 up, which a large cell's runner may hold
        poller.register(self._pidfd, select.POLLIN)
        if not poller.poll(0):
            return False
        self._close_pidfd()
        return True

    def _close_pidfd(self) -> None:
        if self._pidfd >= 0:
            os.close(self._pidfd)
            self._pidfd = -1

    def launch(self, guard: Watcher) -> None:
        """Fork it with its settings applied, held before exec; `failure` says why when it cannot start."""
        self.path, self.failure = resolve(self.spec)
        if self.failure:
            return
        env = self._with_interposer(_environment(self.spec.env))
        cwd = self.spec.cwd if self.spec.cwd is not None else self.folder
        out = CappedOutput(os.path.join(self.folder, self.stdout), self.spec.output_limit)
        try:
            err = CappedOutput(os.path.join(self.folder, self.stderr), self.spec.output_limit)
        except BaseException:
            out.finish(0)
            raise
        self._outputs = (out, err)
        try:
            self.pid, self._report, self._gate = _probe.spawn_program(
                os.fsencode(self.path),
                [os.fsencode(a) for a in self.spec.command],
                [os.fsencode(f"{k}={v}") for k, v in env.items()],
                os.fsencode(cwd),
                settings_args(self.spec.sched, self.spec.cpus),
                self.spec.reset_on_fork,
                out.write_fd,
                err.write_fd,
            )
        except BaseException:
            self._finish_output(0)
            raise
        finally:
            for each in self._outputs:
                each.close_write_end()  # the program holds its own copies: its exit (and its children's) ends the pipes
        guard.watch(self.pid)
        data = _read_exactly(self._report, 12)
        if len(data) == 12:
            self.start_errors = ApplyErrors(*struct.unpack("3i", data))
        self._hold(guard, self.spec.memory_max)

    def _with_interposer(self, env: dict[str, str]) -> dict[str, str]:
        """The program's environment with the libtracetools interposer preloaded and its capture file named (`callbacks:` on).

        Without the built library or a file (no /dev/shm), the program runs as it is and its
        `callbacks` say why in words.
        """
        if not self.spec.callbacks:
            return env
        if not roscb.LIBRARY:
            self.callbacks = RosCapture(error="the libtracetools interposer was not built (pip install the runner with its C core)")
            return env
        try:
            self.capture = roscb.Capture.create(self.spec.name)
        except OSError as error:
            self.callbacks = RosCapture(error=f"the interposer's capture file could not be made in {roscb.FOLDER}: {error.strerror}")
            return env
        return self.capture.environment(env)

    def look_callbacks(self, every_ns: int = MAPS_EVERY_NS) -> None:
        """At most once every `every_ns`: read its processes' maps (is the interposer in them, which ROS 2 libraries are)
        and drain the interposer's rings."""
        now = time.monotonic_ns()
        if self.capture is None or not self.pid or now - self._maps_read < every_ns or self.poll():
            return
        self._maps_read = now
        self.capture.look(self.family())
        self.capture.drain()

    def _collect_callbacks(self) -> None:
        """Decode the interposer's file once nothing of the program writes it any more, and remove it (whatever happened)."""
        capture, self.capture = self.capture, None
        if capture is None:
            return
        try:
            if self.released_ns is not None:
                self.callbacks = replace(capture.read(), blocked=roscb.blocked(self.path))
            else:
                self.callbacks = RosCapture(capture.path, error="the program never started: nothing was recorded")
        finally:
            capture.close()

    def release(self) -> None:
        """Let it exec; `failure` says why when the exec (or the chdir before it) failed."""
        if self._gate < 0:
            return
        os.write(self._gate, b"g")
        os.close(self._gate)
        self._gate = -1
        self.released_ns = time.monotonic_ns()
        data = _read_exactly(self._report, 8)
        os.close(self._report)
        self._report = -1
        if len(data) == 8:
            stage, error = struct.unpack("2i", data)
            what = "change to its working directory" if stage == _probe.STAGE_CWD else "exec"
            where = f" {self.spec.cwd!r}" if stage == _probe.STAGE_CWD else f" {self.path}"
            self.failure = f"program {self.spec.name} could not {what}{where}: {os.strerror(error)}{_exec_hint(self.path, stage, error)}"

    def abandon(self) -> None:
        """The cell will not run: close the gate without a byte, so the child exits without exec."""
        for fd in (self._gate, self._report):
            if fd >= 0:
                os.close(fd)
        self._gate = self._report = -1

    def poll(self) -> bool:
        """Whether it has exited (its wait status then in `status`); it is not reaped: `reap` does that.

        Unreaped, its zombie keeps its PID, and so its process group's number, from every other
        process until the runner is done signalling that group (`stop`, the watchdog, the guard):
        reaped at its exit, a program that ended early left its number free for the rest of the
        cell, and the SIGKILL of its group at the cell's end went to whichever process had been
        given that number and led a group (a shell's job, a daemon), as root any on the machine.
        """
        if self.status is not None or not self.pid:
            return True
        if self.attached:
            if self.exited_ns is None and self._attached_exited():
                self.exited_ns = time.monotonic_ns()
            return self.exited_ns is not None
        self._exited(os.WNOHANG)
        return self.status is not None

    def _exited(self, flags: int = 0) -> None:
        """Note its exit (waiting for it without os.WNOHANG), leaving it unreaped."""
        info = os.waitid(os.P_PID, self.pid, os.WEXITED | os.WNOWAIT | flags)
        if info is not None:
            self.status, self.exited_ns = wait_status(info), time.monotonic_ns()

    def reap(self) -> None:
        """Reap it, once the runner signals its group no more: its PID is free for others from now on."""
        if self.pid and not self.attached and not self._reaped:
            with contextlib.suppress(ChildProcessError):  # reaped already: nothing of it is left to give back
                if self.status is None:
                    self._exited()
                os.waitpid(self.pid, 0)
            self._reaped = True

    def family(self) -> list[int]:
        """The program's process and those it started (children, a daemon, `ros2 run`'s node), as its cgroup holds them now.

        Read afresh each time (a pid that left cannot be reused into the list, and two threads
        asking need no lock); where the runner could not give it a cgroup (or it was attached
        to, by `runner watch`), the program's process alone.
        """
        found = self.cgroup.processes() if self.cgroup is not None and not self.attached else []
        return [self.pid] + [pid for pid in found if pid != self.pid] if self.pid else found

    def watch_state(self) -> None:
        """Note when it was stopped (SIGSTOP, a debugger's stop), found so by two ticks in a row: its threads cannot run.

        Only state T counts: a tracer's stop at each system call (t, strace) passes at once.
        """
        self.look_callbacks()
        if self.halted_ns is not None or not self.pid or self.poll():
            return
        if kernel.process_state(self.pid) != "T":
            self._stopped_seen = None
        elif self._stopped_seen is None:
            self._stopped_seen = time.monotonic_ns()
        else:
            self.halted_ns = self._stopped_seen

    def stop(self, guard: Watcher) -> None:
        """SIGTERM its process group, SIGKILL after the grace period; whatever it left in its group (and cgroup) goes too.

        It is left for `reap`: until then its zombie holds its PID, so every signal to its group
        reaches its own (`poll` says why).

        One never released (the cell stopped while it waited at its gate) never ran: its gate is
        closed and what is left of it is killed, and `stopped` stays empty, as nothing of the
        program was stopped (its results would otherwise say it ran the cell and ignored SIGTERM).

        The interposer's file is read once the program is gone, and removed whatever happens here.
        """
        try:
            self._stop(guard)
        finally:
            self._collect_callbacks()

    def _stop(self, guard: Watcher) -> None:
        if not self.pid or self.attached:
            self._close_pidfd()  # an attached process that outlives the watch is let go of
            self._close_cgroup(guard)
            self._finish_output()
            return
        if self.released_ns is None:
            self.abandon()
            if not self.poll():
                _killpg(self.pid, signal.SIGKILL)
                self._exited()
        elif not self.poll():
            self.look_callbacks(every_ns=0)  # what it has mapped, while it still lives
            _killpg(self.pid, signal.SIGTERM)
            self.stopped = "SIGTERM"
            until = time.monotonic() + self.spec.grace / 1e9
            while not self.poll() and time.monotonic() < until:
                time.sleep(0.005)
            if not self.poll():
                _killpg(self.pid, signal.SIGKILL)
                self.stopped = "SIGKILL"
                self._exited()
        _killpg(self.pid, signal.SIGKILL)
        guard.forget(self.pid)
        self._close_cgroup(guard)
        self._finish_output()

    def _finish_output(self, wait_s: float = FINISH_WAIT_S) -> None:
        """Stop reading its stdout and stderr, once every process that held them is gone (or `wait_s` passed), and count them."""
        deadline = time.monotonic() + wait_s
        if self._outputs:
            self.output = tuple(each.finish(deadline) for each in self._outputs)
            self._outputs = ()

    def _hold(self, guard: Watcher, limit: Optional[int]) -> None:
        """Put the program, still at its gate, in a cgroup of its own, which all it starts joins too.

        With `limit` (memory_max) a memory cgroup that holds it to that; `memory_note` says why
        not.  Without, one that only holds it, where the machine lets the runner make one: what
        the program starts in a session of its own (setsid, a daemon) is stopped with it, even
        should the runner die (its guard empties the cgroup).
        """
        where, why = memcg.hierarchy(limit=limit is not None)
        if where is None:
            self.memory_note = why
            return
        try:
            self.cgroup = memcg.MemoryCgroup.create(where, self.spec.name, limit)
            guard.watch_cgroup(self.cgroup.folder)
            self.cgroup.add(self.pid)
        except OSError as error:
            self.memory_note = f"cgroup v{where.version}: {error.strerror}"
            self._close_cgroup(guard)
            return
        if limit is not None:
            self.memory_limit = self.cgroup.limit()

    def _close_cgroup(self, guard: Watcher) -> None:
        """Its cgroup's peak and OOM kills (memory_max), then the cgroup itself, with anything the program left in it."""
        if self.cgroup is None:
            return
        if self.spec.memory_max is not None:
            self.memory_peak, self.oom_kills = self.cgroup.peak(), self.cgroup.oom_kills()
        self.cgroup.kill_all()
        self.cgroup.remove()
        guard.forget_cgroup(self.cgroup.folder)
        self.cgroup = None

    def raw(self, window_start: Optional[int], window_end: int) -> RawProgram:
        code = sig = None
        if self.status is not None and self.released_ns is not None:  # a child that never exec'd: its exit is not the program's
            if os.WIFSIGNALED(self.status):
                sig = os.WTERMSIG(self.status)
            else:
                code = os.WEXITSTATUS(self.status)
        threads, folded = self.registry.raw(self.pid, window_start, window_end)
        return RawProgram(
            self.spec,
            self.start_settings,
            self.pid,
            self.path,
            self.start_errors,
            self.failure,
            self.released_ns,
            self.exited_ns,
            code,
            sig,
            self.stopped,
            self.stdout if self.output and self.pid else "",
            self.stderr if self.output and self.pid else "",
            self._tail(),
            threads,
            self.attached,
            self.seen_by,
            self.seen_note,
            self.memory_limit,
            self.memory_peak,
            self.oom_kills,
            self.memory_note,
            self.halted_ns,
            folded,
            self.output,
            self._callbacks(threads),
        )

    def _callbacks(self, threads: tuple[RawProgramThread, ...]) -> Optional[RosCapture]:
        """What the interposer recorded, its threads named as the monitor last saw them; None for `callbacks: off` and watched ones."""
        if not self.spec.callbacks or self.attached or self.callbacks is None:
            return None
        return roscb.renamed(self.callbacks, {t.tid: t.comm for t in threads})

    def _tail(self) -> tuple[str, ...]:
        """The last lines it wrote, stderr's then stdout's, as read from its pipes: past the output limit too."""
        lines: list[str] = []
        for name, count in reversed(list(zip((self.stdout, self.stderr), self.output))):
            lines += [f"{name}: {line}" for line in deque(count.tail.decode(errors="replace").splitlines(), TAIL_LINES)]
        return tuple(lines[-TAIL_LINES:])


def _read_exactly(fd: int, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = os.read(fd, size - len(data))
        if not chunk:
            break
        data += chunk
    return data


def wait_status(info: os.waitid_result) -> int:
    """The wait status (as os.waitpid gives it) that a waitid result of an exited child says."""
    if info.si_code == os.CLD_EXITED:
        return (info.si_status & 0xFF) << 8
    return info.si_status | (0x80 if info.si_code == os.CLD_DUMPED else 0)  # killed by that signal (and dumped core)


def _killpg(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Monitor:
    """A thread of the runner that follows the programs' threads: new ones, rules, settings and counters.

    It never touches a thread's scheduling except by a rule the scenario gives, and reads
    only /proc; the measured programs run in their own processes, so this thread and
    the GIL it takes are not theirs.  Where the kernel sends its process events, a second
    thread applies rules the moment a thread appears or takes a matching name, and the
    listing slows to a safety net; elsewhere the listing runs every LIST_EVERY_S.
    """

    def __init__(self, programs: list[ProgramRun], open_events: OpenEvents = ProcEvents.open):
        self.programs = [p for p in programs if p.pid and not p.failure]
        self.window_start: Optional[int] = None  # the start gate: counters are read as a base then
        self.events: Optional[ProcEvents] = None
        self.events_note = ""  # why there are no events, in words
        self.events_lost = 0  # times the kernel dropped events because the listener fell behind
        self.events_failed = False  # the listener stopped on an error: the listing runs at its own pace again
        self._open_events = open_events
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="program-monitor", daemon=True)
        self._listener = threading.Thread(target=self._listen, name="program-events", daemon=True)
        self._lock = threading.Lock()

    def listen(self) -> None:
        """Subscribe to the kernel's process events now (before the programs exec), so none of their threads is missed."""
        if self.programs and self.events is None and not self.events_note:
            self.events, self.events_note = self._open_events(frozenset(p.pid for p in self.programs))
        for p in self.programs:
            p.seen_by = SEEN_BY_EVENTS if self.events is not None else SEEN_BY_LISTING
            p.seen_note = self.events_note

    def start(self) -> None:
        """List the programs' threads once, then follow them: events (when the kernel sends them) and the listing."""
        if not self.programs:
            return
        self.listen()
        with self._lock:
            now = time.monotonic_ns()
            for p in self.programs:
                self._list(p, now)
        self._thread.start()
        if self.events is not None:
            self._listener.start()

    def stop(self) -> None:
        """Stop following; one last reading of every thread still there."""
        self._stop.set()
        for thread in (self._thread, self._listener):
            if thread.is_alive():
                thread.join()
        if self.events is not None:
            self.events.close()
            self.events = None
        with self._lock:
            now = time.monotonic_ns()
            for p in self.programs:
                self._count(p, now)

    def _run(self) -> None:
        next_count = 0.0
        while not self._stop.wait(LIST_EVERY_S if self.events is None or self.events_failed else COUNT_EVERY_S):
            now = time.monotonic_ns()
            with self._lock:
                for p in self.programs:
                    self._list(p, now)
                if (
                    self.window_start is not None
                    and now >= self.window_start
                    and any(t.base is None for p in self.programs for t in p.registry.threads.values() if t.gone_ns is None)
                ):
                    next_count = 0.0  # the start gate passed: take every thread's base now
                if time.monotonic() >= next_count:
                    for p in self.programs:
                        self._count(p, now)
                    next_count = time.monotonic() + COUNT_EVERY_S

    def _listen(self) -> None:
        """Follow the events; should the kernel's socket fail, the listing takes over at its own pace, and the results say so."""
        try:
            self._follow_events()
        except Exception as error:  # whatever failed, the programs' threads are still found, by listing
            why = error.strerror if isinstance(error, OSError) and error.strerror else f"{type(error).__name__}: {error}"
            with self._lock:
                self.events_failed = True
                for p in self.programs:
                    p.seen_by = SEEN_BY_LISTING
                    p.seen_note = f"the kernel's process events failed ({why}); threads that appeared after were found by listing"

    def _follow_events(self) -> None:
        """Apply the events as they come: a new thread (the kernel's instant of its creation), a new name (of its renaming)."""
        assert self.events is not None
        programs = {p.pid: p for p in self.programs}
        while not self._stop.is_set():
            events = self.events.read(EVENT_WAIT_S)
            with self._lock:
                if events is None:
                    self.events_lost += 1
                    now = time.monotonic_ns()
                    for p in self.programs:
                        p.seen_note = (
                            f"the kernel dropped process events {self.events_lost} time(s) (the runner fell behind); "
                            "threads that appeared then were found by listing"
                        )
                        self._list(p, now)
                    continue
                for event in events:
                    program = programs.get(event.tgid)
                    if program is None:
                        continue
                    if event.kind is Kind.FORK:
                        self._appeared(program, event.tid, event.at_ns)
                    elif event.kind is Kind.COMM:
                        self._renamed(program, event.tid, event.comm, event.at_ns)

    def _appeared(self, p: ProgramRun, tid: int, at_ns: int) -> None:
        t = p.registry.threads.get(tid)
        if t is not None and t.gone_ns is not None and at_ns >= t.gone_ns:  # the kernel reused an exited thread's TID
            p.registry.retire(t)
            t = None
        if t is not None:
            if at_ns < t.seen_ns:  # listed before its creation's event was read: it was there since the event
                if t.named_ns == t.seen_ns:
                    t.named_ns = at_ns
                t.seen_ns = at_ns
            return
        comm = kernel.thread_comm(p.pid, tid)
        if comm is None:
            return
        t = p.registry.new_thread(tid, comm, at_ns, p.pid)
        self._snapshot(p, t, at_ns, "appeared")
        self._apply_rule(p, t)

    def _renamed(self, p: ProgramRun, tid: int, comm: str, at_ns: int) -> None:
        t = p.registry.threads.get(tid)
        if t is None or t.gone_ns is not None:  # a new thread (on a reused TID, when its old thread's record is still there)
            self._appeared(p, tid, at_ns)
            return
        if comm != t.comm:
            t.comm, t.named_ns = comm, at_ns
            self._apply_rule(p, t)
        elif at_ns <= (t.rule_ns if t.rule_ns is not None else at_ns):
            t.named_ns = at_ns  # its new name was read from /proc before this event was: the name dates from the event

    def _list(self, p: ProgramRun, now: int) -> None:
        """New threads (of the program's process and those it started) get their snapshot and their rule; a young
        thread's name is re-read until a rule matches it."""
        for pid in p.family():
            for tid in kernel.task_ids(pid):
                t = p.registry.threads.get(tid)
                if t is not None and t.gone_ns is not None:  # listed again after it was found gone: the kernel reused its TID
                    p.registry.retire(t)
                    t = None
                if t is None:
                    comm = kernel.thread_comm(pid, tid)
                    if comm is None:
                        continue
                    t = p.registry.new_thread(tid, comm, now, pid)
                    self._snapshot(p, t, now, "appeared")
                elif t.rule is None and now - t.seen_ns < RENAME_WATCH_NS:
                    comm = kernel.thread_comm(pid, tid)
                    if comm is None or comm == t.comm:
                        continue
                    t.comm, t.named_ns = comm, now
                else:
                    continue
                self._apply_rule(p, t)

    def _apply_rule(self, p: ProgramRun, t: ThreadRecord) -> None:
        index = first_rule(p.spec, t.comm)
        if index is None or t.rule is not None:
            return
        rule = p.spec.threads[index]
        errors = _probe.apply_to(t.tid, *settings_args(rule.sched, rule.cpus))
        t.rule, t.rule_errors, t.rule_ns = index, ApplyErrors(*errors), time.monotonic_ns()
        self._snapshot(p, t, t.rule_ns, "rule")

    def _snapshot(self, p: ProgramRun, t: ThreadRecord, now: int, why: str) -> None:
        try:
            settings = kernel.thread_settings(t.tid, p.online)
        except OSError:
            return
        if why == "changed" and settings == t.settings:
            return
        t.settings = settings
        t.history.append(Snapshot(now, t.comm, settings, why))

    def _count(self, p: ProgramRun, now: int) -> None:
        started = self.window_start is not None and now >= self.window_start
        gone = []
        for t in p.registry.threads.values():
            if t.gone_ns is not None:
                continue
            counters = kernel.thread_counters(t.pid or p.pid, t.tid)
            if counters is None:
                t.gone_ns = now
                gone.append(t)
                continue
            comm = kernel.thread_comm(t.pid or p.pid, t.tid)
            if comm is not None and comm != t.comm:
                t.comm, t.named_ns = comm, now
                self._apply_rule(p, t)
            self._snapshot(p, t, now, "changed")
            if t.base is None and started:
                # a thread that was there at the start gate counts from it; one born later, from zero
                t.base = counters if t.seen_ns <= (self.window_start or 0) else replace(kernel.ZERO, migrations=0)
                t.base_ns = now
            if t.base is not None:
                t.last, t.last_ns = counters, now
                t.cpus.add(counters.cpu)
        for t in gone:
            p.registry.exited(t)
