"""Programs (command:) in the pure evaluation core: raw readings from outside in, threads, failures and verdicts out."""

from __future__ import annotations

import json
import os
import re
import signal

import jsonschema
import pytest

from runner.report.markdown import program_lines, threads_table
from runner.results.document import CellResult, RunDocument, Status, results_schema
from runner.results.read import load
from runner.run.evaluate import degradation, evaluate
from runner.run.kernel import Counters
from runner.run.outside import outcome
from runner.run.rawcell import (
    ApplyErrors,
    FoldedRule,
    FoldedThreads,
    HistoryGap,
    OutputCount,
    RawCell,
    RawProgram,
    RawProgramThread,
    Snapshot,
    Timeline,
)
from runner.scenario.loader import load_scenario
from runner.scenario.model import Policy, ProgramSpec
from runner.scenario.plan import Settings, first_rule, program_settings, rule_settings

OTHER = Settings()
FIFO80 = Settings(Policy.FIFO, 80, 0, (1,))
T0 = 10_000_000_000
SECOND = 1_000_000_000


def _spec(**extra: object) -> ProgramSpec:
    data = {"name": "talker", "command": ["rtprog"], "sched": "fifo:80", "cpus": "1", **extra}
    return ProgramSpec.parse(data)


def _thread(tid: int, index: int, comm: str, settings: Settings, rule: int | None = None, **extra: object) -> RawProgramThread:
    history = [Snapshot(T0 - 5, comm, settings if rule is None else OTHER, "appeared")]
    if rule is not None:
        history.append(Snapshot(T0 - 4, comm, settings, "rule"))
    fields: dict[str, object] = {
        "tid": tid,
        "index": index,
        "comm": comm,
        "seen_ns": T0 - 5,
        "named_ns": T0 - 5,
        "gone_ns": None,
        "rule": rule,
        "rule_errors": ApplyErrors(),
        "rule_ns": T0 - 4 if rule is not None else None,
        "counters": Counters(100, 250, 3, 0, 400_000_000, 2, 1),
        "measured_ns": SECOND // 2,
        "cpus_seen": (1,),
        "history": tuple(history),
        "applied": settings,
    }
    fields.update(extra)
    return RawProgramThread(**fields)  # type: ignore[arg-type]


def _program(spec: ProgramSpec, threads: tuple[RawProgramThread, ...], **extra: object) -> RawProgram:
    fields: dict[str, object] = {
        "spec": spec,
        "start": OTHER,
        "pid": 500,
        "path": "/usr/bin/rtprog",
        "start_errors": ApplyErrors(),
        "failure": "",
        "released_ns": T0 - 100,
        "exited_ns": T0 + SECOND,
        "exit_code": None,
        "exit_signal": signal.SIGTERM,
        "stopped": "SIGTERM",
        "stdout": "talker.stdout",
        "stderr": "talker.stderr",
        "tail": ("talker.stderr: boom",),
        "threads": threads,
    }
    fields.update(extra)
    return RawProgram(**fields)  # type: ignore[arg-type]


def test_a_rule_matches_by_shell_pattern_and_the_first_match_wins():
    spec = _spec(threads=[{"match": "rt_sub*", "sched": "fifo:70"}, {"match": "rt_*", "sched": "rr:10"}])
    assert first_rule(spec, "rt_sub_1") == 0
    assert first_rule(spec, "rt_pub") == 1
    assert first_rule(spec, "ctl_loop") is None
    assert rule_settings(spec, spec.threads[0], OTHER) == Settings(Policy.FIFO, 70, 0, (1,))


def test_reset_on_fork_keeps_the_main_threads_settings_and_resets_those_of_the_threads_it_creates():
    main, others = program_settings(_spec(reset_on_fork=True), OTHER)
    assert (main.policy, main.priority) == (Policy.FIFO, 80)
    assert (others.policy, others.priority, others.cpus) == (Policy.OTHER, 0, (1,))
    main, others = program_settings(_spec(), OTHER)
    assert main == others


def test_threads_are_named_by_their_own_names_with_stable_ordinals_and_rates_per_second():
    spec = _spec()
    raw = _program(
        spec,
        (
            _thread(500, 0, "rtprog", FIFO80),
            _thread(502, 2, "worker", FIFO80),
            _thread(501, 1, "ctl_loop", FIFO80),
            _thread(503, 3, "worker", FIFO80),
        ),
    )
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    labels = [t.label(False) for _, t in out.threads]
    assert labels == ["talker/rtprog (main)", "talker/worker #1", "talker/ctl_loop #1", "talker/worker #2"]
    ctl = out.threads[2][1]
    assert ctl.program and ctl.figures.involuntary.total == 250
    assert ctl.figures.involuntary.per_second == 500.0  # 250 in half a second
    assert ctl.figures.voluntary.per_second == 200.0
    assert (ctl.figures.cpu_time_ns, ctl.figures.migrations, ctl.figures.cpus_seen) == (400_000_000, 2, (1,))
    assert out.failures == [] and out.warnings == []
    assert out.result.exit_signal == "SIGTERM" and out.result.stopped == "SIGTERM" and out.result.started


