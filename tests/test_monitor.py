"""The monitor of a program's threads against a fake /proc: what it keeps of a long watch stays bounded, and says what it left out."""

from __future__ import annotations

import errno
from typing import Any

import pytest

from runner.results.document import Verdict
from runner.run import external, kernel, programthreads
from runner.run.evaluate import degradation, evaluate
from runner.run.external import Monitor, ProgramRun
from runner.run.kernel import Counters
from runner.run.outside import outcome
from runner.run.programthreads import HISTORY_FIRST, HISTORY_LAST, MAX_THREADS, SettingsHistory
from runner.run.rawcell import FoldedRule, HistoryGap, RawCell, Snapshot, Timeline
from runner.scenario.loader import load_scenario
from runner.scenario.model import Policy, ProgramSpec
from runner.scenario.plan import Settings

OTHER = Settings()
FIFO10 = Settings(Policy.FIFO, 10)
PID = 500
T0 = 10_000_000_000
TICK = 50_000_000


class FakeProc:
    """/proc as the monitor reads it: the program's live threads, each with a name, settings and a switch count."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, rule_errno: int = 0, rule_gives: Settings | None = None):
        """A rule's call fails with `rule_errno` (the thread keeps its settings), or the thread holds `rule_gives` after it."""
        self.threads: dict[int, list[Any]] = {}  # tid: [comm, settings, voluntary switches]
        self.rule_errno, self.rule_gives = rule_errno, rule_gives
        monkeypatch.setattr(kernel, "task_ids", lambda pid: list(self.threads) if pid == PID else [])
        monkeypatch.setattr(kernel, "thread_comm", lambda pid, tid: self.threads[tid][0] if tid in self.threads else None)
        monkeypatch.setattr(kernel, "thread_counters", self._counters)
        monkeypatch.setattr(kernel, "thread_settings", self._settings)
        monkeypatch.setattr(external._probe, "apply_to", self._apply)

    def add(self, tid: int, comm: str, settings: Settings = OTHER, switches: int = 10) -> None:
        self.threads[tid] = [comm, settings, switches]

    def _counters(self, pid: int, tid: int) -> Counters | None:
        if tid not in self.threads:
            return None
        n = self.threads[tid][2]
        return Counters(n, 1, 2, 0, 1000 * n, 3, 0)

    def _settings(self, tid: int, online: object) -> Settings:
        if tid not in self.threads:
            raise OSError(errno.ESRCH, "No such process")
        settings: Settings = self.threads[tid][1]
        return settings

    def _apply(self, tid: int, policy: int | None, priority: int | None, *rest: object) -> tuple[int, int, int]:
        if self.rule_errno:
            return self.rule_errno, 0, 0
        self.threads[tid][1] = self.rule_gives or Settings(Policy.FIFO, priority or 0)
        return 0, 0, 0


def _monitored(rules: list[dict[str, str]] | None = None) -> tuple[ProgramRun, Monitor]:
    spec = ProgramSpec.parse({"name": "server", "command": ["server"], "threads": rules or []})
    run = ProgramRun(spec, "/tmp", OTHER, (0, 1))
    run.pid = PID
    monitor = Monitor([run], lambda pids: (None, "no process events in this test"))
    monitor.window_start = T0
    return run, monitor


def _tick(monitor: Monitor, run: ProgramRun, n: int) -> int:
    """One listing and reading of the monitor, `n` ticks into the cell; its instant."""
    now = T0 + n * TICK
    monitor._list(run, now)
    monitor._count(run, now)
    return now


def test_a_history_keeps_its_first_and_latest_snapshots_and_its_rule_and_counts_the_changes_between():
    history = SettingsHistory(first=1, last=2)
    taken = [
        Snapshot(1, "w", OTHER, "appeared"),
        Snapshot(2, "w", Settings(nice=1), "changed"),
        Snapshot(3, "w", Settings(Policy.FIFO, 10), "rule"),
        Snapshot(4, "w", Settings(Policy.FIFO, 11), "changed"),
        Snapshot(5, "w", Settings(Policy.FIFO, 12), "changed"),
        Snapshot(6, "w", Settings(Policy.FIFO, 13), "changed"),
    ]
    for s in taken:
        history.append(s)
    assert [s.at_ns for s in history.snapshots()] == [1, 3, 5, 6], "the rule's snapshot outlives the latest two: its check reads it"
    assert history.gap() == HistoryGap(count=2, first_ns=2, last_ns=4, kept_first=1, kept_last=2)
    assert len(history) == 4
    short = SettingsHistory(first=1, last=2)
    for s in taken[:3]:
        short.append(s)
    assert short.gap() is None and len(short.snapshots()) == 3, "nothing left out: nothing said"
    with pytest.raises(ValueError, match="at least its latest"):
        SettingsHistory(first=4, last=0)


