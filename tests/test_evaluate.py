"""The pure evaluation core: raw records in, figures, degradations, verdicts and status out (no processes)."""

from __future__ import annotations

import dataclasses
import os

from runner.results.document import Status
from runner.run.evaluate import degradation, evaluate, releases_due, status
from runner.run.rawcell import ApplyErrors, BackgroundProcess, OutputCount, RawCell, RawThread, ReadyReport, Timeline
from runner.run.samples import Sample, slot_of
from runner.scenario.loader import load_scenario
from runner.scenario.model import Expectation, PeriodicWork, Policy
from runner.scenario.plan import Settings, plan_scenario

SCENARIOS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenarios")
FIFO80 = Settings(Policy.FIFO, 80, 0, None)
OTHER = Settings(Policy.OTHER, 0, 0, None)


def test_releases_due_run_from_the_gate_to_the_end_or_the_interrupt():
    work = PeriodicWork.parse({"period": "100ms"})
    timeline = Timeline(0, start_ns=1_000, end_ns=1_000 + 1_000_000_000, stopped_ns=1_000 + 250_000_000)
    assert releases_due(work, timeline, interrupted=False) == 10
    assert releases_due(work, timeline, interrupted=True) == 3  # releases at 0, 100 and 200 ms
    assert releases_due(work, Timeline(0), interrupted=False) == 0  # the gate never opened


def test_degradation_names_each_shortfall_with_the_kernels_reason():
    assert degradation(FIFO80, FIFO80, ApplyErrors()) == []
    words = degradation(FIFO80, OTHER, ApplyErrors(sched=1, other=12))
    assert words == [
        "policy fifo:80 requested, other applied (Operation not permitted)",
        "a per-callback allocation failed (Cannot allocate memory)",
    ]
    assert degradation(FIFO80, None, ApplyErrors()) == ["the thread was gone before its settings could be read back"]


def test_a_ready_report_is_checked_and_gives_each_slot_its_errors():
    report = ReadyReport.parse(
        {
            "pid": 7,
            "tids": [7, 8],
            "errors": {"main": {"sched": 1, "nice": 0, "cpus": 0}, "threads": [[0, 0, 0, 0], [0, 13, 0, 12]], "memory": {"errno": 12}},
        },
        2,
    )
    assert report.errors(0) == ApplyErrors(sched=1, memory=12)
    assert report.errors(1) == ApplyErrors(nice=13, memory=12, other=12)
    for broken in ({"tids": [1, 2]}, {"pid": 1, "tids": [1]}, {"pid": "x", "tids": [1, 2]}):
        try:
            ReadyReport.parse(broken, 2)
        except ValueError:
            continue
        raise AssertionError(f"{broken} should be refused")


def _raw(callbacks: int, interrupted: bool = False, failures: tuple[str, ...] = (), applied: Settings = FIFO80):
    loaded = load_scenario(os.path.join(SCENARIOS, "fifo80.yaml"))
    cell = loaded.cells[0]
    planned = plan_scenario(cell.scenario, OTHER)
    t0, period = 1_000_000_000, 100_000_000
    threads = []
    for p in planned:
        samples = (
            tuple(
                Sample(
                    t0 + k * period,
                    t0 + k * period + 20_000,
                    t0 + k * period + 40_000_000,
                    40_000_000,
                    k,
                    0,
                    1,
                    0,
                    0,
                    0,
                    0,
                    0,
                    period_ns=period,
                    next_ns=t0 + (k + 1) * period,
                )
                for k in range(callbacks)
            )
            if p.index == 0
            else ()
        )
        slot = slot_of(list(samples), tid=100 + p.index, cpus_seen=(0,), work_start_ns=t0)
        threads.append(RawThread(p, 99, slot, applied if p.index == 0 else p.settings, ApplyErrors(), True))
    timeline = Timeline(0, t0, t0 + 10 * period, t0 + 10 * period, t0 + 11 * period)
    return cell, RawCell("now", tuple(threads), 1, timeline, failures=failures, interrupted=interrupted)


