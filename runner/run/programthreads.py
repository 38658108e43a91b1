"""A program's threads as the monitor found them: one record each, bounded histories, and the exited ones folded.

The runner does not own a measured program's threads: the monitor (external.py) finds them
by the kernel's events or by listing /proc, and this registry keeps what it learns, apart
from the process handle (`ProgramRun`) that starts, stops and reaps the program.  A thread
is found by its TID while it lives; one whose TID the kernel gave to a new thread is retired
(kept, no longer found by it); past MAX_THREADS records, exited threads are folded into counts.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Optional

from runner.run.evaluate import degradation
from runner.run.kernel import Counters
from runner.run.rawcell import ApplyErrors, FoldedName, FoldedRule, FoldedThreads, HistoryGap, RawProgramThread, Snapshot
from runner.scenario.model import ProgramSpec
from runner.scenario.plan import Settings, rule_settings

# A thread's settings history keeps its first snapshots (it appeared, its rule, what the program set as it started) and
# its most recent (what it ended with, and the pattern of its changes): 64 in all, each about 375 bytes of the runner's
# memory (measured with tracemalloc) plus 8 to 13 bytes per CPU of an affinity narrower than all CPUs, and 125 bytes of
# results.json, so a thread that boosts its priority at every callback costs about 24 KiB, plus 0.5 to 0.8 KiB per CPU
# of its affinity.
HISTORY_FIRST = 16
HISTORY_LAST = 48
# Thread records a program keeps before threads that exit are folded into counts: far above what a program that creates
# its threads as it starts holds (a ROS 2 node: tens), so only churn (a thread per request) reaches it, whose threads
# hold a snapshot or two each: about 8 MiB of memory and 6 MiB of results.json for all 4,096.  The worst case, every
# record a full history, is about 95 MiB of memory plus 2 to 3 MiB per CPU of the threads' affinity (120 MiB with 8 CPUs,
# 230 MiB with 64), and 40 MiB of results.json, however long the program runs.
MAX_THREADS = 4096
# Distinct (name, rule) pairs of folded threads counted by name, so an expectation on a name knows how many of its threads
# were folded and not checked; folded threads of further names are only counted together.
MAX_FOLDED_NAMES = 256


class SettingsHistory:
    """A thread's snapshots of its settings, bounded: its first `first`, its latest `last`, and its rule's.

    A program that changes its own priority at every callback would otherwise grow the
    runner's memory, results.json and the report by a snapshot a change for as long as it
    runs.  What falls between the first and the latest is counted, with the instants of
    the first and the last left out, so the results say what they lack.  A snapshot that
    is not a change (a thread appears once, a rule is applied to it once) is never left
    out: the check of what a rule asked for reads its snapshot.
    """

    def __init__(self, first: int = HISTORY_FIRST, last: int = HISTORY_LAST) -> None:
        if first < 0 or last < 1:
            raise ValueError(f"a history keeps at least its latest snapshot: first={first}, last={last}")
        self._first = first
        self._head: list[Snapshot] = []
        self._pinned: list[Snapshot] = []  # snapshots that are not changes, once they fell out of the latest
        self._tail: deque[Snapshot] = deque()
        self._last = last
        self.left_out = 0
        self._left_first_ns = 0
        self._left_last_ns = 0

    def append(self, snapshot: Snapshot) -> None:
        """Keep `snapshot` as the latest; the oldest of the latest is left out (counted) once there are `last` of them."""
        if len(self._head) < self._first:
            self._head.append(snapshot)
            return
        if len(self._tail) == self._last:
            old = self._tail.popleft()
            if old.why != "changed":
                self._pinned.append(old)
            else:
                if not self.left_out:
                    self._left_first_ns = old.at_ns
                self.left_out += 1
                self._left_last_ns = old.at_ns
        self._tail.append(snapshot)

    def snapshots(self) -> tuple[Snapshot, ...]:
        """The snapshots kept, in the order they were taken."""
        return (*self._head, *self._pinned, *self._tail)

    def gap(self) -> Optional[HistoryGap]:
        """The changes left out; None when none were."""
        if not self.left_out:
            return None
        return HistoryGap(self.left_out, self._left_first_ns, self._left_last_ns, self._first, self._last)

    def __len__(self) -> int:
        return len(self._head) + len(self._pinned) + len(self._tail)


@dataclass
class ThreadRecord:
    """One thread of the program, as the monitor saw it: names, its rule, settings, counters from its base to its last reading."""

    tid: int
    index: int
    comm: str
    seen_ns: int
    named_ns: int = 0  # when it was first seen under its current name (programs rename threads after creating them)
    settings: Optional[Settings] = None
    rule: Optional[int] = None
    rule_errors: ApplyErrors = field(default_factory=ApplyErrors)
    rule_ns: Optional[int] = None
    base: Optional[Counters] = None
    base_ns: int = 0
    last: Optional[Counters] = None
    last_ns: int = 0
    gone_ns: Optional[int] = None
    cpus: set[int] = field(default_factory=set)
    history: SettingsHistory = field(default_factory=SettingsHistory)
    pid: int = 0  # its process: the program's, or one the program started (0: the program's)

    def counters(self) -> Optional[Counters]:
        """What it did from its base to its last reading; None when it was never read in the window."""
        return self.last.minus(self.base) if self.last is not None and self.base is not None else None


@dataclass
class Folded:
    """A program's exited threads beyond its cap of thread records, as running sums (see FoldedThreads)."""

    count: int = 0
    measured: int = 0
    voluntary: int = 0
    involuntary: int = 0
    minor_faults: int = 0
    major_faults: int = 0
    cpu_time_ns: int = 0
    migrations: Optional[int] = 0
    first_seen_ns: int = 0
    last_gone_ns: int = 0
    rules: dict[int, list[int]] = field(default_factory=dict)  # rule index: [applied, not as asked]
    names: dict[tuple[str, Optional[int]], int] = field(default_factory=dict)  # (name, rule index): folded threads, bounded
    names_not_kept: int = 0  # folded threads of a (name, rule) beyond MAX_FOLDED_NAMES of them

    def add(self, t: ThreadRecord, not_as_asked: bool) -> None:
        """Count `t` (an exited thread) and add its counters, as measured to its last reading, and its name.

        The name is counted so that an expectation naming it can say its folded threads
        were not checked rather than pass on the kept ones, or say none ran.
        """
        self.first_seen_ns = t.seen_ns if not self.count else min(self.first_seen_ns, t.seen_ns)
        self.last_gone_ns = max(self.last_gone_ns, t.gone_ns or t.seen_ns)
        self.count += 1
        key = (t.comm, t.rule)
        if key in self.names or len(self.names) < MAX_FOLDED_NAMES:
            self.names[key] = self.names.get(key, 0) + 1
        else:
            self.names_not_kept += 1
        if t.rule is not None:
            counts = self.rules.setdefault(t.rule, [0, 0])
            counts[0] += 1
            counts[1] += not_as_asked
        c = t.counters()
        if c is None:
            return
        self.measured += 1
        self.voluntary += c.voluntary
        self.involuntary += c.involuntary
        self.minor_faults += c.minor_faults
        self.major_faults += c.major_faults
        self.cpu_time_ns += c.cpu_time_ns
        self.migrations = None if self.migrations is None or c.migrations is None else self.migrations + c.migrations

    def raw(self) -> FoldedThreads:
        counters = Counters(self.voluntary, self.involuntary, self.minor_faults, self.major_faults, self.cpu_time_ns, self.migrations, -1)
        rules = tuple(FoldedRule(rule, applied, missed) for rule, (applied, missed) in sorted(self.rules.items()))
        names = tuple(FoldedName(comm, rule, count) for (comm, rule), count in self.names.items())
        return FoldedThreads(
            MAX_THREADS, self.count, self.measured, counters, self.first_seen_ns, self.last_gone_ns, rules, names, self.names_not_kept
        )


