"""The process shell of a cell run: worker processes, background load, a common start, a hard deadline.

The runner's Python code only orchestrates; measuring happens in the workers'
native threads.  Deadlines are enforced by the native watchdog (an RT thread
that needs no GIL), so a scenario that starves the runner's Python thread still
cannot outlive its cell.  The shell decides nothing: it returns a `RawCell` of
what the kernel and the native core recorded, and `evaluate` makes results of it.
`kernelbackend.KernelBackend`, the real `Backend` (backend.py), runs each cell through `run_cell`.
"""

from __future__ import annotations

import mmap
import os
import signal
import struct
import subprocess
import threading
import time
from contextlib import suppress
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Optional

from runner.results.document import thread_key
from runner.results.pstable import ThreadRow
from runner.run import _probe, kernel, samples, tracing
from runner.run.backend import CellOptions, Interrupted
from runner.run.child import signal_name
from runner.run.commands import COMMAND_HEAD_START_S, BackgroundCommands
from runner.run.external import Monitor, ProgramRun
from runner.run.gate import LOAD_LEAD_S, LoadGroup, await_gates, gate_late, load_late, start_load, start_margin
from runner.run.output import FINISH_WAIT_S
from runner.run.programs import settings_of
from runner.run.rawcell import ApplyErrors, BackgroundProcess, RawCell, RawThread, ResourceState, Timeline
from runner.run.traced import Task
from runner.run.wiring import process_spec, resource_specs, worker_layout
from runner.run.workers import (
    READY_TIMEOUT_S,
    Exits,
    Worker,
    drain,
    exit_code,
    exited_within,
    follow_lines,
    hog_workers,
    kill_group_or_process,
    read_done,
    ready_report,
    unmap,
    wait_ready,
)
from runner.safefs import make_folders
from runner.scenario.loader import ResolvedCell
from runner.scenario.model import Pending, ResourceKind, SamplesMode, Until
from runner.scenario.plan import PlannedThread, Settings, plan_scenario

if TYPE_CHECKING:
    from runner.run.kernelbackend import KernelBackend

STOP_GRACE_S = 2.0


def run_cell(cell: ResolvedCell, folder: str, start: Settings, options: CellOptions, shared: KernelBackend) -> RawCell:
    """Run one cell's processes and return what they left behind, interrupted or not.

    An OSError creating the cell's files (a full disk, a folder that vanished) propagates
    once every process the cell started is stopped; the caller decides what it means for the run.
    """
    run = _CellRun(cell, os.path.abspath(folder), start, options, shared)
    try:
        run.start()
        if not run.reason:
            run.supervise()
    except Interrupted:
        run.interrupted = True
        run.exit_time = run.exit_time or time.monotonic_ns()
        for w in run.workers:
            w.signal(signal.SIGKILL)
    except OSError:
        run.remove_buffers()  # the cell could not start (a full disk): leave nothing behind
        raise
    finally:
        run.stop()
    try:
        return run.raw()
    finally:
        run.remove_buffers(wait=False)