def test_a_cell_that_kept_up_passes():
    cell, raw = _raw(10)
    result = evaluate(cell, cell.scenario, raw, allow_degraded=False)
    main = result.threads[0]
    assert result.status is Status.PASSED and result.reason == "" and result.warnings == []
    assert main.figures.callbacks == 10 and main.figures.missed_releases == 0
    assert [v.passed for v in result.expectations] == [True]
    assert main.key == "minimal_schedul[0]/minimal_schedul (main)" and main.histograms is not None


def test_a_late_release_or_a_hog_whose_load_began_late_is_said_in_words_without_failing_the_cell():
    cell, raw = _raw(10)
    late = dataclasses.replace(raw, released_late=(("process app[0]", 2_500_000),), load_late=(("hog busy[1]", 400_000),))
    result = evaluate(cell, cell.scenario, late, allow_degraded=False)
    assert result.status is Status.PASSED
    assert any(w.startswith("process app[0] was released 2.50 ms after the common start") for w in result.warnings), result.warnings
    assert any(
        w.startswith("background hog busy[1] began its load 400 µs after the common start") and "ran without it" in w
        for w in result.warnings
    ), result.warnings


def test_a_background_commands_log_beyond_its_limit_is_counted_and_said_in_words():
    cell, raw = _raw(10)
    mib = 1024 * 1024
    chatty = BackgroundProcess("command", "loadgen", 4242, ("loadgen", "-v"), "command-0.log", OutputCount(200 * mib, 64 * mib, 64 * mib))
    quiet = BackgroundProcess("command", "stress-ng", 4243, ("stress-ng",), "command-1.log", OutputCount(300, 300, 64 * mib))
    result = evaluate(cell, cell.scenario, dataclasses.replace(raw, background=(chatty, quiet)), allow_degraded=False)
    assert result.status is Status.PASSED
    said = [w for w in result.warnings if w.startswith("background command")]
    assert said == [
        "background command loadgen wrote 200MiB to its log; the first 64MiB are in command-0.log, the rest (136MiB) was "
        "dropped (the limit of a command's log: 64MiB)"
    ], result.warnings
    assert [(b.log, b.output_bytes, b.output_dropped) for b in result.background] == [
        ("command-0.log", 200 * mib, 136 * mib),
        ("command-1.log", 300, 0),
    ]


def test_a_background_commands_name_is_kept_in_the_results_and_the_report():
    """A command's `name:` was dropped from results.json and the report (issue 40, 15)."""
    from runner.report.markdown import _load_line

    cell, raw = _raw(10)
    named = BackgroundProcess("command", "disk load", 4242, ("fio", "job.fio"), "command-0.log", OutputCount(0, 0, 1024))
    plain = BackgroundProcess("command", "stress-ng", 4243, ("stress-ng", "--cpu", "2"), "command-1.log", OutputCount(0, 0, 1024))
    result = evaluate(cell, cell.scenario, dataclasses.replace(raw, background=(named, plain)), allow_degraded=False)
    assert [b.name for b in result.background] == ["disk load", "stress-ng"]
    assert str(_load_line(result)) == "disk load (`fio job.fio`), `stress-ng --cpu 2`"


def test_failures_interrupts_and_degradations_decide_the_status_in_order():
    cell, raw = _raw(10, failures=("process x (pid 1) was killed by SIGKILL",))
    result = evaluate(cell, cell.scenario, raw, False)
    assert result.status is Status.ERROR and "killed by SIGKILL" in result.reason
    cell, raw = _raw(4, interrupted=True, failures=("ignored once interrupted",))
    result = evaluate(cell, cell.scenario, raw, False)
    assert result.status is Status.INTERRUPTED and result.reason.startswith("interrupted")
    cell, raw = _raw(10, applied=OTHER)
    assert evaluate(cell, cell.scenario, raw, False).status is Status.ERROR
    assert evaluate(cell, cell.scenario, raw, True).status is Status.DEGRADED
    assert status(evaluate(cell, cell.scenario, raw, True), raw, True)[0] is Status.DEGRADED