class ThreadRegistry:
    """The thread records of one program: by TID while found so, retired ones, and the folded count beyond the cap."""

    def __init__(self, spec: ProgramSpec, start: Settings) -> None:
        self.spec, self.start_settings = spec, start  # what a rule asked for, to tell a thread it did not take on
        self.threads: dict[int, ThreadRecord] = {}  # by TID: the records a TID found in a listing or an event leads to
        self.retired: list[ThreadRecord] = []  # exited threads kept whose TID the kernel gave to a new thread: no longer found by it
        self.threads_seen = 0  # thread records ever made here: the next one's index
        self.folded = Folded()
        self._exemplars: set[int] = set()  # rules that did not take as asked on a thread kept for it beyond the cap

    def new_thread(self, tid: int, comm: str, seen_ns: int, pid: int) -> ThreadRecord:
        """Record a thread the monitor found (by an event or a listing) under the next index of appearance."""
        t = self.threads[tid] = ThreadRecord(tid, self.threads_seen, comm, seen_ns, seen_ns, pid=pid)
        self.threads_seen += 1
        return t

    def retire(self, t: ThreadRecord) -> None:
        """`t` exited and its TID now names a new thread: keep its record (in the results, under the cap) but out of the TIDs.

        The monitor finds a thread's record by its TID; left there, the old record would
        swallow the new thread, which would never get its rule, its snapshot or its counters.
        """
        if self.threads.get(t.tid) is t:
            del self.threads[t.tid]
            self.retired.append(t)

    def exited(self, t: ThreadRecord) -> None:
        """`t` was found gone: once the program holds more than MAX_THREADS records, fold it into `folded` instead of keeping it.

        Threads still alive keep their records whatever their number, and so does the main
        thread, and, once per rule, a thread on which the rule did not take as asked, so the
        results name one and the cell says it was degraded.  A folded thread's TID is free
        again: should the kernel reuse it, the listing records a new thread.
        """
        if len(self.threads) + len(self.retired) <= MAX_THREADS or t.index == 0 or self.threads.get(t.tid) is not t:
            return
        missed = self._not_as_asked(t)
        if missed and t.rule is not None and t.rule not in self._exemplars:
            self._exemplars.add(t.rule)
            return
        del self.threads[t.tid]
        self.folded.add(t, missed)

    def _not_as_asked(self, t: ThreadRecord) -> bool:
        """A rule was applied to `t` and the kernel refused part of it, or read back other settings than it asked for.

        Decided as the results decide it for a kept thread (outside.outcome): from the
        settings read back after the rule.  A thread gone before they could be read (the
        rule's call said ESRCH) was gone before its rule, not degraded by it.
        """
        if t.rule is None:
            return False
        read_back = next((s.settings for s in t.history.snapshots() if s.why == "rule"), None)
        if read_back is None:
            return False
        wanted = rule_settings(self.spec, self.spec.threads[t.rule], self.start_settings)
        return bool(degradation(wanted, read_back, t.rule_errors))

    def raw(self, pid: int, window_start: Optional[int], window_end: int) -> tuple[tuple[RawProgramThread, ...], Optional[FoldedThreads]]:
        """Every record kept, in the order of appearance (`pid`: the program's process, for threads of its own), and the folded."""
        records = sorted([*self.threads.values(), *self.retired], key=lambda t: t.index)
        threads = tuple(self._raw_thread(t, pid, window_start, window_end) for t in records)
        return threads, self.folded.raw() if self.folded.count else None

    def _raw_thread(self, t: ThreadRecord, pid: int, window_start: Optional[int], window_end: int) -> RawProgramThread:
        counters = t.counters()
        end = t.gone_ns if t.gone_ns is not None else window_end
        begin = max(t.seen_ns, window_start) if window_start is not None else t.seen_ns
        return RawProgramThread(
            t.tid,
            t.index,
            t.comm,
            t.seen_ns,
            t.named_ns,
            t.gone_ns,
            t.rule,
            t.rule_errors,
            t.rule_ns,
            counters,
            max(0, min(end, t.last_ns or end) - begin),
            tuple(sorted(t.cpus)),
            t.history.snapshots(),
            t.settings,
            t.pid or pid,
            t.history.gap(),
        )
