"""The worker processes of a cell as the runner sees them: started, told their spec, read back, drained, signalled, reaped.

A worker (run/worker.py is its own side) holds the measured threads of one scenario
process, or a hog's spinning threads, and shares a buffer of slots with the runner
(samples.py).  What is here starts one (forked by the zygote, or a fresh interpreter),
reads its ready line and its `done`, hands its samples to the session's sink, follows its
callbacks for --follow, and says how it ended.  A child of the runner's is left unreaped
until the cell is done signalling its group (`exit_code`).
"""

from __future__ import annotations

import json
import mmap
import os
import select
import selectors
import signal
import subprocess
import time
from collections.abc import Callable, Mapping
from contextlib import suppress
from dataclasses import dataclass, field
from typing import Any, Optional

from runner.results.document import thread_key
from runner.run import kernel, samples
from runner.run.backend import CellOptions, Interrupted
from runner.run.child import child_env, python_module, signal_name
from runner.run.external import wait_status
from runner.run.guard import Guard
from runner.run.rawcell import ReadyReport
from runner.run.wiring import hog_specs, lock_slots
from runner.run.zygote import Zygote, ZygoteChild, ZygoteError
from runner.safefs import open_write
from runner.scenario.model import PeriodicWork, Scenario
from runner.scenario.plan import PlannedThread

READY_TIMEOUT_S = 20.0
DRAIN_CHUNK = 4096  # samples drained and written at a time: the runner's memory does not follow how far it fell behind


@dataclass
class Worker:
    """A worker process and what the runner knows of it."""

    label: str
    spec: dict[str, Any]
    layout: samples.Layout
    planned: list[PlannedThread]
    measured: bool
    log_path: str
    popen: Optional[subprocess.Popen[str] | ZygoteChild] = None
    ready: Optional[dict[str, Any]] = None
    done: bool = False
    buffer: Optional[samples.Buffer] = None
    seen: list[int] = field(default_factory=list)
    written: list[int] = field(default_factory=list)  # samples handed to the sink, per slot

    @property
    def pid(self) -> int:
        assert self.popen is not None
        return self.popen.pid

    @property
    def nslots(self) -> int:
        return self.layout.nthreads

    def start(self, guard: Guard, resources_fd: Optional[int] = None, zygote: Optional[Zygote] = None) -> None:
        """Start the worker (forked by the zygote when there is one that serves) and send it its spec."""
        fd = samples.create(self.spec["comm"], self.layout)
        passed = [fd] if resources_fd is None else [fd, resources_fd]
        try:
            self.buffer = samples.Buffer(fd, self.layout)  # the mapping outlives the descriptor, and the worker
            self.written = [0] * self.nslots
            forked = self._fork(zygote, passed) if zygote is not None else None
            if forked is not None:
                self.popen = forked
                child_fds = list(range(3, 3 + len(passed)))  # where a forked worker finds them
            else:
                self.popen = self._popen(passed)
                child_fds = passed
        finally:
            os.close(fd)
        self.spec["samples_fd"] = child_fds[0]
        self.spec["resources_fd"] = child_fds[1] if resources_fd is not None else None
        guard.watch(self.popen.pid)
        assert self.popen.stdin is not None
        self.popen.stdin.write(json.dumps(self.spec) + "\n")
        self.popen.stdin.flush()

    def _popen(self, passed: list[int]) -> subprocess.Popen[str]:
        """A fresh interpreter running the worker: the way without a zygote."""
        with os.fdopen(open_write(self.log_path, mode=0o644), "w") as log:  # the worker holds its own copies of the descriptors
            return subprocess.Popen(
                python_module("runner.run.worker"),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                text=True,
                bufsize=1,
                start_new_session=True,
                close_fds=True,
                pass_fds=passed,
                cwd="/",
                env=child_env(RUNNER_PARENT_PID=str(os.getpid())),
            )

    def _fork(self, zygote: Zygote, passed: list[int]) -> Optional[ZygoteChild]:
        """The worker forked by the zygote; None when the zygote does not serve (the caller starts one itself)."""
        if zygote.sock is None:
            return None
        opened: list[int] = []  # every descriptor made here, closed on any failure
        try:
            opened.append(open_write(self.log_path, mode=0o644))  # never through a link
            opened += [*os.pipe(), *os.pipe()]  # stdin's read and write ends, stdout's
            log, stdin_r, stdin_w, stdout_r, stdout_w = opened
            pid = zygote.spawn(stdin_r, stdout_w, log, passed)
        except BaseException as error:
            for each in opened:
                os.close(each)
            if isinstance(error, ZygoteError):
                return None
            raise
        for each in (log, stdin_r, stdout_w):  # the child holds its own copies now
            os.close(each)
        return ZygoteChild(zygote, pid, os.fdopen(stdin_w, "w", buffering=1), os.fdopen(stdout_r))

    def hang_up(self) -> None:
        """Cancel its start gate and close its input: a worker whose cell never started leaves at once, its threads unworked.

        A stop signal would not do: at the gate, the native core only notes it, and the worker
        waited out the grace period for its SIGKILL.  Its input's end reaches one still reading its spec.
        """
        if self.buffer is not None:
            with suppress(ValueError):  # unmapped already
                self.buffer.cancel_gate()
        if self.popen is not None and self.popen.stdin is not None:
            with suppress(OSError):
                self.popen.stdin.close()

    def signal(self, sig: int) -> None:
        """Signal the worker's process group, or the worker alone while it has none yet (forked, not yet setsid()).

        A stop that came in that moment once missed the worker, and the cell waited out the 2 s grace.
        """
        if self.popen is not None and exit_code(self.popen) is None:
            kill_group_or_process(self.popen.pid, sig)

    def exit_reason(self) -> Optional[str]:
        """Why the worker ended badly, or None if it exited cleanly."""
        assert self.popen is not None
        code = self.popen.returncode
        if code is None or (code == 0 and self.done):
            return None
        if code < 0:
            return f"{self.label} (pid {self.pid}) was killed by {signal_name(-code)}"
        tail = _tail(self.log_path)
        return f"{self.label} (pid {self.pid}) exited with code {code}" + (f": {tail}" if tail else "")