def test_missed_releases_count_every_release_no_callback_served():
    cell, raw = _raw(3)
    main = evaluate(cell, cell.scenario, raw, False).threads[0]
    assert main.figures.callbacks == 3 and main.figures.missed_releases == 7


def test_a_thread_that_could_not_keep_up_fails_its_cell_by_an_implicit_verdict():
    cell, raw = _raw(3)  # 3 callbacks for 10 releases; fifo80's expectation does not look at misses
    result = evaluate(cell, cell.scenario, raw, False)
    assert result.status is Status.FAILED
    implicit = [v for v in result.expectations if v.line is None]
    assert [(v.thread, v.metric, v.limit, v.measured, v.passed) for v in implicit] == [
        ("minimal_schedul/minimal_schedul (main)", "missed_releases", "<= 0", 7, False)
    ]
    assert "could not keep up: missed 7 of 10 releases" in implicit[0].note
    assert result.warnings == []  # said once, by the verdict


def test_a_scenarios_own_bound_on_misses_replaces_the_implicit_verdict_and_the_words_stay():
    cell, raw = _raw(3)
    own = Expectation.parse({"thread": "minimal_schedul", "metric": "missed_releases", "max": 7})
    scenario = cell.scenario.replace(expect=[*cell.scenario.expect, own])
    result = evaluate(cell, scenario, raw, False)
    assert result.status is Status.PASSED
    assert [(v.measured, v.passed) for v in result.expectations if v.metric == "missed_releases"] == [(7, True)]
    assert len(result.warnings) == 1 and "could not keep up: missed 7 of 10 releases" in result.warnings[0]
    strict = scenario.replace(expect=[*cell.scenario.expect, own.replace(max=6.0)])
    assert evaluate(cell, strict, raw, False).status is Status.FAILED


def test_a_thread_with_callbacks_that_ran_none_fails_its_cell_unless_the_scenario_bounds_them():
    """A periodic phases thread starved before its timer phase (no release, so none missed) once passed."""
    from runner.scenario.model import PhasesWork

    cell, raw = _raw(10)
    main = raw.threads[0]
    work = PhasesWork.parse(
        {"kind": "phases", "phases": [{"name": "init", "loop": 1, "events": [{"run": "5s"}]}, {"events": [{"timer": {"period": "10ms"}}]}]}
    )
    starved = RawThread(dataclasses.replace(main.planned, work=work), 99, slot_of([], tid=100), FIFO80, ApplyErrors(), True)
    held = RawCell("now", (starved, *raw.threads[1:]), 1, raw.timeline)
    result = evaluate(cell, cell.scenario, held, False)
    implicit = [(v.metric, v.limit, v.measured, v.passed) for v in result.expectations if v.line is None]
    assert result.status is Status.FAILED and implicit == [("callbacks", ">= 1", 0, False)]
    own = Expectation.parse({"thread": "minimal_schedul", "metric": "callbacks", "min": 0})
    scenario = cell.scenario.replace(expect=[own])
    assert [v for v in evaluate(cell, scenario, held, False).expectations if v.line is None] == []
    # A timer it reached whose first release was past the end had none due: running none was right.
    assert raw.timeline.end_ns is not None
    late = dataclasses.replace(starved, slot=dataclasses.replace(starved.slot, timer_due_ns=raw.timeline.end_ns + 1))
    quiet = evaluate(cell, cell.scenario, RawCell("now", (late, *raw.threads[1:]), 1, raw.timeline), False)
    assert [v for v in quiet.expectations if v.line is None] == []


def test_a_deadline_thread_whose_callbacks_outlast_its_runtime_is_said_to_be_throttled():
    from runner.results.threadfigures import ThreadFigures
    from runner.run.evaluate import throttled

    def figures(wall_max: int) -> ThreadFigures:
        quantiles = dict.fromkeys(("p50", "p90", "p99", "p999", "max"), wall_max)
        counts = {"callbacks": 50, "missed_releases": 49, "involuntary": {"total": 0}, "voluntary": {"total": 0}}
        return ThreadFigures.model_validate(
            {**counts, "faults": {"minor": 0, "major": 0}, "complete": True, "callback_wall_ns": {"min": 1, **quantiles}}
        )

    dl = Settings(Policy.DEADLINE, 0, 0, None, 2_000_000, 10_000_000, 10_000_000)
    words = throttled(dl, figures(12_140_000))
    assert "2.00 ms of runtime every 10.00 ms and its callbacks took up to 12.14 ms" in words and "stops it" in words
    assert throttled(dl, figures(1_900_000)) == "" and throttled(FIFO80, figures(12_140_000)) == ""