def test_only_what_the_runner_asked_for_is_checked_against_the_kernel():
    spec = _spec(threads=[{"match": "ctl_loop", "sched": "fifo:90"}])
    raw = _program(
        spec,
        (
            _thread(500, 0, "rtprog", Settings(Policy.OTHER, 0, 0, (1,))),  # the kernel refused the process's FIFO 80
            _thread(501, 1, "ctl_loop", FIFO80, rule=0),  # the rule asked for 90
            _thread(502, 2, "helper", Settings(Policy.RR, 5, 0, None)),  # the program set its own: none of the runner's business
        ),
        start_errors=ApplyErrors(sched=1),
    )
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    degraded = {t.name: t.degraded for _, t in out.threads}
    assert degraded["rtprog"] == ["policy fifo:80 requested, other applied (Operation not permitted)"]
    assert degraded["ctl_loop"] == ["policy fifo:90 requested, fifo:80 applied"]
    assert degraded["helper"] == []
    assert out.threads[1][1].rule == "ctl_loop" and out.threads[1][1].rule_after_ns == 1


@pytest.mark.parametrize(
    ("until", "code", "sig", "stopped", "failure"),
    [
        ("end", 0, None, "", "exited with code 0 0.50s into the cell; with until: end it must run the whole cell"),
        ("end", None, signal.SIGSEGV, "", "was killed by SIGSEGV 0.50s into the cell"),
        ("exit", 3, None, "", "exited with code 3 0.50s into the cell; its last output: talker.stderr: boom"),
        ("exit", 0, None, "", None),
        ("exit", None, signal.SIGTERM, "SIGTERM", "did not exit within the cell's 1.00 s and was stopped with SIGTERM"),
        ("end", None, signal.SIGTERM, "SIGTERM", None),
    ],
)
def test_how_a_program_ended_decides_whether_the_cell_was_measured_as_written(until, code, sig, stopped, failure):
    raw = _program(_spec(until=until), (_thread(500, 0, "rtprog", FIFO80),), exit_code=code, exit_signal=sig, stopped=stopped)
    raw = RawProgram(**{**raw.__dict__, "exited_ns": T0 + SECOND // 2})
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    if failure is None:
        assert out.failures == []
    else:
        assert len(out.failures) == 1 and failure in out.failures[0], out.failures


def test_a_thread_that_ended_on_its_own_finished_and_only_a_program_cut_short_did_not():
    """A program's thread that exited mid-run (rt-app's threads, once their loops are done) was labelled "(did not finish)"
    (issue 40, 15): a thread exits only by itself, or with its process; only a program killed by a signal the runner did
    not send (a crash) or an interrupted cell leaves its threads unfinished."""
    done = _thread(501, 1, "worker", FIFO80, gone_ns=T0 + SECOND // 4)
    raw = _program(_spec(), (_thread(500, 0, "rtprog", FIFO80), done))
    finished = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert [t.figures.complete for _, t in finished.threads] == [True, True]
    assert "(did not finish)" not in str(threads_table([(t.label(False), t) for _, t in finished.threads]).render())
    crashed = RawProgram(**{**raw.__dict__, "exit_signal": signal.SIGSEGV, "stopped": "", "exited_ns": T0 + SECOND // 2})
    assert [t.figures.complete for _, t in outcome(crashed, T0, T0 + SECOND, False, degradation).threads] == [False, False]
    assert [t.figures.complete for _, t in outcome(raw, T0, T0 + SECOND, True, degradation).threads] == [False, False]


MISSING = "program 'nosuch' is not in PATH (/usr/bin)"


def test_a_program_the_cell_left_at_its_gate_did_not_start_and_claims_no_duration_nor_signal():
    """A second program missing from PATH stopped the cell before its start: the first, held at its gate, never ran."""
    gated = _program(_spec(until="exit"), (), released_ns=None, exited_ns=T0, tail=())  # stopped with SIGTERM, as the shell once said
    out = outcome(gated, None, T0, False, degradation, MISSING)
    assert out.failures == [] and out.warnings == []
    assert not out.result.started and out.result.failure == f"did not start: the cell stopped before its start because {MISSING}"
    never_launched = _program(_spec(), (), pid=0, path="", released_ns=None, exited_ns=None, exit_signal=None, stopped="", tail=())
    assert outcome(never_launched, None, T0, False, degradation).result.failure == "did not start: the cell stopped before its start"
    released = _program(_spec(until="exit"), (_thread(500, 0, "rtprog", FIFO80),))  # exec'd, then stopped with the cell, unstarted
    assert outcome(released, None, T0 + SECOND, False, degradation, MISSING).failures == []


def test_a_cell_stopped_before_its_start_by_a_missing_program_says_only_that(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(
        "name: two\nduration: 1s\nprocesses:\n  - {name: quitter, command: [sleep, '1'], until: exit}\n"
        "  - {name: missing, command: [nosuch]}\n"
    )
    cell = load_scenario(os.fspath(path)).cells[0]
    quitter, missing = cell.scenario.programs
    raw = RawCell(
        "2026-01-01T00:00:00+00:00",
        (),
        0,
        Timeline(0, None, None, None, T0),
        failures=(MISSING,),
        programs=(
            _program(quitter, (), released_ns=None, exited_ns=T0, exit_signal=None, stopped="", tail=()),
            _program(missing, (), pid=0, path="", failure=MISSING, released_ns=None, exited_ns=None, exit_signal=None, stopped=""),
        ),
    )
    result = evaluate(cell, cell.scenario, raw, allow_degraded=False)
    assert result.status is Status.ERROR and result.reason == MISSING
    lines = program_lines(result)
    assert f"did not start: the cell stopped before its start because {MISSING}" in lines[0] and "SIGTERM" not in lines[0]
    assert f"could not start: {MISSING}" in lines[1]


def test_a_program_stopped_at_its_gate_is_not_said_to_have_been_stopped_with_sigterm(monkeypatch, tmp_path):
    """A short real fork: the child waits at its gate, never execs; stopping it records no signal and no exit of the program."""
    from runner.run import external, memcg

    class Guard:
        def watch(self, pgid: int) -> None: ...
        def forget(self, pgid: int) -> None: ...
        def watch_cgroup(self, path: str) -> None: ...
        def forget_cgroup(self, path: str) -> None: ...

    monkeypatch.setattr(memcg, "hierarchy", lambda limit=True: (None, "no cgroup in this test"))
    spec = ProgramSpec.parse({"name": "quitter", "command": ["true"], "until": "exit"})
    run = external.ProgramRun(spec, str(tmp_path), OTHER, (0,))
    run.launch(Guard())
    assert run.pid and not run.failure
    run.stop(Guard())  # the cell stopped before releasing it
    raw = run.raw(None, T0)
    assert run.stopped == "" and raw.stopped == "" and raw.exit_code is None and raw.exit_signal is None and raw.released_ns is None
    assert os.waitid(os.P_PID, run.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None, "ended, its PID still held"
    run.reap()
    with pytest.raises(ChildProcessError):
        os.waitpid(run.pid, os.WNOHANG)  # reaped


def test_a_program_that_ignored_sigterm_is_a_warning_and_a_rule_that_matched_nothing_too():
    raw = _program(
        _spec(threads=[{"match": "rt_*", "sched": "fifo:70"}]),
        (_thread(500, 0, "rtprog", FIFO80),),
        exit_signal=signal.SIGKILL,
        stopped="SIGKILL",
    )
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert out.failures == []
    assert out.warnings == [
        "program talker did not exit within 1s of SIGTERM and was killed (SIGKILL)",
        "program talker: no thread matched the rule 'rt_*'; its threads: rtprog",
    ]


def test_an_expectation_on_a_program_thread_that_never_appeared_fails_in_words(tmp_path):
    path = tmp_path / "prog.yaml"
    path.write_text(
        "name: prog\nduration: 1s\nprocesses:\n  - name: talker\n    command: [rtprog]\n"
        "expect:\n  - {thread: talker/ctl_loop, metric: involuntary.per_second, max: 5}\n"
        "  - {thread: talker/rtprog, metric: involuntary.per_second, max: 5}\n"
    )
    loaded = load_scenario(os.fspath(path))
    cell = loaded.cells[0]
    spec = cell.scenario.programs[0]
    raw = RawCell(
        "2026-01-01T00:00:00+00:00",
        (),
        0,
        Timeline(0, T0, T0 + SECOND, T0 + SECOND, T0 + SECOND),
        programs=(_program(spec, (_thread(500, 0, "rtprog", OTHER),)),),
    )
    result = evaluate(cell, cell.scenario, raw, allow_degraded=False)
    verdicts = {v.thread: v for v in result.expectations}
    assert not verdicts["talker/ctl_loop"].passed and verdicts["talker/ctl_loop"].note == "not measured (no thread of that name ran)"
    main = verdicts["talker/rtprog (main)"]
    assert main.measured == 500.0 and not main.passed  # 250 involuntary switches in half a second, against at most 5/s
    assert result.status is Status.FAILED
    assert [t.name for t in result.threads] == ["rtprog"] and result.programs[0].pid == 500


def test_an_expectation_judges_every_thread_it_names_and_one_without_the_figure_fails_not_measured(tmp_path):
    """Issue 40: `latency.max` on a program's thread once dropped out of the verdicts (no case in JUnit, exit 0); a bare
    name that also names a program's thread judges that thread too, and a traced figure without the trace says why."""
    from runner.figures import figure
    from runner.report.cellview import render_cell
    from runner.report.junit import junit_xml
    from runner.run.rawcell import RawThread
    from runner.run.samples import Sample, slot_of
    from runner.scenario.plan import plan_scenario

    path = tmp_path / "mixed.yaml"
    path.write_text(
        "name: mixed\nduration: 1s\nprocesses:\n  - name: own\n    threads: [{name: ctl_loop, work: {kind: periodic, period: 100ms}}]\n"
        "  - {name: talker, command: [rtprog]}\n"
        "expect:\n  - {thread: ctl_loop, metric: latency.max, max: 1ms}\n  - {thread: talker/ctl_loop, metric: wakeup.max, max: 1ms}\n"
    )
    cell = load_scenario(os.fspath(path)).cells[0]
    period = 100_000_000
    threads = []
    for p in plan_scenario(cell.scenario, OTHER):
        at = [T0 + k * period for k in range(10 if p.index else 0)]
        samples = [Sample(t, t + 20_000, t + 60_000, 40_000, k, 0, 1, 0, 0, 0, 0, 0, period, t + period) for k, t in enumerate(at)]
        slot = slot_of(samples, tid=100 + p.index, cpus_seen=(0,), work_start_ns=T0)
        threads.append(RawThread(p, 99, slot, p.settings, ApplyErrors(), True))
    program = _program(cell.scenario.programs[0], (_thread(500, 0, "rtprog", OTHER), _thread(501, 1, "ctl_loop", OTHER)))
    raw = RawCell("now", tuple(threads), 1, Timeline(0, T0, T0 + SECOND, T0 + SECOND, T0 + SECOND), programs=(program,))
    result = evaluate(cell, cell.scenario, raw, allow_degraded=False)
    verdicts = [(v.thread, v.metric, v.passed, v.note) for v in result.expectations]
    assert verdicts == [
        ("own/ctl_loop #1", "latency.max", True, ""),
        (
            "talker/ctl_loop #1",
            "latency.max",
            False,
            "not measured (latency.max is measured per callback; this is a thread of a command: program (measured from /proc))",
        ),
        ("talker/ctl_loop #1", "wakeup.max", False, "not measured (the scheduler trace did not run: not asked for (--no-trace))"),
    ]
    assert result.status is Status.FAILED
    text = render_cell(result)
    assert "FAIL talker/ctl_loop #1: latency.max <= 1ms: not measured (latency.max is measured per callback;" in text
    assert "measured not measured" not in text
    doc = RunDocument.model_validate({"scenario": {"name": "mixed", "path": os.fspath(path)}, "cells": [result.model_dump()]})
    xml = junit_xml(doc).decode()
    assert xml.count("<testcase") == 4, "the run and each of the three verdicts"
    words = figure("wakeup.max").words
    assert f"talker/ctl_loop #1: {words} &lt;= 1ms: not measured (the scheduler trace did not run: not asked for (--no-trace))" in xml
    assert "measured not measured" not in xml and "not measured (not measured" not in xml


def test_a_program_that_raises_a_thread_to_priority_99_is_an_error_unless_allowed_and_then_a_warning():
    """Issue 40: a program that made itself FIFO 99 (chrt -f 99, sched_setscheduler) passed without a word.  The runner cannot
    refuse it beforehand; the kernel's read-back shows it, and a spinning thread at 99 can starve the watchdog (FIFO 99 too)."""
    fifo99 = Settings(Policy.FIFO, 99)
    raised = _thread(
        501,
        1,
        "ctl_loop",
        fifo99,
        history=(Snapshot(T0 - 5, "ctl_loop", OTHER, "appeared"), Snapshot(T0 + SECOND // 4, "ctl_loop", fifo99, "changed")),
    )
    raw = _program(_spec(sched=None, cpus=None), (_thread(500, 0, "rtprog", OTHER), raised))
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert out.failures == [
        "program talker raised thread ctl_loop (tid 501, fifo:99 0.25s into the cell) to RT priority 99, the runner watchdog's own, "
        "which the runner refuses without --allow-priority-99: spinning there it could have kept the watchdog from stopping the "
        "cell; lower the program's priority to 98 or less, or pass --allow-priority-99"
    ]
    allowed = outcome(raw, T0, T0 + SECOND, False, degradation, allow_priority_99=True)
    assert allowed.failures == [] and allowed.warnings == [
        "program talker ran thread ctl_loop (tid 501, fifo:99 0.25s into the cell) at RT priority 99, the runner watchdog's own "
        "(--allow-priority-99)"
    ]
    assert outcome(raw, T0, T0 + SECOND, False, degradation).result.degraded == [], "its own doing, not a setting refused"
    watched = _program(_spec(sched=None, cpus=None), raw.threads, attached=True, exited_ns=None)
    assert outcome(watched, T0, T0 + SECOND, False, degradation).failures == [], "runner watch only looks"
    at_80 = _program(_spec(), (_thread(500, 0, "rtprog", FIFO80),))
    assert outcome(at_80, T0, T0 + SECOND, False, degradation).failures == []


def test_watch_rules_are_written_pattern_sched_at_cpus_and_refused_in_words():
    from runner.errors import UsageError
    from runner.watch import parse_rule, resolve_targets

    rule = parse_rule("ctl_*=fifo:80@1")
    assert (rule.match, rule.sched and rule.sched.label(), rule.cpus) == ("ctl_*", "fifo:80", (1,))
    assert parse_rule("mw_*@0").sched is None
    with pytest.raises(UsageError) as bad_priority:
        parse_rule("x=fifo:bad")
    assert "priority 'bad' in 'fifo:bad' is not an integer" in str(bad_priority.value) and "Value error" not in str(bad_priority.value)
    for bad, words in (("ctl_loop", "expected PATTERN=SCHED"), ("x=fifo:200", "rule"), ("=fifo:80", "expected PATTERN")):
        with pytest.raises(UsageError, match=words):
            parse_rule(bad)
    with pytest.raises(UsageError, match="no live process is named 'no-such-proc-xyz'"):
        resolve_targets(["no-such-proc-xyz"])
    with pytest.raises(UsageError, match="no live process has PID 999999999"):
        resolve_targets(["999999999"])
    with pytest.raises(UsageError, match="is this runner itself"):  # it once watched nothing and passed
        resolve_targets([str(os.getpid())])


def test_how_the_threads_were_found_is_kept_and_the_report_says_when_it_was_the_slower_listing():
    threads = (_thread(500, 0, "rtprog", FIFO80),)
    by_events = outcome(_program(_spec(), threads, seen_by="events"), T0, T0 + SECOND, False, degradation).result
    note = "the kernel did not acknowledge a listen"
    listed = outcome(_program(_spec(), threads, seen_by="listing", seen_note=note), T0, T0 + SECOND, False, degradation).result
    assert (by_events.threads_seen_by, listed.threads_seen_by, listed.threads_seen_note) == ("events", "listing", note)
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[by_events])
    assert "listing /proc" not in program_lines(cell)[0]
    cell.programs = [listed]
    assert f"its threads were found by listing /proc every 2 ms, not by the kernel's process events ({note})" in program_lines(cell)[0]
    dropped = "the kernel dropped process events 1 time(s) (the runner fell behind); threads that appeared then were found by listing"
    cell.programs = [by_events.model_copy(update={"threads_seen_note": dropped})]
    assert program_lines(cell)[0].endswith(dropped)


def test_a_program_the_oom_killer_ended_at_its_memory_max_is_an_error_that_says_so():
    spec = _spec(memory_max="32MiB")
    raw = _program(spec, (_thread(500, 0, "rtprog", FIFO80),), exit_signal=signal.SIGKILL, stopped="", oom_kills=1, memory_limit=32 << 20)
    raw = RawProgram(**{**raw.__dict__, "exited_ns": T0 + SECOND // 2, "memory_peak": 32 << 20})
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert len(out.failures) == 1
    assert "was killed by the OOM killer (SIGKILL): its cgroup reached its memory_max of 32MiB" in out.failures[0]
    assert (out.result.memory_max, out.result.memory_peak, out.result.oom_kills) == (32 << 20, 32 << 20, 1)
    cell = CellResult(id="c", spec_hash="-", status=Status.ERROR, started_at="", duration_ns=SECOND, programs=[out.result])
    assert (
        "killed by the OOM killer (SIGKILL) at its memory_max after 500.00 ms; memory_max 32 MiB, peak 32 MiB, 1 OOM kill"
        in (program_lines(cell)[0])
    )


def test_an_oom_kill_of_something_the_program_started_is_a_warning_and_an_unapplied_limit_is_a_degradation():
    spec = _spec(memory_max="32MiB")
    raw = _program(spec, (_thread(500, 0, "rtprog", FIFO80),), oom_kills=2, memory_limit=32 << 20)
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert out.failures == [] and "program talker: the OOM killer ended 2 of its tasks at its memory_max of 32MiB" in out.warnings
    raw = _program(spec, (_thread(500, 0, "rtprog", FIFO80),), memory_note="cgroup v1: Permission denied")
    assert "memory_max 32MiB not applied: cgroup v1: Permission denied" in outcome(raw, T0, T0 + SECOND, False, degradation).result.degraded


def test_a_program_that_sets_its_own_policy_as_it_starts_is_not_degraded_and_a_watched_one_is_not_checked():
    """A program that made itself FIFO 50 before the first look was an error (`policy other requested`), one that
    did it 0.5 s later passed; and `runner watch` of any RT process was an error."""
    mine = Settings(Policy.FIFO, 50, 0, None)
    spec = ProgramSpec.parse({"name": "rtspin", "command": ["rtspin"]})
    out = outcome(_program(spec, (_thread(500, 0, "rtspin", mine),)), T0, T0 + SECOND, False, degradation)
    assert [t.degraded for _, t in out.threads] == [[]] and out.result.degraded == [] and out.warnings == []
    watched = _program(spec, (_thread(500, 0, "rtspin", mine),), attached=True)
    assert [t.degraded for _, t in outcome(watched, T0, T0 + SECOND, False, degradation).threads] == [[]]
    # Asked for FIFO 80 (the kernel took it before exec) and then changed by the program: words, not an error.
    changed = outcome(_program(_spec(), (_thread(500, 0, "rtprog", mine),)), T0, T0 + SECOND, False, degradation)
    assert changed.failures == [] and [t.degraded for _, t in changed.threads] == [[]]
    assert any("held other settings than the runner gave it before exec" in w and "fifo:80 requested" in w for w in changed.warnings)


def test_a_rule_that_matched_the_main_thread_is_checked_against_the_rule():
    """`match: '*'` at fifo:5 was checked against the process's settings: an error when the rule worked."""
    spec = ProgramSpec.parse({"name": "star", "command": ["sleep", "10"], "threads": [{"match": "*", "sched": "fifo:5"}]})
    worked = _program(spec, (_thread(500, 0, "sleep", Settings(Policy.FIFO, 5, 0, None), rule=0),))
    assert [t.degraded for _, t in outcome(worked, T0, T0 + SECOND, False, degradation).threads] == [[]]
    refused = _program(spec, (_thread(500, 0, "sleep", OTHER, rule=0, rule_errors=ApplyErrors(sched=1)),))
    assert [t.degraded for _, t in outcome(refused, T0, T0 + SECOND, False, degradation).threads] == [
        ["policy fifo:5 requested, other applied (Operation not permitted)"]
    ]


def test_a_program_seen_stopped_is_an_error_that_says_when():
    raw = _program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), halted_ns=T0 + SECOND // 4, exit_signal=signal.SIGKILL, stopped="SIGKILL")
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert out.failures == [
        "program talker (pid 500) was stopped (SIGSTOP or a debugger) 0.25s into the cell; its threads could not run while it was"
    ]
    assert outcome(raw, T0, T0 + SECOND, True, degradation).failures == [], "interrupted: the user's stop says it"


def test_a_program_is_stopped_when_two_ticks_find_it_so_and_a_tracers_stop_is_not_one(monkeypatch):
    from runner.run import external, kernel

    states = iter(["t", "S", "T", "S", "T", "T", "T"])
    monkeypatch.setattr(kernel, "process_state", lambda pid: next(states))
    run = external.ProgramRun(_spec(), "/tmp", OTHER, (0, 1))
    run.pid = 500
    monkeypatch.setattr(run, "poll", lambda: False)
    seen = []
    for _ in range(6):
        run.watch_state()
        seen.append(run.halted_ns is not None)
    assert seen == [False, False, False, False, False, True], "strace's t, then T once, then T twice in a row"


def test_watch_rules_are_refused_as_a_scenarios_are_priority_99_and_cpus_this_machine_lacks():
    from runner.errors import UsageError
    from runner.run.preflight import check_rules
    from runner.watch import parse_rule

    with pytest.raises(UsageError, match="--rule '\\*' asks for RT priority 99"):
        check_rules([parse_rule("*=fifo:99")], False, {0, 1})
    check_rules([parse_rule("*=fifo:99")], True, {0, 1})
    with pytest.raises(UsageError, match="--rule 'ctl' asks for CPUs 7"):
        check_rules([parse_rule("ctl=fifo:80@7")], False, {0, 1})
    check_rules([parse_rule("ctl=rr:98@1")], False, {0, 1})


def test_a_program_without_a_cgroup_of_its_own_is_a_warning_that_says_what_escapes():
    """Where no cgroup could be made (a user's session folder is root's), a child that setsid()s outlived the cell unsaid."""
    why = "cgroup v2: Permission denied"
    raw = _program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), memory_note=why)
    said = [w for w in outcome(raw, T0, T0 + SECOND, False, degradation).warnings if "no cgroup of its own" in w]
    assert said == [
        f"program talker has no cgroup of its own ({why}): what it starts in a session of its own (setsid, a daemon) "
        "is neither measured nor stopped with it"
    ]
    held = _program(_spec(), (_thread(500, 0, "rtprog", FIFO80),))
    assert not [w for w in outcome(held, T0, T0 + SECOND, False, degradation).warnings if "cgroup" in w]


CHURN = FoldedThreads(
    cap=4096,
    count=12_000,
    measured=11_990,
    counters=Counters(36_000, 1_200, 48_000, 2, 9_000_000_000, 600, -1),
    first_seen_ns=T0 + SECOND,
    last_gone_ns=T0 + 58 * SECOND,
    rules=(FoldedRule(rule=0, applied=11_000, not_as_asked=3),),
)
BOOSTED = HistoryGap(count=1_234, first_ns=T0 + 2_100_000_000, last_ns=T0 + 58 * SECOND, kept_first=16, kept_last=48)


def _churned() -> RawProgram:
    """A server that ran a thread a request (most of them folded) and boosted its main thread's priority at every callback."""
    spec = _spec(threads=[{"match": "req*", "sched": "fifo:70"}])
    return _program(spec, (_thread(500, 0, "rtprog", FIFO80, history_gap=BOOSTED),), folded=CHURN)


def test_folded_threads_and_a_history_that_left_changes_out_are_in_the_results_from_the_start_gate():
    out = outcome(_churned(), T0, T0 + 60 * SECOND, False, degradation)
    folded = out.result.threads_folded
    assert folded is not None
    assert (folded.cap, folded.count, folded.measured) == (4096, 12_000, 11_990)
    assert (folded.voluntary, folded.involuntary, folded.minor_faults, folded.major_faults) == (36_000, 1_200, 48_000, 2)
    assert (folded.cpu_time_ns, folded.migrations) == (9_000_000_000, 600)
    assert (folded.first_seen_ns, folded.last_gone_ns) == (SECOND, 58 * SECOND)
    assert [(r.rule, r.applied, r.not_as_asked) for r in folded.rules] == [("req*", 11_000, 3)]
    assert not [w for w in out.warnings if "no thread matched" in w], "the rule matched threads that were folded"
    gap = out.threads[0][1].history_not_kept
    assert gap is not None
    assert (gap.count, gap.from_ns, gap.to_ns, gap.kept_first, gap.kept_last) == (1_234, 2_100_000_000, 58 * SECOND, 16, 48)
    plain = outcome(_program(_spec(), (_thread(500, 0, "rtprog", FIFO80),)), T0, T0 + SECOND, False, degradation)
    assert plain.result.threads_folded is None and plain.threads[0][1].history_not_kept is None


def test_folded_threads_and_history_gaps_are_stored_read_back_and_absent_from_older_files(tmp_path):
    out = outcome(_churned(), T0, T0 + 60 * SECOND, False, degradation)
    cell = CellResult(
        id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[out.result], threads=[out.threads[0][1]]
    )
    doc = RunDocument(
        scenario={"name": "s"}, started_at="t", cell_ids=["c"], matrix_cells=["c"], plan={"repeat": 1, "settle_ns": 0}, cells=[cell]
    )
    doc.save(str(tmp_path / "results.json"))
    data = json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))
    jsonschema.validate(data, results_schema())
    again = load(str(tmp_path)).cells[0]
    assert again.programs[0].threads_folded == out.result.threads_folded
    assert again.threads[0].history_not_kept == out.threads[0][1].history_not_kept
    del data["cells"][0]["programs"][0]["threads_folded"]
    del data["cells"][0]["threads"][0]["history_not_kept"]
    (tmp_path / "results.json").write_text(json.dumps(data), encoding="utf-8")
    older = load(str(tmp_path)).cells[0]
    assert older.programs[0].threads_folded is None and older.threads[0].history_not_kept is None


def test_the_report_says_how_many_threads_were_folded_and_which_history_changes_were_not_kept():
    out = outcome(_churned(), T0, T0 + 60 * SECOND, False, degradation)
    cell = CellResult(
        id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[out.result], threads=[out.threads[0][1]]
    )
    line = program_lines(cell)[0]
    assert (
        "; 12,000 threads that exited once it had 4,096 thread records were counted together, not kept one by one (between 1.00 s "
        "and 58.00 s; the 11,990 measured: 1,200 involuntary and 36,000 voluntary switches, 48,000 minor and 2 major faults, "
        "9.00 s of CPU time, 600 migrations); rule `req*` was applied to 11,000 of them, 3 not as asked" in line
    )
    assert line.endswith(
        "; talker/rtprog (main): its settings history keeps its first 16 and last 48 snapshots; 1,234 further changes between "
        "2.10 s and 58.00 s not kept"
    )
    plain = outcome(_program(_spec(), (_thread(500, 0, "rtprog", FIFO80),)), T0, T0 + SECOND, False, degradation)
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[plain.result])
    assert "not kept" not in program_lines(cell)[0] and "counted together" not in program_lines(cell)[0]


def test_the_report_names_a_few_threads_whose_history_left_changes_out_and_counts_the_others():
    threads = tuple(_thread(500 + i, i, "rtprog" if i == 0 else "worker", FIFO80, history_gap=BOOSTED) for i in range(5))
    out = outcome(_program(_spec(), threads), T0, T0 + 60 * SECOND, False, degradation)
    kept = [t for _, t in out.threads]
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[out.result], threads=kept)
    line = program_lines(cell)[0]
    named = re.findall(r"talker/\S+ (?:\(main\)|`#\d`)", line)  # `#1` in code: GitHub would make it a link to issue 1
    assert named == ["talker/rtprog (main)", "talker/worker `#1`", "talker/worker `#2`"]
    assert line.endswith("; 2 more threads' histories the same way: 2,468 further changes not kept")


def test_folded_threads_none_of_which_was_measured_claim_no_figures():
    nothing = Counters(0, 0, 0, 0, 0, 0, -1)
    unread = FoldedThreads(cap=4096, count=7, measured=0, counters=nothing, first_seen_ns=T0 - SECOND, last_gone_ns=T0)
    out = outcome(_program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), folded=unread), T0, T0 + SECOND, False, degradation)
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[out.result])
    line = program_lines(cell)[0]
    assert "; 7 threads that exited once it had 4,096 thread records were counted together, not kept one by one" in line
    assert "(between -1.00 s and 0.00 s; none of them was read in the measured window)" in line and "switches" not in line