def unmap(maps: list[samples.Buffer | mmap.mmap]) -> None:
    for m in maps:
        m.close()


def _tail(path: str, lines: int = 3) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as handle:
            text = handle.read().strip().splitlines()
    except OSError:
        return ""
    return " | ".join(text[-lines:])


def hog_workers(scenario: Scenario, folder: str) -> list[Worker]:
    """Background hogs as workers: one spinning process each, or one process of spinning threads."""
    specs = hog_specs(scenario, kernel.online_cpus())
    return [Worker(h.label, h.spec, h.layout, [], False, os.path.join(folder, h.log_name)) for h in specs]


def wait_ready(workers: list[Worker], deadline: float, stop_requested: Callable[[], bool]) -> Optional[str]:
    """Read each worker's ready line; return a reason on failure; raise Interrupted when asked to stop."""
    sel = selectors.DefaultSelector()
    pending: dict[Any, Worker] = {}
    for w in workers:
        assert w.popen is not None and w.popen.stdout is not None
        sel.register(w.popen.stdout, selectors.EVENT_READ, w)
        pending[w.popen.stdout] = w
    try:
        while pending:
            if stop_requested():
                raise Interrupted()
            left = deadline - time.monotonic()
            if left <= 0:
                return f"{', '.join(w.label for w in pending.values())} did not get ready within {READY_TIMEOUT_S:g}s"
            for key, _ in sel.select(timeout=min(left, 0.5)):
                w = key.data
                line = key.fileobj.readline()  # type: ignore[union-attr]
                sel.unregister(key.fileobj)
                del pending[key.fileobj]
                if not line:
                    try:
                        w.popen.wait(timeout=5)
                    except subprocess.TimeoutExpired:
                        return f"{w.label} (pid {w.pid}) closed its output before getting ready, and did not exit"
                    return w.exit_reason() or f"{w.label} closed its output before getting ready"
                try:
                    msg = json.loads(line)
                except ValueError:
                    return f"{w.label} said {line.strip()[:80]!r} where its ready report was expected"
                if not msg.get("ready"):
                    return f"{w.label}: {msg.get('failed', 'could not get ready')}"
                w.ready = msg
    finally:
        sel.close()
    return None


def read_done(w: Worker) -> None:
    assert w.popen is not None and w.popen.stdout is not None
    try:
        for line in w.popen.stdout:
            message = json.loads(line)
            if message.get("done"):
                w.done = True
    except (ValueError, OSError):
        pass


def follow_lines(w: Worker, epoch_offset_ns: int, emit: Callable[[str], None]) -> None:
    """Print new callbacks in the ros2-realtime-examples' log form (those still in the ring: --follow shows, the files keep)."""
    assert w.buffer is not None
    cap = w.layout.capacity
    for t in w.planned:
        if not t.has_callbacks or not cap:
            continue
        written = w.buffer.written(t.index)
        w.seen[t.index] = max(w.seen[t.index], written - cap + 1)
        while w.seen[t.index] < written:
            s = w.buffer.sample(t.index, w.seen[t.index])
            w.seen[t.index] += 1
            stamp = s.wake_ns + epoch_offset_ns
            when = f"[{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}] [{t.name}]"
            emit(f"[{'WARN' if s.nivcsw else 'INFO'}] {when}: Involuntary context switches: '{s.nivcsw}'")
            if s.minflt or s.majflt or (isinstance(t.work, PeriodicWork) and t.work.alloc):
                lvl = "WARN" if s.minflt or s.majflt else "INFO"
                emit(f"[{lvl}] {when}: New page faults during spin: [minor: {s.minflt}, major: {s.majflt}]")