def test_a_stage_that_missed_resumes_left_in_its_queue_is_failed_by_a_verdict_that_names_the_queue():
    """browser-short's BrowserMain "missed 13 of 14 releases" and the verdict did not say where (issue 40, 13): the resumes
    its queue still held at the end, beyond one burst of them, are named with the queue."""
    from runner.run.rawcell import ResourceState
    from runner.run.samples import EventStats
    from runner.scenario.model import Scenario

    sc = Scenario.parse(
        {
            "name": "chain",
            "resources": {"frames": {"kind": "queue"}},
            "processes": [
                {
                    "name": "app",
                    "threads": [
                        {"name": "producer", "work": {"kind": "phases", "events": [{"timer": {"period": "10ms"}}, {"resume": "frames"}]}},
                        {"name": "stage", "work": {"kind": "phases", "events": [{"suspend": "frames"}, {"run": "12ms"}]}},
                    ],
                }
            ],
        }
    )
    cell = dataclasses.replace(load_scenario(os.path.join(SCENARIOS, "fifo80.yaml")).cells[0], scenario=sc)
    t0 = 1_000_000_000
    threads = []
    for p in plan_scenario(sc, OTHER):
        n = {"producer": 100, "stage": 83}.get(p.name, 0)
        samples = [
            Sample(t0 + k * 12_000_000, t0 + k * 12_000_000, t0 + k * 12_000_000 + 100, 100, k, 0, 1, 0, 0, 0, 0, 0) for k in range(n)
        ]
        slot = dataclasses.replace(slot_of(samples, tid=100 + p.index, work_start_ns=t0), events=(EventStats(count=n), EventStats(count=n)))
        threads.append(RawThread(p, 99, slot, p.settings, ApplyErrors(), True))
    timeline = Timeline(0, t0, t0 + 1_000_000_000, t0 + 1_000_000_000, t0 + 1_100_000_000)
    raw = RawCell("now", tuple(threads), 1, timeline, resources=(ResourceState("frames", "queue", queued=17),))
    result = evaluate(cell, sc, raw, allow_degraded=False)
    (verdict,) = [v for v in result.expectations if not v.passed and "stage" in v.thread]
    assert verdict.measured == 16 and verdict.note.startswith(
        "could not keep up: missed 16 of 99 releases: 16 resumes of queue frames were still waiting at the end beyond one burst "
        "of its resumes; implicit"
    ), verdict.note


def test_a_run_takes_no_text_from_the_list_renderer():
    """Results say a thread's work in the scenario stage's words (worktext.py), not through `runner FILE --list`'s renderer."""
    import subprocess
    import sys

    code = "import sys, runner.session, runner.run.evaluate; print('runner.scenario.listing' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd="/")
    assert done.stdout.split() == ["False"]


def test_a_bound_on_releases_missed_in_a_row_validates_in_a_scenario_file_and_the_run_judges_it(tmp_path):
    with open(os.path.join(SCENARIOS, "fifo80.yaml")) as handle:
        text = handle.read() + "  - {thread: minimal_schedul, metric: missed_releases.consecutive_max, max: 1}\n"
    (tmp_path / "s.yaml").write_text(text)
    scenario = load_scenario(str(tmp_path / "s.yaml")).cells[0].scenario
    verdicts = {}
    for callbacks in (10, 3):  # every release served; 3 served, then 7 missed in a row to the end of the cell
        cell, raw = _raw(callbacks)
        result = evaluate(cell, scenario, raw, False)
        verdicts[callbacks] = [(v.measured, v.passed) for v in result.expectations if v.metric == "missed_releases.consecutive_max"]
    assert verdicts == {10: [(0, True)], 3: [(7, False)]}