def test_a_watched_process_that_exited_is_over_even_when_its_pid_lives_on_in_another(monkeypatch, tmp_path):
    """`runner watch` holds a pidfd: once the process exits, a newcomer given its PID is not followed as the program."""
    import subprocess
    import sys

    from runner.run import external, kernel

    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE, cwd=tmp_path)
    run = external.ProgramRun(_spec(), str(tmp_path), OTHER, (0, 1))
    run.attach(child.pid)
    assert not run.poll(), "alive: followed"
    monkeypatch.setattr(kernel, "process_alive", lambda pid: True)  # /proc finds a process there, whoever it is
    assert child.stdin is not None
    child.stdin.close()
    child.wait(timeout=10)
    assert run.poll() and run.exited_ns is not None, "its own exit, not a PID that lives on"


def test_output_limit_is_64mib_by_default_a_size_with_a_unit_and_never_unlimited():
    assert _spec().output_limit == 64 << 20 and _spec(output_limit="1MiB").output_limit == 1 << 20
    assert _spec(output_limit="0B").output_limit == 0
    assert _spec(output_limit="1MiB").dump()["output_limit"] == "1MiB"
    for wrong, words in ((None, "expected a size"), (1000, "bare number 1000 has no unit"), ("-1MiB", "cannot read")):
        with pytest.raises(ValueError, match=words):
            _spec(output_limit=wrong)


