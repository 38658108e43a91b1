"""What a cell's process shell hands the pure evaluation core: typed raw data, nothing decided yet.

The shell (run/spawn.py) starts, supervises and stops processes and reads back what the
kernel and the native core recorded; it decides nothing about figures, verdicts or
status.  Everything it learned travels in a `RawCell`: every field of each thread's
native slot (samples, rusage totals, the errno of each setting it applied, the
`err_other` of a failed per-callback allocation), the settings read back from the
kernel, the worker's ready report, the mid-run thread table, and what went wrong
around the threads (a worker that died, the watchdog, background load that ended,
a stopped process, an interrupt).  A fake shell builds the same records to test the
run path without RT rights.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from runner.results.pstable import ThreadRow
from runner.run.kernel import Counters
from runner.run.roscbdata import RosCapture
from runner.run.samples import SlotData
from runner.run.traced import Task
from runner.run.tracing import TraceData, TraceUnavailable
from runner.scenario.model import ProgramSpec
from runner.scenario.plan import PlannedThread, Settings


@dataclass(frozen=True)
class ApplyErrors:
    """The errno of each setting a thread applied to itself; 0 where it worked or was not asked for."""

    sched: int = 0
    nice: int = 0
    cpus: int = 0
    memory: int = 0  # mlockall / preallocation of the thread's process
    other: int = 0  # the native slot's err_other: e.g. ENOMEM of a per-callback allocation

    def failed(self) -> dict[str, int]:
        """The settings that failed, by name, with their errno."""
        return {
            k: v
            for k, v in (("sched", self.sched), ("nice", self.nice), ("cpus", self.cpus), ("memory", self.memory), ("other", self.other))
            if v
        }


@dataclass(frozen=True)
class ReadyReport:
    """A worker's `ready` message, checked: its TIDs and the errno of every setting, per slot."""

    pid: int
    tids: tuple[int, ...]
    main: tuple[int, int, int]  # sched, nice, cpus of the main thread (applied by the worker's Python code)
    threads: tuple[tuple[int, int, int, int], ...]  # per slot: sched, nice, cpus, other (from the native slot)
    memory_errno: int = 0
    memory_message: str = ""

    @classmethod
    def parse(cls, message: dict[str, Any], nslots: int) -> ReadyReport:
        """The report in a worker's JSON line; ValueError when it is not one (a worker out of step)."""
        try:
            errors = message.get("errors") or {}
            main = errors.get("main") or {}
            threads = errors.get("threads") or [[0, 0, 0, 0]] * nslots
            memory = errors.get("memory") or {}
            report = cls(
                pid=int(message["pid"]),
                tids=tuple(int(t) for t in message["tids"]),
                main=(int(main.get("sched", 0)), int(main.get("nice", 0)), int(main.get("cpus", 0))),
                threads=tuple((int(a), int(b), int(c), int(d)) for a, b, c, d in threads),
                memory_errno=int(memory.get("errno", 0)),
                memory_message=str(memory.get("message", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"malformed ready report: {type(exc).__name__}: {exc}") from None
        if len(report.tids) != nslots or len(report.threads) != nslots:
            raise ValueError(f"ready report for {len(report.tids)} threads, {nslots} expected")
        return report

    def errors(self, index: int) -> ApplyErrors:
        """What slot `index` failed to apply; the main thread's policy errors come from the worker's own call."""
        sched, nice, cpus, other = self.threads[index]
        if index == 0:
            sched, nice, cpus = self.main
        return ApplyErrors(sched, nice, cpus, self.memory_errno, other)


@dataclass(frozen=True)
class RawThread:
    """One planned thread as the shell found it."""

    planned: PlannedThread
    pid: int  # its process; 0 when the process never started
    slot: SlotData
    applied: Optional[Settings]  # read back from the kernel; None when it could not be read
    errors: ApplyErrors
    ready: bool  # its process reported ready (settings applied, threads created)
    samples_written: int = 0  # per-callback rows drained to the samples file
    samples_lost: int = 0  # rows overwritten in the ring before the runner could drain them


@dataclass(frozen=True)
class BackgroundProcess:
    """A process of the background load, for the record."""

    kind: str  # "hog" or "command"
    name: str
    pid: Optional[int]
    argv: tuple[str, ...] = ()
    log: str = ""  # a command's output file, in the cell's folder
    output: Optional[OutputCount] = None  # what a command wrote to it, once the cell stopped it


@dataclass(frozen=True)
class ResourceState:
    """A shared resource after the run, read from the segment the runner created (programs' mutexes, queues, ...)."""

    name: str
    kind: str
    acquisitions: int = 0  # mutex: locks taken
    contended: int = 0  # mutex: locks that had to wait
    dropped: int = 0  # queue: resumes lost because its consumers were QDEPTH behind
    queued: int = 0  # queue: resumes still waiting to be taken at the end
    owner_died: int = 0  # times a thread took its mutex over from a holder that had died holding it
    lost: int = 0  # queue with pending: drop: resumes that came while no thread was suspended on it (rt-app loses them too)


@dataclass(frozen=True)
class Snapshot:
    """A thread's name and settings at one instant: when it appeared, when a rule changed it, when it changed itself."""

    at_ns: int  # CLOCK_MONOTONIC
    comm: str
    settings: Settings
    why: str  # "appeared", "rule", "changed"


@dataclass(frozen=True)
class HistoryGap:
    """The changes of a thread's settings its bounded history left out: how many, and from when to when.

    A history keeps its first `kept_first` and its most recent `kept_last` snapshots (and
    always the one of its rule); what came between is only counted.
    """

    count: int
    first_ns: int  # CLOCK_MONOTONIC of the first change left out
    last_ns: int  # and of the last
    kept_first: int
    kept_last: int


@dataclass(frozen=True)
class FoldedRule:
    """A thread rule as applied to threads that were folded: to how many, and on how many it did not take as asked."""

    rule: int  # its index in the program's rules
    applied: int
    not_as_asked: int  # the kernel refused part of it, or read back other settings than it asked for


@dataclass(frozen=True)
class FoldedName:
    """Folded threads of one name and rule: what an expectation on that name would have checked, had they been kept."""

    comm: str
    rule: Optional[int]  # the index of the rule applied to them; None: none was
    count: int


@dataclass(frozen=True)
class FoldedThreads:
    """A program's threads that exited once it had `cap` thread records: counted together, not kept one by one."""

    cap: int  # the thread records a program keeps before exited threads are folded
    count: int
    measured: int  # those whose counters were read in the measured window: `counters` sums theirs
    counters: Counters  # summed up to each one's last reading; migrations None unless every one had them; cpu -1
    first_seen_ns: int
    last_gone_ns: int
    rules: tuple[FoldedRule, ...] = ()
    names: tuple[FoldedName, ...] = ()  # the first distinct (name, rule) pairs folded, with their counts
    names_not_kept: int = 0  # folded threads whose (name, rule) came after those: their names are unknown


@dataclass(frozen=True)
class RawProgramThread:
    """One thread of a program as the monitor saw it."""

    tid: int
    index: int  # order of appearance; 0 is the main thread
    comm: str  # its name when last read
    seen_ns: int  # when the monitor first listed it
    named_ns: int  # when it was first seen under the name it ended with (a rule can match only from then)
    gone_ns: Optional[int]  # when it was found gone; None while it lived to the end
    rule: Optional[int]  # the index of the rule applied to it
    rule_errors: ApplyErrors
    rule_ns: Optional[int]  # when the rule was applied
    counters: Optional[Counters]  # over the measured window (or from its appearance); None if never read
    measured_ns: int  # the time those counters cover
    cpus_seen: tuple[int, ...]  # CPUs it was found running on at the readings
    history: tuple[Snapshot, ...]
    applied: Optional[Settings]  # its settings when last read
    pid: int = 0  # its process: the program's, or one the program started
    history_gap: Optional[HistoryGap] = None  # the changes `history` left out; None when it kept them all


@dataclass(frozen=True)
class OutputCount:
    """What one stream of a program took: bytes written to it, those kept in its file, and why fewer than the limit, if so."""

    written: int  # bytes the program (and what it started) wrote, kept or not
    kept: int  # of them, the bytes in the file: the first ones
    limit: int  # the bytes the file was to keep at most
    error: str = ""  # why the file stopped taking bytes before the limit (a full disk), in words; "" when it did not
    held_open: bool = False  # a process still held the stream at the cell's end: what it wrote after was neither kept nor counted
    tail: bytes = b""  # the last bytes read, kept or not

    @property
    def dropped(self) -> int:
        """Bytes written but not kept: beyond the limit, or after the file could not be written."""
        return self.written - self.kept


@dataclass(frozen=True)
class RawProgram:
    """A program of the cell: how it started and ended, its output, and its threads."""

    spec: ProgramSpec
    start: Settings  # the settings it inherited from the runner, before its own
    pid: int  # 0 when it never started
    path: str  # the program as found in PATH
    start_errors: ApplyErrors  # the errno of each process-level setting applied before exec
    failure: str  # why it could not start, in words; "" when it did
    released_ns: Optional[int]  # exec
    exited_ns: Optional[int]  # when it was found exited
    exit_code: Optional[int]  # its exit status, or None when a signal ended it
    exit_signal: Optional[int]
    stopped: str  # how the runner ended it: "", "SIGTERM", "SIGKILL" (SIGTERM ignored for the grace period)
    stdout: str  # file names in the cell folder
    stderr: str
    tail: tuple[str, ...]  # the last lines of its output (stderr, then stdout)
    threads: tuple[RawProgramThread, ...]
    attached: bool = False  # a process the runner did not start (runner watch): it has no exit status for the runner
    seen_by: str = ""  # how its threads were found: "events" (the kernel's process events) or "listing" (/proc)
    seen_note: str = ""  # why not by events, in words
    memory_limit: Optional[int] = None  # memory_max as its cgroup holds it, read back
    memory_peak: Optional[int] = None  # the most its cgroup was charged with
    oom_kills: Optional[int] = None  # its tasks the OOM killer ended
    memory_note: str = ""  # why it has no cgroup of its own, so memory_max could not be applied either
    halted_ns: Optional[int] = None  # when it was first seen stopped (state T: SIGSTOP, a debugger), if it was
    folded: Optional[FoldedThreads] = None  # exited threads counted beyond its cap of thread records; None when none were
    output: tuple[OutputCount, ...] = ()  # what its stdout and stderr took, in that order; () when not captured (runner watch)
    callbacks: Optional[RosCapture] = None  # its ROS 2 callbacks as the interposer recorded them; None: `callbacks: off` or watched


@dataclass(frozen=True)
class Timeline:
    """CLOCK_MONOTONIC instants (ns) of the cell; None for what never happened."""

    began_ns: int  # the shell started on the cell
    start_ns: Optional[int] = None  # the common start gate
    end_ns: Optional[int] = None  # the planned end of the measured work
    stopped_ns: Optional[int] = None  # the workers exited, or the interrupt came
    ended_ns: int = 0  # everything was stopped and read back


@dataclass(frozen=True)
class RawCell:
    """Everything the shell learned about one cell run."""

    started_at: str  # wall-clock start, ISO 8601 UTC
    threads: tuple[RawThread, ...]
    processes: int  # measured process instances (names need the instance when there are several)
    timeline: Timeline
    table: tuple[ThreadRow, ...] = ()  # the mid-run snapshot of /proc, as ps shows it
    failures: tuple[str, ...] = ()  # start failures, workers that died, the watchdog
    incidents: tuple[str, ...] = ()  # background load that ended early, processes that were stopped
    interrupted: bool = False
    background: tuple[BackgroundProcess, ...] = field(default=())
    online_cpus: tuple[int, ...] = ()  # the CPUs the runner may use: an affinity of all of them reads as "all"
    rt_limit_us: tuple[Optional[int], Optional[int]] = (None, None)  # sched_rt_runtime_us, sched_rt_period_us
    resources: tuple[ResourceState, ...] = ()
    programs: tuple[RawProgram, ...] = ()  # the user's programs, measured from outside
    trace: Optional[TraceData | TraceUnavailable] = None  # the scheduler trace; None when not asked for
    trace_tasks: dict[int, Task] = field(default_factory=dict)  # tasks the trace names, as /proc had them at its end
    released_late: tuple[tuple[str, int], ...] = ()  # (process, ns): measured processes released after the common start
    load_late: tuple[tuple[str, int], ...] = ()  # (hog, ns): background hogs whose load began after the common start