def test_a_thread_that_changes_its_priority_at_every_reading_keeps_its_first_and_latest_changes_and_counts_the_rest(monkeypatch):
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    run, monitor = _monitored()
    ticks = 1000
    instants = []
    for n in range(ticks):
        proc.threads[PID][1] = Settings(Policy.FIFO, 1 + n % 90, 0)
        instants.append(_tick(monitor, run, n))
    history = run.registry.threads[PID].history
    assert len(history) == HISTORY_FIRST + HISTORY_LAST, "the runner's memory does not grow with the changes"
    (main,) = run.raw(T0, instants[-1]).threads
    assert [s.why for s in main.history[:2]] == ["appeared", "changed"]
    taken = instants  # it appeared with the settings of the first reading, and changed at each one after
    kept = taken[:HISTORY_FIRST] + taken[-HISTORY_LAST:]
    assert [s.at_ns for s in main.history] == kept
    assert main.history[-1].settings == Settings(Policy.FIFO, 1 + (ticks - 1) % 90, 0), "it ends with the settings it ended with"
    assert main.history_gap == HistoryGap(
        count=len(taken) - HISTORY_FIRST - HISTORY_LAST,
        first_ns=taken[HISTORY_FIRST],
        last_ns=taken[-HISTORY_LAST - 1],
        kept_first=HISTORY_FIRST,
        kept_last=HISTORY_LAST,
    )


def test_threads_that_exit_beyond_the_cap_are_folded_into_counts_and_live_ones_keep_being_measured(monkeypatch):
    """A thread a request: each lives one reading; beyond the cap those that exit are counted together, the live keep records."""
    cap = 4
    monkeypatch.setattr(programthreads, "MAX_THREADS", cap)
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    for tid in (600, 601):
        proc.add(tid, "pool", switches=5)  # a worker pool that lives throughout
    run, monitor = _monitored()
    _tick(monitor, run, 0)
    requests = 30
    most = 0
    for n in range(1, requests + 1):
        proc.threads.pop(1000 + n - 1, None)
        proc.add(1000 + n, "request", switches=10)
        for tid in (PID, 600, 601):
            proc.threads[tid][2] += 1
        end = _tick(monitor, run, n)
        most = max(most, len(run.registry.threads))
    assert most <= cap + 1, "at most the cap, and the one thread that appeared since the last reading"
    raw = run.raw(T0, end)
    kept = [(t.tid, t.index, t.gone_ns is None) for t in raw.threads]
    assert kept == [(PID, 0, True), (600, 1, True), (601, 2, True), (1000 + requests, requests + 2, True)], (
        "the first request exited when the next one made five records: folded"
    )
    assert raw.threads[1].counters is not None and raw.threads[1].counters.voluntary == requests, "the pool is still measured"
    folded = raw.folded
    assert folded is not None
    gone = requests - 1
    assert (folded.cap, folded.count, folded.measured) == (cap, gone, gone)
    born_in_the_window = Counters(10 * gone, gone, 2 * gone, 0, 10_000 * gone, 3 * gone, -1)  # each one's reading, from zero
    assert folded.counters == born_in_the_window
    assert (folded.first_seen_ns, folded.last_gone_ns) == (T0 + TICK, T0 + requests * TICK)
    assert folded.rules == ()
    proc.add(1001, "reused")  # the kernel gives a folded thread's TID to a new thread: a record of its own
    _tick(monitor, run, requests + 1)
    assert run.registry.threads[1001].comm == "reused" and run.registry.threads[1001].index == requests + 3