class _CellRun:
    """One cell's processes from start to collection: start, supervise, stop, collect, in that order."""

    def __init__(self, cell: ResolvedCell, folder: str, start: Settings, options: CellOptions, shared: KernelBackend):
        self.cell, self.folder, self.options = cell, folder, options
        self.watchdog, self.guard, self.traces, self.zygote = shared.watchdog, shared.guard, shared.traces, shared.zygote
        self.scenario = cell.scenario.replace(duration=options.duration_ns)
        make_folders(folder)
        self.began = time.monotonic()
        self.started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
        self.planned = plan_scenario(self.scenario, start)
        self.by_process: dict[tuple[str, int], list[PlannedThread]] = {}
        for t in self.planned:
            self.by_process.setdefault((t.process, t.instance), []).append(t)
        self.workers: list[Worker] = []
        gids = {id(t): gid for gid, t in enumerate(self.planned)}
        self.keys = {gid: thread_key(t.process, t.instance, t.index, t.name) for gid, t in enumerate(self.planned)}
        every = kernel.online_cpus()
        for (proc, inst), threads in self.by_process.items():
            layout = worker_layout(threads, options.duration_ns, self.scenario.samples)
            spec = process_spec(threads, self.scenario, layout, gids, every)
            self.workers.append(Worker(f"process {proc}[{inst}]", spec, layout, threads, True, os.path.join(folder, f"{proc}.{inst}.log")))
        self.resources: Optional[mmap.mmap] = None
        self.hogs = hog_workers(self.scenario, folder)
        self.programs = [ProgramRun(spec, folder, start, kernel.online_cpus()) for spec in self.scenario.programs]
        self.monitor: Optional[Monitor] = None
        self.tracer: Optional[tracing.Tracer] = None
        self.trace: Optional[tracing.TraceData | tracing.TraceUnavailable] = None
        self.trace_tasks: dict[int, Task] = {}
        self.last_only = self.scenario.samples.mode is SamplesMode.LAST
        self.commands = BackgroundCommands(folder, self.guard)
        self.load_groups: list[LoadGroup] = []  # the hogs' spinning threads by the CPU they were woken on
        self.table: list[ThreadRow] = []
        self.applied: dict[int, Optional[Settings]] = {}
        self.reason = ""
        self.interrupted = False
        self.exit_time: Optional[int] = None
        self.t0: Optional[int] = None  # the common start instant, once the gate opened
        self.t_end: Optional[int] = None
        self.incidents: dict[str, str] = {}  # background load that died, processes that were stopped: by who
        self.load_ended = False  # the background load was stopped once the measured work was over

    def start(self) -> None:
        """Start every process; once all are ready, read back each thread's settings and start background commands."""
        everyone = self.workers + self.hogs
        res_fd = self._create_resources()
        try:
            for w in self.workers:
                w.start(self.guard, res_fd, self.zygote)
            for w in self.hogs:
                w.start(self.guard, zygote=self.zygote)
        finally:
            if res_fd is not None:
                os.close(res_fd)
        self.watchdog.arm(time.monotonic_ns() + int((READY_TIMEOUT_S + 5) * 1e9), [w.pid for w in everyone])
        self.reason = wait_ready(everyone, time.monotonic() + READY_TIMEOUT_S, self.options.stop_requested) or ""
        if self.reason:
            return
        every = kernel.online_cpus()
        for w in self.workers:
            assert w.ready is not None
            for t, tid in zip(w.planned, w.ready["tids"]):
                if t.spawned:
                    continue  # not created yet: it reads its settings back itself when a spawn creates it
                try:
                    self.applied[id(t)] = kernel.thread_settings(tid, every)
                except OSError:
                    self.applied[id(t)] = None
        if self.scenario.background.commands or self.programs:
            self.guard.ready()  # what they start only the guard, or its second, stops should the runner die
        self.reason = self.commands.start(self.scenario.background.commands)
        for p in self.programs:
            if not self.reason:
                p.launch(self.guard)
                self.reason = p.failure
        if self.options.trace and not self.reason:
            traced = [w.pid for w in self.workers] + [p.pid for p in self.programs]
            opened = self.traces.open(traced)
            if isinstance(opened, tracing.TraceUnavailable):
                self.trace = opened
            else:
                self.tracer = opened

    def _create_resources(self) -> Optional[int]:
        """The shared segment of the scenario's mutexes, conditions, barriers and queues: a memfd every worker maps."""
        specs = resource_specs(self.scenario)
        if not specs:
            return None
        fd = os.memfd_create(f"runner-res-{self.cell.id}"[:200], os.MFD_CLOEXEC)
        try:
            os.ftruncate(fd, len(specs) * _probe.RES_BYTES)
            self.resources = mmap.mmap(fd, len(specs) * _probe.RES_BYTES)
            _probe.init_resources(self.resources, specs)
        except BaseException:
            os.close(fd)
            raise
        return fd

    def supervise(self) -> None:
        """Open the start gate, then watch the workers until they exit: progress, follow lines, a mid-run table."""
        options, workers, hogs = self.options, self.workers, self.hogs
        self.monitor = Monitor(self.programs)
        self.monitor.listen()  # before exec: the events of the programs' first threads are kept for it
        for p in self.programs:
            p.release()
            if p.failure:
                self.reason = p.failure
                return
        pids = [w.pid for w in workers + hogs] + [c.pid for c in self.commands] + [p.pid for p in self.programs if p.pid]
        now = time.monotonic_ns()
        head_start = COMMAND_HEAD_START_S if self.commands else 0.0
        margin = int((head_start + start_margin(len(workers), sum(w.nslots for w in workers))) * 1e9)
        longest = max((p for t in self.planned for p in t.periods), default=0)
        grace = int(max(STOP_GRACE_S * 1e9, 2 * longest))
        # The programs are stopped one after another, each given its own grace between SIGTERM and SIGKILL.
        stopping = sum(p.spec.grace for p in self.programs)
        t0 = now + margin
        t_end = t0 + options.duration_ns
        if self.tracer is not None:
            self.tracer.window(t0, t_end)
        self.t0, self.t_end = t0, t_end
        deadline = t_end + grace + stopping + int(1e9)
        self.watchdog.arm(deadline, pids)
        for w in workers:  # the measured threads first, through their gates while the CPUs are free
            assert w.buffer is not None
            w.buffer.open_gate(t0, t_end)
            w.seen = [0] * w.nslots
        if hogs:
            await_gates(workers, t0 - int(LOAD_LEAD_S * 1e9))
            # the cell's end stops the load (_end_load) once no measured thread works
            self.load_groups = start_load(hogs, time.monotonic_ns(), deadline, t0)
        epoch_offset = time.time_ns() - time.monotonic_ns()
        snapshot_at = (t0 + options.duration_ns // 2) / 1e9
        total_expected = sum(options.duration_ns // t.period for t in self.planned if t.period)
        self.monitor.window_start = t0
        self.monitor.start()
        exits = Exits([w.pid for w in workers] + [p.pid for p in self.programs if p.pid], self.zygote)
        try:
            while self._running(t_end):
                exits.wait(self._next_wait(t_end))
                if self.awaiting_end and time.monotonic_ns() >= t_end and not any(w.buffer and w.buffer.working() for w in workers):
                    self._stop_trace()  # the measured work is over; the tasks it names are looked up while the load lives
                    self._end_load()
                self._tick(t0, t_end, snapshot_at, epoch_offset, total_expected)  # after: its drain can take a while
        finally:
            exits.close()
        self.exit_time = time.monotonic_ns()
        self.monitor.stop()
        self._stop_trace()
        for w in workers:
            if options.follow:
                follow_lines(w, epoch_offset, options.follow)
            read_done(w)

    def _next_wait(self, t_end: int) -> float:
        """Seconds the supervising loop sleeps at most: a tick, and while the end is awaited, up to the end, then briefly.

        The workers' threads finish at the end, but leave their processes only as the CPUs let
        them: as soon as no measured thread works any more, the trace's last read and the end
        of the background load need not wait for those exits.  The load would hold them up
        (SCHED_OTHER threads beside a busy loop per CPU: 2 to 8 ms), and the trace's read
        overlaps them (1,024 threads in 16 processes: 40 ms of each, which went one after the
        other).  After the end the wait grows with the time since (a millisecond at first,
        half of it later), so a callback that overran far past the end is not polled a
        thousand times a second.
        """
        tick = 0.05 if self.options.follow else 0.2
        if not self.awaiting_end:
            return tick
        left = (t_end - time.monotonic_ns()) / 1e9
        return min(tick, left if left > 0 else max(0.001, -left / 2))

    @property
    def awaiting_end(self) -> bool:
        """Whether the end of the measured work is watched for: a trace to stop or load to end, and no program measured.

        A program's threads have no slots to say when they are done: with programs, both wait for every exit.
        """
        return not self.programs and (self.tracer is not None or self.loading)

    @property
    def loading(self) -> bool:
        """Whether background load still runs that the cell's end may stop early: hogs or commands, and no program measured."""
        return not self.load_ended and bool(self.hogs or self.commands) and not self.programs

    def _end_load(self) -> None:
        """The measured work is over: the background load stops now (stop() reaps it)."""
        self.load_ended = True
        for h in self.hogs:
            h.signal(signal.SIGTERM)
        self.commands.end()

    def _tick(self, t0: int, t_end: int, snapshot_at: float, epoch_offset: int, total_expected: int) -> None:
        """One round of supervision: a stop request, the mid-run table, incidents, draining, progress."""
        options, workers = self.options, self.workers
        if options.stop_requested():
            raise Interrupted()
        if not self.table and time.monotonic() >= snapshot_at:
            pids = [w.pid for w in workers] + [pid for p in self.programs if p.pid and not p.poll() for pid in p.family()]
            self.table = [row for pid in dict.fromkeys(pids) for row in kernel.thread_rows(pid)]
        self._watch_for_incidents(t0, t_end)
        for w in workers:
            if options.follow:
                follow_lines(w, epoch_offset, options.follow)
            drain(w, options, self.last_only, final=False, holders=self.keys)
        if options.progress:
            done = sum(sum(w.buffer.loops()) for w in workers if w.buffer)
            left = max(0.0, (t_end - time.monotonic_ns()) / 1e9)
            options.progress(f"cell {self.cell.id}: {done}/{total_expected or '-'} callbacks, {left:4.1f}s left")

    def _stop_trace(self) -> None:
        """Stop the trace and learn what can still be learnt of the tasks it names, while they live (hogs, programs)."""
        if self.tracer is None:
            return
        data = self.tracer.stop()
        self.tracer = None
        self.trace = data
        self.trace_tasks.update({tid: Task(*task) for tid, task in tracing.named_tasks(data).items()})

    def _running(self, t_end: int) -> bool:
        """Whether the cell goes on: a worker runs, or a program runs before the end (every `until: exit` one, before its exit)."""
        if any(exit_code(w.popen) is None for w in self.workers):  # type: ignore[arg-type]
            return True
        running = [p for p in self.programs if not p.poll()]
        if not running or time.monotonic_ns() >= t_end:
            return False
        waiting = [p for p in self.programs if p.spec.until is Until.EXIT]
        return not waiting or any(p in running for p in waiting)

    def remove_buffers(self, wait: bool = True) -> None:
        """Unmap the cell's sample buffers: their memory goes with the last mapping (the workers' are gone by now).

        Without `wait` a thread unmaps them while the cell's results are worked out and saved:
        the kernel takes tens of milliseconds to free a large cell's (1,024 threads: 150 MB,
        31 ms), with the GIL released, and what was read from them is copied out already.
        """
        maps: list[samples.Buffer | mmap.mmap] = [w.buffer for w in self.workers + self.hogs if w.buffer is not None]
        maps += [self.resources] if self.resources is not None else []
        for w in self.workers + self.hogs:
            w.buffer = None
        self.resources = None
        if wait:
            unmap(maps)
        elif maps:
            try:
                threading.Thread(target=unmap, args=(maps,), name="unmap").start()
            except RuntimeError:  # no thread to be had: unmapped here, later than it could have been
                unmap(maps)

    def _watch_for_incidents(self, t0: int, t_end: int) -> None:
        """Note background load that ended early and processes that were stopped (SIGSTOP, a debugger)."""
        now = time.monotonic_ns()
        if now >= t_end:
            return
        at = f"{max(0, now - t0) / 1e9:.1f}s into the cell"
        for h in self.hogs:
            assert h.popen is not None
            code = exit_code(h.popen)
            if code is not None and h.label not in self.incidents:
                how = f"killed by {signal_name(-code)}" if code < 0 else f"exited with code {code}"
                self.incidents[h.label] = f"background {h.label} (pid {h.pid}) {how} {at}; the load it stood for was missing from then on"
        for label, incident in self.commands.incidents(at):
            self.incidents.setdefault(label, incident)
        for p in self.programs:
            p.watch_state()
        for w in self.workers + self.hogs:
            assert w.popen is not None
            if w.label not in self.incidents and kernel.process_state(w.pid) in ("T", "t"):
                self.incidents[w.label] = (
                    f"{w.label} (pid {w.pid}) was stopped (SIGSTOP or a debugger) {at}; its threads could not run while it was"
                )

    def stop(self) -> None:
        """Stop the programs and the background load and reap every process (SIGKILL after the grace period); disarm the watchdog.

        Each process is reaped last, once nothing of the runner signals its group any more (the
        watchdog disarmed, the guard told): until then its zombie keeps its PID, the number of its
        group, from every other process (`exit_code`).
        """
        if self.monitor is not None:
            self.monitor.stop()
        if self.tracer is not None:
            self.tracer.close()
            self.tracer = None
        for p in self.programs:
            p.abandon()
            p.stop(self.guard)
        for w in self.workers + self.hogs:
            w.hang_up()
        self._end_load()
        stop_by = time.monotonic() + STOP_GRACE_S
        processes = [w.popen for w in self.workers + self.hogs if w.popen] + [c.popen for c in self.commands]
        for proc in processes:
            if not exited_within(proc, max(0.05, stop_by - time.monotonic())):
                kill_group_or_process(proc.pid)
                exited_within(proc, None)
            if isinstance(proc, subprocess.Popen) and proc.returncode is None:  # unreaped: the group is still its own
                with suppress(ProcessLookupError, PermissionError):
                    os.killpg(proc.pid, signal.SIGKILL)  # whatever the process left in its group goes with it
        self.commands.remove_groups()  # and what a command started outside its group
        self.commands.finish_outputs(time.monotonic() + FINISH_WAIT_S)  # one wait for all: what outlived its command holds a log
        self.watchdog.disarm()
        for proc in processes:
            self.guard.forget(proc.pid)
            proc.wait()  # a child of the runner's reaped now; the zygote reaped its own
        for p in self.programs:
            p.reap()

    def raw(self) -> RawCell:
        """Everything the processes left behind, read back: slots, settings, the table, what went wrong."""
        failures: list[str] = [self.reason] if self.reason else []
        if not self.reason and not self.interrupted:
            failures += [r for w in self.workers if (r := w.exit_reason())]
            if self.watchdog.fired:
                failures.append("the cell overran its deadline and was killed by the watchdog")
        threads = self._raw_threads()
        background = [BackgroundProcess("hog", h.spec["comm"], h.pid if h.popen else None) for h in self.hogs]
        background += [c.background() for c in self.commands]
        timeline = Timeline(int(self.began * 1e9), self.t0, self.t_end, self.exit_time, time.monotonic_ns())
        return RawCell(
            self.started_at,
            tuple(threads),
            len(self.by_process),
            timeline,
            tuple(self.table),
            tuple(failures),
            tuple(self.incidents.values()),
            self.interrupted,
            tuple(background),
            kernel.online_cpus(),
            kernel.rt_limit(),
            self._resource_states(),
            tuple(p.raw(self.t0, self.exit_time or time.monotonic_ns()) for p in self.programs),
            self.trace,
            dict(self.trace_tasks),
            tuple((w.label, late) for w in self.workers if w.buffer is not None and (late := gate_late(w.buffer, self.t0)) > 0),
            tuple(load_late(self.load_groups, self.t0)),
        )

    def _raw_threads(self) -> list[RawThread]:
        """Each measured thread's slot, drained one last time, with the settings read back and what the kernel refused."""
        threads: list[RawThread] = []
        for w in self.workers:
            if w.buffer is None:
                continue
            drain(w, self.options, self.last_only, final=True, holders=self.keys)
            slots = w.buffer.slots()
            report = ready_report(w)
            for t, slot in zip(w.planned, slots):
                errors = report.errors(t.index) if report else ApplyErrors()
                applied = self.applied.get(id(t))
                if t.spawned:
                    errors = ApplyErrors(slot.err_sched, slot.err_nice, slot.err_cpus, errors.memory, slot.err_other)
                    applied = settings_of(slot.phases[-1], kernel.online_cpus()) if slot.phases else None
                threads.append(
                    RawThread(
                        t,
                        w.pid if w.popen else 0,
                        slot,
                        applied,
                        errors,
                        report is not None,
                        w.written[t.index],
                        0 if self.last_only else w.buffer.lost[t.index],
                    )
                )
        return threads

    def _resource_states(self) -> tuple[ResourceState, ...]:
        """Counters of the shared resources: (kind, parties, owner, protocol, period, ..., dropped, ..., acquisitions, contended,
        owner_died)."""
        if self.resources is None:
            return ()
        out = []
        for i, (name, res) in enumerate(self.scenario.resources.items()):
            f = struct.unpack_from("<iiiiq6q3Q", self.resources, i * _probe.RES_BYTES)
            queued = f[7] if res.kind is ResourceKind.QUEUE else 0  # `pending`: resumes not taken yet
            dropped, lost = (0, f[8]) if res.pending is Pending.DROP else (f[8], 0)  # what `dropped` counts depends on the queue
            out.append(
                ResourceState(
                    name, res.kind.value, acquisitions=f[11], contended=f[12], dropped=dropped, queued=queued, owner_died=f[13], lost=lost
                )
            )
        return tuple(out)