def test_output_beyond_the_limit_is_counted_in_the_results_and_said_in_a_warning():
    gib = 1 << 30
    counts = (OutputCount(gib + (gib // 5), 64 << 20, 64 << 20), OutputCount(4096, 4096, 64 << 20))
    raw = _program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), output=counts)
    out = outcome(raw, T0, T0 + SECOND, False, degradation)
    assert out.warnings == [
        "program talker wrote 1.2GiB to stdout; the first 64MiB are in talker.stdout, the rest (1.1GiB) was dropped (output_limit: 64MiB)"
    ]
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[out.result])
    assert "; output: `talker.stdout` (the first 64 MiB of 1.2 GiB), `talker.stderr`" in program_lines(cell)[0]
    r = out.result
    assert (r.output_limit, r.stdout_bytes, r.stdout_dropped, r.stderr_bytes, r.stderr_dropped) == (
        64 << 20,
        gib + gib // 5,
        gib + gib // 5 - (64 << 20),
        4096,
        0,
    )


def test_output_the_disk_refused_none_kept_and_a_stream_held_past_the_end_are_said_too():
    counts = (OutputCount(5000, 0, 0, held_open=True), OutputCount(3 << 20, 1 << 20, 64 << 20, error="the disk is full"))
    out = outcome(_program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), output=counts), T0, T0 + SECOND, False, degradation)
    assert out.warnings == [
        "program talker wrote 4.9KiB to stdout; none of it was kept (output_limit: 0B)",
        "program talker: a process it started still held its stdout at the cell's end (it had no cgroup to stop it with); "
        "what that process wrote after was neither kept nor counted",
        "program talker wrote 3MiB to stderr; talker.stderr took only the first 1MiB (the disk is full), the rest was dropped",
    ]