def test_nothing_is_folded_below_the_cap_and_a_program_without_churn_says_nothing(monkeypatch):
    monkeypatch.setattr(programthreads, "MAX_THREADS", 4)
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    proc.add(600, "a")
    proc.add(601, "b")
    run, monitor = _monitored()
    _tick(monitor, run, 0)
    del proc.threads[600]
    proc.add(602, "c")
    end = _tick(monitor, run, 1)
    raw = run.raw(T0, end)
    assert [t.tid for t in raw.threads] == [PID, 600, 601, 602] and raw.folded is None
    assert all(t.history_gap is None for t in raw.threads)


def _requests_one_after_another(proc, count):
    """A program with a rule for `req*` whose `request` threads (TIDs 1001 on) come one a tick, each gone when the next
    comes; what its monitor recorded at the end."""
    run, monitor = _monitored([{"match": "req*", "sched": "fifo:10"}])
    end = _tick(monitor, run, 0)
    for n in range(1, count + 1):
        proc.threads.pop(1000 + n - 1, None)
        proc.add(1000 + n, "request")
        end = _tick(monitor, run, n)
    return run.raw(T0, end)


def test_a_rule_that_did_not_take_keeps_one_thread_beyond_the_cap_and_the_folded_say_how_many_it_missed(monkeypatch):
    monkeypatch.setattr(programthreads, "MAX_THREADS", 3)
    proc = FakeProc(monkeypatch, rule_errno=errno.EPERM)
    proc.add(PID, "server")
    raw = _requests_one_after_another(proc, 7)
    refused = [t.tid for t in raw.threads if t.rule == 0 and t.rule_errors.sched == errno.EPERM and t.gone_ns is not None]
    assert refused == [1001, 1002], "the first one (under the cap) and one kept for the rule beyond it"
    assert raw.folded is not None and raw.folded.rules == (FoldedRule(rule=0, applied=4, not_as_asked=4),)


@pytest.mark.parametrize(("gives", "missed"), [(None, 0), (Settings(Policy.FIFO, 5), 3)])
def test_folded_threads_a_rule_was_applied_to_count_those_that_read_back_other_settings(monkeypatch, gives, missed):
    """A rule the kernel took without an error can still leave other settings (a priority clamped): that is not as asked."""
    monkeypatch.setattr(programthreads, "MAX_THREADS", 2)
    proc = FakeProc(monkeypatch, rule_gives=gives)
    proc.add(PID, "server")
    raw = _requests_one_after_another(proc, 5)
    assert raw.folded is not None and raw.folded.rules == (FoldedRule(rule=0, applied=4 - bool(missed), not_as_asked=missed),), (
        "1001 to 1004 (1005 lives), but for the one kept for a rule that did not take"
    )


def test_an_hour_of_a_thread_per_request_stays_within_the_cap_of_records(monkeypatch):
    """Churn at the real cap: 6,000 threads in batches of 500 a reading, with records that never pass the cap and a batch."""
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    run, monitor = _monitored()
    _tick(monitor, run, 0)
    batch, batches = 500, 12
    most = 0
    for n in range(1, batches + 1):
        for tid in range(1000 + (n - 2) * batch, 1000 + (n - 1) * batch):
            proc.threads.pop(tid, None)
        for tid in range(1000 + (n - 1) * batch, 1000 + n * batch):
            proc.add(tid, "request")
        end = _tick(monitor, run, n)
        most = max(most, len(run.registry.threads))
    assert most <= MAX_THREADS + batch
    raw = run.raw(T0, end)
    assert raw.folded is not None
    assert len(raw.threads) + raw.folded.count == 1 + batch * batches, "every thread is either kept or counted"


def test_the_main_thread_is_never_folded(monkeypatch):
    """Its record is the program's main thread in the results (the process's settings are checked on it)."""
    monkeypatch.setattr(programthreads, "MAX_THREADS", 1)
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    proc.add(600, "worker")
    run, monitor = _monitored()
    _tick(monitor, run, 0)
    del proc.threads[PID]  # it called pthread_exit; its worker goes on
    end = _tick(monitor, run, 1)
    raw = run.raw(T0, end)
    assert [(t.tid, t.gone_ns) for t in raw.threads] == [(PID, end), (600, None)] and raw.folded is None