def drain(w: Worker, options: CellOptions, last_only: bool, final: bool, holders: Mapping[int, str]) -> None:
    """Hand the samples written since the last call to the session's sink (the samples file), thread by thread.

    With `samples: last N` the ring is the N callbacks to keep: it is read once, at the end.
    `holders` names the cell's threads by gid, for who held a mutex an activation waited for.
    """
    if w.buffer is None or options.samples is None or not w.layout.capacity or (last_only and not final):
        return
    for t in w.planned:
        if not t.has_callbacks:
            continue
        for _ in range(w.layout.capacity // DRAIN_CHUNK + 1):  # a ring at most: a writer ahead of the drain waits for the next tick
            taken = w.buffer.drain(t.index, stopped=final, most=DRAIN_CHUNK)
            if taken:
                options.samples.write(
                    thread_key(t.process, t.instance, t.index, t.name),
                    int(w.ready["tids"][t.index]) if w.ready else 0,
                    taken,
                    lock_slots(t.work),
                    holders,
                )
                w.written[t.index] += len(taken)
            if len(taken) < DRAIN_CHUNK:
                break


class Exits:
    """The cell's processes as pidfds: the supervising loop wakes the moment one exits, not at its next tick.

    A worker the zygote forked is reaped by the zygote, which then says so on its socket:
    the loop wakes on that message too, since the worker's exit is known only then.
    Without pidfds (before Linux 5.3) it waits out the tick, as a sleep would.
    """

    def __init__(self, pids: list[int], zygote: Optional[Zygote] = None) -> None:
        self.poller = select.poll()
        self.fds: list[int] = []
        self.zygote_fd = -1
        for pid in pids:
            try:
                fd = os.pidfd_open(pid)
            except OSError:  # gone already (its exit is seen by the caller's poll), or no pidfds
                continue
            self.fds.append(fd)
            self.poller.register(fd, select.POLLIN)
        if zygote is not None and zygote.sock is not None and self.fds:
            self.zygote_fd = zygote.sock.fileno()
            self.poller.register(self.zygote_fd, select.POLLIN)

    def wait(self, timeout_s: float) -> None:
        """Until a process exits or `timeout_s` passes; an exited one no longer wakes it."""
        if not self.fds:
            time.sleep(timeout_s)
            return
        for fd, events in self.poller.poll(timeout_s * 1000):
            if fd != self.zygote_fd:  # the zygote's messages are taken by the caller's poll of its workers
                self.poller.unregister(fd)
            elif events & (select.POLLHUP | select.POLLERR | select.POLLNVAL):  # the zygote is gone: it would wake every poll
                self.poller.unregister(fd)
                self.zygote_fd = -1

    def close(self) -> None:
        for fd in self.fds:
            os.close(fd)
        self.fds = []


def ready_report(w: Worker) -> Optional[ReadyReport]:
    """The worker's ready report, typed; None when it never got ready (or sent something else)."""
    if w.ready is None:
        return None
    try:
        return ReadyReport.parse(w.ready, w.nslots)
    except ValueError:
        return None


def exit_code(proc: subprocess.Popen[Any] | ZygoteChild) -> Optional[int]:
    """Its exit code once it has exited (negative: the signal that ended it), None while it runs.

    A child of the runner's own (subprocess.Popen) is left unreaped: its zombie keeps its PID, and
    so the number of the process group it leads, from every other process until `Cell.stop` has
    signalled that group for the last time and reaps it (Popen.poll reaped it at once, and the
    SIGKILL of its group at the cell's end then went to whichever process had been given the
    number).  A worker the zygote forked is the zygote's to reap, which kills its group first.
    """
    if not isinstance(proc, subprocess.Popen) or proc.returncode is not None:  # a zygote's worker, or reaped
        return proc.poll()
    try:
        info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:  # reaped by someone else after all: Popen knows its code
        return proc.poll()
    return None if info is None else os.waitstatus_to_exitcode(wait_status(info))


def exited_within(proc: subprocess.Popen[Any] | ZygoteChild, timeout: Optional[float]) -> bool:
    """Wait until `proc` has exited (left unreaped, as `exit_code` leaves it) or `timeout` seconds (None: no limit) passed."""
    if not isinstance(proc, subprocess.Popen):
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return False
        return True
    until = None if timeout is None else time.monotonic() + timeout
    while exit_code(proc) is None:
        if until is not None and time.monotonic() >= until:
            return False
        time.sleep(0.002)
    return True


def kill_group_or_process(pid: int, sig: int = signal.SIGKILL) -> None:
    """Signal the process group `pid` leads, or the process alone while it leads none yet (forked, before its setsid()).

    A group the runner may signal none of (a command run through sudo) falls back to its leader, and
    what the kernel refuses there too is left to the cgroup the command was started in.
    """
    try:
        os.killpg(pid, sig)
        return
    except (ProcessLookupError, PermissionError):
        pass
    with suppress(ProcessLookupError, PermissionError):
        os.kill(pid, sig)