def test_output_counts_are_stored_read_back_and_null_in_older_files_and_for_a_watched_process(tmp_path):
    counts = (OutputCount(3 << 20, 1 << 20, 1 << 20), OutputCount(10, 10, 1 << 20))
    out = outcome(_program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), output=counts), T0, T0 + SECOND, False, degradation)
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="", duration_ns=SECOND, programs=[out.result])
    doc = RunDocument(
        scenario={"name": "s"}, started_at="t", cell_ids=["c"], matrix_cells=["c"], plan={"repeat": 1, "settle_ns": 0}, cells=[cell]
    )
    doc.save(str(tmp_path / "results.json"))
    data = json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))
    jsonschema.validate(data, results_schema())
    again = load(str(tmp_path)).cells[0].programs[0]
    assert (again.output_limit, again.stdout_bytes, again.stdout_dropped, again.stderr_bytes, again.stderr_dropped) == (
        1 << 20,
        3 << 20,
        2 << 20,
        10,
        0,
    )
    for key in ("output_limit", "stdout_bytes", "stdout_dropped", "stderr_bytes", "stderr_dropped"):
        del data["cells"][0]["programs"][0][key]
    (tmp_path / "results.json").write_text(json.dumps(data), encoding="utf-8")
    older = load(str(tmp_path)).cells[0].programs[0]
    assert (older.output_limit, older.stdout_bytes, older.stdout_dropped, older.stderr_bytes, older.stderr_dropped) == (None,) * 5
    watched = outcome(_program(_spec(), (_thread(500, 0, "rtprog", FIFO80),), attached=True), T0, T0 + SECOND, False, degradation)
    assert watched.result.stdout_bytes is None and watched.result.output_limit is None


def test_a_watched_process_held_by_a_descriptor_past_1023_is_followed_to_its_exit(tmp_path):
    """select() refuses descriptors from 1024 up; a runner of a large cell (or a raised RLIMIT_NOFILE) may hold one."""
    import resource
    import subprocess
    import sys

    from runner.run import external

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 1600:
        pytest.skip(f"RLIMIT_NOFILE's hard limit is {hard}: no descriptor past 1023 here")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, 1600), hard))
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE, cwd=tmp_path)
    try:
        run = external.ProgramRun(_spec(), str(tmp_path), OTHER, (0, 1))
        run.attach(child.pid)
        high = os.dup2(run._pidfd, 1500)
        os.close(run._pidfd)
        run._pidfd = high
        assert not run.poll(), "alive: followed"
        assert child.stdin is not None
        child.stdin.close()
        child.wait(timeout=10)
        assert run.poll(), "its exit seen through the high descriptor"
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