def _judged(tmp_path: Any, monkeypatch: pytest.MonkeyPatch, churn: list[tuple[str, int]], limit: float = 1000) -> list[Verdict]:
    """The verdicts of `expect: server/flush involuntary.total <= limit` on a program whose threads come and go.

    `churn` is (name, how many) in order: each such thread appears, is read once and exits,
    with MAX_THREADS at 4, so the first few are kept and the rest folded.
    """
    monkeypatch.setattr(programthreads, "MAX_THREADS", 4)
    path = tmp_path / "churn.yaml"
    path.write_text(
        "name: churn\nduration: 1s\nprocesses:\n  - name: server\n    command: [server]\n"
        f"expect:\n  - {{thread: server/flush, metric: involuntary.total, max: {limit}}}\n"
    )
    cell = load_scenario(str(path)).cells[0]
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    run = ProgramRun(cell.scenario.programs[0], "/tmp", OTHER, (0, 1))
    run.pid = PID
    monitor = Monitor([run], lambda pids: (None, "no process events in this test"))
    monitor.window_start = T0
    n = 0
    end = _tick(monitor, run, n)
    tid = 700
    for name, count in churn:
        for _ in range(count):
            proc.add(tid, name)
            _tick(monitor, run, n := n + 1)
            del proc.threads[tid]
            end = _tick(monitor, run, n := n + 1)
            tid += 1
    raw = RawCell("2026-01-01T00:00:00+00:00", (), 0, Timeline(0, T0, end, end, end), programs=(run.raw(T0, end),))
    result = evaluate(cell, cell.scenario, raw, allow_degraded=False)
    return [v for v in result.expectations if v.thread.startswith("server/flush")]


def test_an_expectation_on_a_name_whose_threads_were_all_folded_is_not_measured_and_says_they_were_folded(tmp_path, monkeypatch):
    """Every flush thread came after the cap was full and was folded: they ran, so "no thread of that name ran" would be false."""
    verdicts = _judged(tmp_path, monkeypatch, [("request", 10), ("flush", 20)])
    assert [(v.passed, v.measured, v.note) for v in verdicts] == [
        (False, None, "not measured (20 threads of that name were folded (beyond 4 thread records) and not checked)")
    ]


def test_an_expectation_kept_threads_pass_does_not_pass_the_cell_when_others_of_that_name_were_folded(tmp_path, monkeypatch):
    """Two flush threads were kept and pass; eighteen more were folded unchecked: the cell must not read as passed."""
    verdicts = _judged(tmp_path, monkeypatch, [("flush", 20)])
    kept = [v for v in verdicts if v.measured is not None]
    assert kept and all(v.passed for v in kept), "the kept ones are checked as before"
    unchecked = [v for v in verdicts if v.measured is None]
    assert [(v.passed, v.note) for v in unchecked] == [
        (
            False,
            f"not measured ({20 - len(kept)} threads of that name were folded (beyond 4 thread records) and not checked; "
            "the verdicts of the kept threads of that name do not speak for them)",
        )
    ]


def test_an_expectation_on_a_name_no_thread_had_still_says_none_ran_beside_folded_threads_of_other_names(tmp_path, monkeypatch):
    verdicts = _judged(tmp_path, monkeypatch, [("request", 20)])
    assert [(v.passed, v.note) for v in verdicts] == [(False, "not measured (no thread of that name ran)")]


def test_folded_names_are_bounded_and_a_name_beyond_them_is_said_to_be_possibly_among_the_folded(tmp_path, monkeypatch):
    monkeypatch.setattr(programthreads, "MAX_FOLDED_NAMES", 3)
    verdicts = _judged(tmp_path, monkeypatch, [("request", 4), ("a", 1), ("b", 1), ("c", 1), ("flush", 2), ("d", 1)])
    assert [(v.passed, v.note) for v in verdicts] == [
        (
            False,
            "not measured (4 folded threads (beyond 4 thread records) whose names were not kept may be of that name, and were not checked)",
        )
    ]


def _request_gone(monkeypatch):
    """A program (cap of 4 records, a rule for `worker`) whose `request` thread, TID 700, came at tick 1 and was gone at 2."""
    monkeypatch.setattr(programthreads, "MAX_THREADS", 4)
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    run, monitor = _monitored([{"match": "worker", "sched": "fifo:10"}])
    _tick(monitor, run, 0)
    proc.add(700, "request")
    _tick(monitor, run, 1)
    del proc.threads[700]
    _tick(monitor, run, 2)
    return proc, run, monitor


@pytest.mark.parametrize("later", [1, 40], ids=["within the rename watch", "seconds later"])
def test_a_new_thread_on_the_reused_tid_of_a_kept_exited_record_is_recorded_and_gets_its_rule(monkeypatch, later):
    """Below the cap an exited thread's record is kept; the kernel may give its TID to a new thread, which is a thread of its own."""
    proc, run, monitor = _request_gone(monkeypatch)
    assert run.registry.threads[700].gone_ns == T0 + 2 * TICK, "below the cap: kept, gone"
    for n in range(3, 2 + later):
        _tick(monitor, run, n)
    proc.add(700, "worker", switches=5)
    end = _tick(monitor, run, 2 + later)
    worker = run.registry.threads[700]
    assert (worker.comm, worker.gone_ns, worker.rule, worker.index) == ("worker", None, 0, 2)
    assert proc.threads[700][1] == FIFO10, "its rule was applied"
    raw = run.raw(T0, end)
    records = [(t.tid, t.comm, t.gone_ns) for t in raw.threads]
    assert records == [(PID, "server", None), (700, "request", T0 + 2 * TICK), (700, "worker", None)], "both, in order of appearance"
    assert [t.index for _, t in outcome(raw, T0, end, False, degradation).threads] == [0, 1, 1], "each first of its name"


def test_a_reused_tid_announced_by_an_event_is_a_new_thread_and_a_late_event_of_the_old_one_is_not(monkeypatch):
    proc, run, monitor = _request_gone(monkeypatch)
    monitor._appeared(run, 700, T0 + TICK - 1)  # the old thread's creation, read late: its record, still
    assert run.registry.threads[700].comm == "request" and not run.registry.retired
    proc.add(700, "worker")
    monitor._renamed(run, 700, "worker", T0 + 3 * TICK)
    assert (run.registry.threads[700].comm, run.registry.threads[700].rule) == ("worker", 0) and [t.comm for t in run.registry.retired] == [
        "request"
    ]


def test_records_out_of_their_tid_count_toward_the_cap(monkeypatch):
    monkeypatch.setattr(programthreads, "MAX_THREADS", 3)
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    run, monitor = _monitored()
    _tick(monitor, run, 0)
    n = 0
    for _ in range(6):  # one TID reused again and again
        proc.add(700, "request")
        _tick(monitor, run, n := n + 1)
        del proc.threads[700]
        end = _tick(monitor, run, n := n + 1)
    raw = run.raw(T0, end)
    assert len(raw.threads) <= 3 + 1 and raw.folded is not None and len(raw.threads) + raw.folded.count == 7


def test_a_folded_thread_gone_before_its_rule_landed_is_not_counted_as_not_as_asked(monkeypatch):
    """The rule's call found the thread gone (ESRCH) and nothing was read back: a kept one shows no degradation, nor does the count."""
    monkeypatch.setattr(programthreads, "MAX_THREADS", 2)
    proc = FakeProc(monkeypatch)
    proc.add(PID, "server")
    run, monitor = _monitored([{"match": "req*", "sched": "fifo:10"}])
    _tick(monitor, run, 0)

    def exits_as_the_rule_lands(tid: int, *settings: object) -> tuple[int, int, int]:
        proc.threads.pop(tid, None)
        return errno.ESRCH, errno.ESRCH, 0

    monkeypatch.setattr(external._probe, "apply_to", exits_as_the_rule_lands)
    for n in range(1, 8):
        proc.add(1000 + n, "request")
        end = _tick(monitor, run, n)
    raw = run.raw(T0, end)
    out = outcome(raw, T0, end, False, degradation)
    assert all(not t.degraded for _, t in out.threads)
    assert raw.folded is not None and raw.folded.rules == (FoldedRule(rule=0, applied=raw.folded.count, not_as_asked=0),)
    assert [t.tid for t in raw.threads if t.rule == 0] == [1001], "no thread kept as the rule's example of not taking"
