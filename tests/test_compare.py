"""`runner compare` and --baseline: thresholds, alignment by cell id, refusals, exit codes."""

from __future__ import annotations

import copy
import json
import os

import pytest
from conftest import run_cli
from reportdata import MATRIX, heavy_tail, latencies, main_thread, matrix, with_figures, with_latencies

from runner.errors import ScenarioError, UsageError
from runner.report import compare as cmp
from runner.results.document import Status
from runner.results.read import load


def save(doc, folder) -> str:
    folder.mkdir(parents=True, exist_ok=True)
    path = str(folder / "results.json")
    doc.save(path)
    return path


def test_identical_runs_pass(tmp_path):
    done = run_cli("compare", MATRIX, MATRIX)
    assert done.code == 0, done.err
    assert "No regression in 5 cells" in done.out


def test_synthetic_latency_regression_is_flagged_with_exit_1(tmp_path):
    fifo = "policy=fifo,priority=80"
    base = with_latencies(matrix(), fifo, latencies(2_000, seed=1))
    new = with_latencies(base, fifo, heavy_tail(latencies(2_000, seed=2)))
    done = run_cli("compare", save(base, tmp_path / "base"), save(new, tmp_path / "new"))
    assert done.code == 1, done.out
    assert "1 regression** in 1 of 5 cells: policy=fifo,priority=80" in done.out
    regressions = done.out.split("### Regressions")[1].split("###")[0]
    assert "policy=fifo,priority=80" in regressions and "wake-up latency p99" in regressions
    assert "beyond its sampling error: p = " in regressions, regressions


def test_a_p99_of_ten_callbacks_is_not_judged_and_says_what_it_needs(tmp_path):
    """The recorded runs have 10 callbacks a cell: their p99 is their max, no figure to gate on, however much it moved."""
    base = matrix()
    p99 = main_thread(base.cells[1]).figures.latency_ns.p99
    new = save(with_figures(base, "policy=fifo,priority=80", latency_p99=round(p99 * 1.5) + 20_000), tmp_path / "new")
    junit = tmp_path / "c.xml"
    done = run_cli("compare", MATRIX, new, "--junit", str(junit))
    assert done.code == 0, done.out
    row = next(line for line in done.out.splitlines() if "policy=fifo,priority=80" in line and "latency p99" in line)
    assert "not judged" in row and "10 callbacks; p99 needs at least 368, run ≥ 49s" in row, row
    assert "p99 needs at least 368" in junit.read_text()
    assert "<skipped" in junit.read_text()


def test_involuntary_regression_and_its_threshold_override(tmp_path):
    new = save(with_figures(matrix(), "policy=rr,priority=80", invol_mean=1.0), tmp_path / "new")
    assert run_cli("compare", MATRIX, new).code == 1
    assert run_cli("compare", MATRIX, new, "--threshold", "involuntary.per_callback_mean=+2").code == 0
    assert run_cli("compare", MATRIX, new, "--threshold", "involuntary.per_callback_mean=off").code == 0


def test_a_figure_the_baseline_never_recorded_is_no_baseline_not_a_regression():
    """The first schema kept no overruns: a run's first overrun against it is new, not a change from an invented 0."""
    base = matrix()  # the recorded policy_matrix run, a file of the first schema
    assert main_thread(base.cells[-1]).figures.overruns is None
    result = cmp.compare(base, with_figures(base, base.cells[-1].id, overruns=1))
    assert result.regressions == 0
    rows = [f for f in result.figures if f.figure.name == "overruns"]
    assert [f.verdict for f in rows] == [cmp.Verdict.NEW], rows


def test_a_figure_whose_threshold_is_off_is_not_checked_not_within_threshold(tmp_path):
    base = matrix()
    p99 = main_thread(base.cells[1]).figures.latency_ns.p99
    new = save(with_figures(base, "policy=fifo,priority=80", latency_p99=p99 * 500), tmp_path / "new")
    junit = tmp_path / "c.xml"
    done = run_cli("compare", MATRIX, new, "--threshold", "latency.p99=off", "--junit", str(junit))
    assert done.code == 0, done.err
    row = next(line for line in done.out.splitlines() if "policy=fifo,priority=80" in line and "latency p99" in line)
    assert "not checked (threshold off)" in row and "within threshold" not in row, row
    assert "not checked (its threshold is off)" in junit.read_text()


def test_small_latency_wobble_is_under_the_noise_floor():
    cell = "policy=fifo,priority=10"
    values = latencies(2_000, seed=3)
    base = with_latencies(matrix(), cell, values)
    p99 = main_thread(base.cells[0]).figures.latency_ns.p99
    shifted = with_latencies(base, cell, [v + 9_000 for v in values])  # > 20% only if p99 < 45 us
    assert cmp.compare(base, shifted).regressions == 0
    assert cmp.compare(base, with_latencies(base, cell, [v + 11_000 + p99 // 5 for v in values])).regressions == 1


def test_a_change_past_its_threshold_that_sampling_explains_is_within_noise():
    """0 switches in 10 callbacks, then 6: past +0.5 per callback, but a Poisson count of 6 against 0 is p = 0.016,
    and the comparison tests every figure at once: Holm's adjustment leaves it within noise, not a regression."""
    base = matrix()
    new = with_figures(base, "policy=rr,priority=80", invol_mean=0.6)
    result = cmp.compare(base, new)
    row = next(f for f in result.figures if f.cell == "policy=rr,priority=80" and f.figure.name == "involuntary.per_callback_mean")
    assert row.verdict == cmp.Verdict.NOISE, row
    assert "sampling explains it: p = " in row.why and "(Holm, " in row.why, row.why
    assert result.regressions == 0
    assert cmp.compare(base, with_figures(base, "policy=rr,priority=80", invol_mean=3.0)).regressions == 1


def test_improvement_is_reported_as_better_not_regression():
    base = matrix()
    other = base.cells[-1]
    result = cmp.compare(base, with_figures(base, other.id, invol_mean=0.0))
    verdicts = {(f.cell, f.figure.name): f.verdict for f in result.figures}
    assert verdicts[(other.id, "involuntary.per_callback_mean")] == cmp.Verdict.BETTER
    assert result.regressions == 0


def test_a_cell_with_several_regressed_figures_is_named_once():
    """The headline once said '6 regressions in 6 of 5 cells', naming a cell once per figure."""
    cell = matrix().cells[0]
    base = with_latencies(matrix(), cell.id, latencies(2_000, seed=4))
    worse = with_figures(with_latencies(base, cell.id, heavy_tail(latencies(2_000, seed=5))), cell.id, invol_mean=9.0)
    result = cmp.compare(base, worse)
    assert result.regressions >= 2 and result.regressed_cells() == [cell.id]


def test_a_programs_threads_are_compared_by_what_is_measured_of_them():
    """A program's threads have no callbacks: they were left out, so its switches per second could never regress."""

    def as_program(doc, per_second: float):
        out = copy.deepcopy(doc)
        for cell in out.cells:
            t = main_thread(cell)
            i = cell.threads.index(t)
            invol = t.figures.involuntary.model_copy(update={"per_second": per_second})
            figures = t.figures.model_copy(update={"involuntary": invol, "latency_ns": None, "callbacks": 0})
            cell.threads[i] = t.model_copy(update={"periodic": False, "released": False, "program": True, "figures": figures})
        return out

    base = as_program(matrix(), 40.0)
    result = cmp.compare(base, as_program(matrix(), 72.0))
    changed = [(f.figure.name, f.verdict) for f in result.figures if f.cell == base.cells[0].id]
    assert ("involuntary.per_second", cmp.Verdict.REGRESSION) in changed
    assert cmp.compare(base, as_program(matrix(), 41.0)).regressions == 0


def test_a_cell_that_now_fails_is_a_regression():
    base = matrix()
    new = copy.deepcopy(base)
    new.cells[2].status = Status.FAILED
    result = cmp.compare(base, new)
    assert result.regressed_cells() == [base.cells[2].id] and result.regressions == 1


def test_a_cell_that_errs_in_both_runs_is_a_run_error_not_within_threshold(tmp_path):
    """`error → error ✅ within threshold`, a ✅ headline and exit 0: the new run's own errors were never looked at."""
    runs = []
    for name in ("base", "new"):
        doc = copy.deepcopy(matrix())
        doc.cells[1].status, doc.cells[1].reason, doc.status = Status.ERROR, "worker killed", "error"
        runs.append(save(doc, tmp_path / name))
    junit = tmp_path / "c.xml"
    done = run_cli("compare", *runs, "--junit", str(junit))
    assert done.code == 4, done.err
    headline = done.out.split("\n\n")[1]
    assert headline.startswith("💥 **1 cell of this run could not run or was cut short**: policy=fifo,priority=80 (error).")
    assert "✅" not in headline
    row = next(line for line in done.out.splitlines() if line.startswith("| policy=fifo,priority=80") and "error" in line)
    assert "💥 run error (error → error)" in row and "within threshold" not in row
    assert 'message="the cell could not run or was cut short: error → error"' in junit.read_text()
    result = cmp.compare(load(runs[0]), load(runs[1]))
    assert [c.verdict for c in result.cells if c.cell == "policy=fifo,priority=80"] == [cmp.Verdict.ERROR]
    assert result.statuses() == [Status.ERROR] and result.regressions == 0


def test_a_cell_cut_short_now_is_a_run_error_not_a_regression_and_the_comparison_exits_130(tmp_path):
    """`💥 1 cell ... cut short ... ❌ 1 regression in 1 of 5 cells` though every figure was within its threshold:
    a cell cut short is a run error (exit 130, or 4), its own outcome; regressions are what got worse."""
    from runner.session import exit_code

    base = matrix()
    new = copy.deepcopy(base)
    new.cells[2].status = Status.INTERRUPTED
    result = cmp.compare(base, new)
    assert result.regressed_cells() == [] and result.regressions == 0  # passed, now cut short, figures equal
    assert [c.verdict for c in result.cells if c.cell == base.cells[2].id] == [cmp.Verdict.ERROR]
    assert result.statuses() == [Status.INTERRUPTED] and exit_code(result.statuses(), result.regressions) == 130
    new.status = "interrupted"  # as the run would have written it
    done = run_cli("compare", MATRIX, save(new, tmp_path / "new"))
    headline = done.out.split("\n\n")[1]
    assert done.code == 130 and "regression**" not in headline and "✅" not in headline, headline
    assert "No regression in 5 cells" in headline, headline


def test_missing_and_new_cells_are_reported_not_failed():
    base = matrix()
    new = copy.deepcopy(base)
    new.cells = new.cells[1:]
    result = cmp.compare(base, new)
    assert result.regressions == 0
    assert [c.verdict for c in result.cells if c.cell == base.cells[0].id] == [cmp.Verdict.MISSING]
    assert [c.verdict for c in cmp.compare(new, base).cells if c.cell == base.cells[0].id] == [cmp.Verdict.NEW]


def test_repeats_are_compared_by_their_median():
    base = matrix()
    new = copy.deepcopy(base)
    spiky = with_figures(base, base.cells[0].id, latency_p99=50_000_000).cells[0]  # 50 ms
    again = copy.deepcopy(base.cells[0])
    for c, r in ((new.cells[0], 0), (spiky, 1), (again, 2)):
        c.repeat = r
    new.cells += [spiky, again]
    assert cmp.compare(base, new).regressions == 0  # one spike in three repeats is not a regression


def test_cells_whose_scenario_differs_are_refused_naming_the_setting(tmp_path):
    new = matrix()
    cell = new.cells[1]
    cell.spec["processes"][0]["main"]["sched"]["priority"] = 70
    cell.spec_hash = "0000000000000000"
    path = save(new, tmp_path / "new")
    done = run_cli("compare", MATRIX, path)
    assert done.code == 2
    assert "cells.policy=fifo,priority=80: differs from the baseline" in done.err
    assert "processes[0].main.sched.priority: 80 in the baseline, 70 now" in done.err
    assert "Traceback" not in done.err


def test_runs_of_another_length_are_refused_as_a_changed_duration_is(tmp_path):
    """--duration is not in a cell's spec: a 500 ms run once compared with a 1 s baseline as 'No regression'."""
    base = matrix()
    shorter = copy.deepcopy(base)
    shorter.plan.duration_ns = base.plan.duration_ns // 2 if base.plan.duration_ns else 500_000_000
    with pytest.raises(ScenarioError, match="ran for 1s in the baseline, 500ms now"):
        cmp.compare(base, shorter)
    done = run_cli("compare", MATRIX, save(shorter, tmp_path / "short"))
    assert done.code == 2 and "ran for" in done.err


def test_spec_differences_lists_every_changed_leaf():
    base = {"a": {"b": 1, "c": [1, 2]}, "d": "x"}
    new = {"a": {"b": 2, "c": [1, 3]}, "e": True}
    assert cmp.spec_differences(base, new) == [
        "a.b: 1 in the baseline, 2 now",
        "a.c[1]: 2 in the baseline, 3 now",
        "d: 'x' in the baseline, absent now",
        "e: absent in the baseline, True now",
    ]


@pytest.mark.parametrize(
    "text, relative, absolute",
    [
        ("latency.p99=+20%", 0.2, None),
        ("latency.p99=+20%,+10us", 0.2, 10_000),
        ("latency.max=+1ms", None, 1_000_000),
        ("involuntary.per_callback_mean=+0.5", None, 0.5),
        ("latency.p99=off", None, None),
    ],
)
def test_threshold_syntax(text, relative, absolute):
    t = cmp.parse_threshold(text)
    assert (t.relative, t.absolute) == (relative, absolute)


def test_fewer_callbacks_are_worse_more_are_not():
    """`--threshold callbacks=+0` once flagged 3 -> 4 callbacks and let a drop pass as better."""
    base = matrix()
    cell = base.cells[0]
    ran = main_thread(cell).figures.callbacks
    threshold = [cmp.parse_threshold("callbacks=+0")]
    assert cmp.compare(base, with_figures(base, cell.id, callbacks=ran - 1), threshold).regressions == 1
    assert cmp.compare(base, with_figures(base, cell.id, callbacks=ran + 1), threshold).regressions == 0


def test_one_more_release_missed_in_a_row_is_a_regression_by_default():
    """The default threshold of `missed_releases.consecutive_max` is +0: a control loop that lost two in a row where it lost one."""
    base = with_figures(matrix(), matrix().cells[0].id, missed_consecutive_max=1)
    cell = base.cells[0].id
    rows = {
        f.verdict
        for f in cmp.compare(base, with_figures(base, cell, missed_consecutive_max=2)).figures
        if f.figure.name == "missed_releases.consecutive_max" and f.cell == cell
    }
    assert rows == {cmp.Verdict.REGRESSION}
    same = cmp.compare(base, base)
    assert {f.verdict for f in same.figures if f.figure.name == "missed_releases.consecutive_max" and f.cell == cell} == {cmp.Verdict.SAME}
    assert cmp.compare(base, with_figures(base, cell, missed_consecutive_max=0)).regressions == 0


@pytest.mark.parametrize("text", ["involuntary.per_callback_mean=-1", "latency.p99=-5%", "missed_releases=+10%,-1"])
def test_a_negative_threshold_is_refused_not_read_as_every_run_regressing(text):
    with pytest.raises(UsageError, match="not less than 0"):
        cmp.parse_threshold(text)
    assert cmp.parse_threshold("slack.min=-10us").absolute == 10_000, "slack falls when it worsens: -10us and +10us say the same"


@pytest.mark.parametrize(
    "text, message",
    [
        ("latency.p9=+20%", "did you mean 'latency.p99'"),
        ("latency.p99", "expected FIGURE=LIMIT"),
        ("latency.p99=+10", "with a unit"),
        ("involuntary.per_callback_mean=lots", "is not a limit"),
    ],
)
def test_threshold_errors_say_what_is_expected(text, message):
    with pytest.raises(UsageError, match=message.replace("(", r"\(")):
        cmp.parse_threshold(text)


@pytest.mark.parametrize(
    "text, words",
    [
        ("latency.p99=+5%,+10us,+50%", "two relative limits, +5% and +50%; expected at most one +N% and one +N with a unit (+10us)"),
        ("latency.max=+1ms, +2ms", "two absolute limits, +1ms and +2ms; expected at most one +N% and one +N with a unit (+10us)"),
        ("involuntary.per_callback_mean=+0.5,+20%,1", "two absolute limits, +0.5 and 1; expected at most one +N% and one +N"),
    ],
)
def test_a_threshold_giving_one_kind_of_limit_twice_is_refused_not_the_last_one_kept(text, words):
    """`latency.p99=+5%,+10us,+50%` once kept +50% without a word: which limit was meant is the user's to say."""
    with pytest.raises(UsageError) as refused:
        cmp.parse_threshold(text)
    assert str(refused.value) == f"runner: --threshold {text!r}: {words}"


def test_compare_appends_to_the_github_step_summary(tmp_path, monkeypatch):
    summary = tmp_path / "summary.md"
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(summary))
    assert run_cli("compare", MATRIX, MATRIX).code == 0
    assert summary.read_text().startswith("## Comparison with the baseline")


def test_compare_refuses_a_results_file_of_another_schema(tmp_path):
    bad = tmp_path / "results.json"
    bad.write_text(json.dumps({"schema": "runner.results/0"}))
    done = run_cli("compare", MATRIX, str(bad))
    assert done.code == 2 and "expected a runner.results/2 (or runner.results/1) results file" in done.err


def test_refusal_is_a_scenario_error_with_every_cell():
    base = matrix()
    new = copy.deepcopy(base)
    for cell in new.cells[:2]:
        cell.spec_hash = "x"
        cell.spec = {**cell.spec, "duration": 1}
    with pytest.raises(ScenarioError) as err:
        cmp.compare(base, new)
    assert len(err.value.problems) == 2


def test_comparison_section_matches_golden_file():
    from test_report import golden

    from runner.report.markdown import render_comparison

    fifo = "policy=fifo,priority=80"
    base = with_latencies(matrix(), fifo, latencies(2_000, seed=1))
    new = with_latencies(base, fifo, heavy_tail(latencies(2_000, seed=2)))
    new = with_figures(with_figures(new, "policy=other,priority=0", invol_mean=4.0), "policy=rr,priority=80", invol_mean=0.6)
    text = render_comparison(cmp.compare(base, new), "base/results.json", "new/results.json")
    golden("comparison.md", text)
    # it once promised "a false regression at most 5% of the time", which 6 of 19 identical nights disproved
    assert "if each callback were an independent sample of one unchanged host" in text and "judge against a history (--history)" in text


def test_runs_with_no_cell_in_common_are_refused_naming_both_files(tmp_path):
    other = copy.deepcopy(matrix())
    for cell in other.cells:
        cell.id = "x=" + cell.id
    other.cell_ids = [c.id for c in other.cells]
    path = save(other, tmp_path / "other")
    done = run_cli("compare", MATRIX, path)
    assert done.code == 2, done.out
    assert "no cell in common with the baseline" in done.err and MATRIX in done.err and path in done.err
    assert "No regression" not in done.out
    empty = copy.deepcopy(matrix())
    empty.cells, empty.cell_ids = [], []
    assert run_cli("compare", save(empty, tmp_path / "empty"), MATRIX).code == 2


def test_a_run_killed_before_its_first_cell_is_incomplete_not_another_scenario(tmp_path):
    """It read `no cell in common... compare runs of the same scenario` (exit 2): wrong advice for a run that never got going."""
    killed = copy.deepcopy(matrix())
    killed.cells, killed.status = [], "running"
    path = save(killed, tmp_path / "killed")
    junit = tmp_path / "c.xml"
    done = run_cli("compare", MATRIX, path, "--junit", str(junit))
    assert done.code == 4, done.err
    assert "no cell in common" not in done.err
    headline = done.out.split("\n\n")[1]
    assert headline.startswith("⚠️ This run is incomplete: its run never finished (results.json says running): 5 of its 5 cell runs")
    assert junit.read_text().count("<error") == 5
    as_baseline = run_cli("compare", path, MATRIX)  # nothing to compare with: refused, saying why
    assert as_baseline.code == 2, as_baseline.err
    assert f"the baseline {path} holds no cell: its run never finished" in as_baseline.err
    assert "compare runs of the same scenario" not in as_baseline.err


def test_a_partial_comparison_says_which_cells_were_not_compared():
    base = matrix()
    new = copy.deepcopy(base)
    new.cells = new.cells[1:]
    from runner.report.markdown import render_comparison

    text = render_comparison(cmp.compare(base, new), "b", "n")
    assert f"No regression in 4 cells compared with the baseline. 1 cell of the baseline not in this run: {base.cells[0].id}." in text
    text = render_comparison(cmp.compare(new, base), "b", "n")
    assert f"No regression in 4 cells compared with the baseline. 1 cell not in the baseline: {base.cells[0].id}." in text


def test_a_figure_that_is_not_a_number_is_never_within_threshold():
    base = matrix()
    cell = base.cells[1].id
    name = "involuntary.per_callback_mean"
    for bad in (float("nan"), float("inf")):
        result = cmp.compare(base, with_figures(base, cell, invol_mean=bad))
        verdicts = {(f.cell, f.figure.name): f.verdict for f in result.figures}
        assert verdicts[(cell, name)] == cmp.Verdict.MISSING
        result = cmp.compare(with_figures(base, cell, invol_mean=bad), base)
        assert {(f.cell, f.figure.name): f.verdict for f in result.figures}[(cell, name)] == cmp.Verdict.NEW


def test_comparison_numbers_read_as_the_report_writes_them_with_one_minus_sign():
    """`9.89`, not `9.8889`; baseline, run and change of a row in one unit and precision; U+2212 for every minus."""
    from runner.report.markdown import render_comparison, render_run

    base = matrix()
    new = with_figures(base, "policy=other,priority=0", invol_mean=4.0, latency_p99=2_100_000)
    section = render_comparison(cmp.compare(base, new), "base", "new")
    row = next(line for line in section.splitlines() if "other" in line and "involuntary switches per callback" in line)
    assert [c.strip() for c in row.split("|")[4:7]] == ["9.89 \\[7.94, 12.17\\]", "4.00 \\[2.80, 5.54\\]", "−5.89 (−60%)"]
    assert "9.89" in render_run(base)  # as the report says it
    row = next(line for line in section.splitlines() if "other" in line and "wake-up latency p99" in line)
    assert [c.strip() for c in row.split("|")[3:7]] == ["wake-up latency p99 (µs)", "3,156", "2,100", "−1,056 (−33%)"]
    assert "-" not in "".join(c for line in section.splitlines() if line.startswith("| policy") for c in line.split("|")[4:7])


def test_a_run_that_never_finished_is_never_green_against_its_baseline(tmp_path):
    """A crashed run's results.json (running, 2 of 5 cells) compared as `✅ No regression in 2 cells`, exit 0."""
    crashed = copy.deepcopy(matrix())
    crashed.cells, crashed.status = crashed.cells[:2], "running"
    done = run_cli("compare", MATRIX, save(crashed, tmp_path / "new"))
    assert done.code == 4, done.err
    assert "⚠️ This run is incomplete: its run never finished (results.json says running): 3 of its 5 cell runs are missing." in done.out
    headline = next(line for line in done.out.splitlines() if "This run is incomplete" in line)
    assert "✅" not in headline and "only the cells it holds were compared" in done.err


def test_an_interrupted_run_is_never_green_and_exits_130_as_the_run_did(tmp_path):
    """A run stopped between cells (interrupted, 2 of 5 cells, all passed) compared as `✅ No regression`, exit 0, a clean JUnit."""
    stopped = copy.deepcopy(matrix())
    stopped.cells, stopped.status = stopped.cells[:2], "interrupted"
    junit = tmp_path / "c.xml"
    done = run_cli("compare", MATRIX, save(stopped, tmp_path / "new"), "--junit", str(junit))
    assert done.code == 130, done.err
    headline = next(line for line in done.out.splitlines() if "This run is incomplete" in line)
    assert headline.startswith(
        "⚠️ This run is incomplete: its run was interrupted (results.json says interrupted): 3 of its 5 cell runs are missing."
    )
    assert "✅" not in headline and "only the cells it holds were compared" in done.err
    xml = junit.read_text()
    assert xml.count("<error") == 3 and "not run: the run ended before it (its status: interrupted)" in xml


def _never_finished(doc):
    doc.cells, doc.status = doc.cells[:2], "running"


def _stopped(doc):
    doc.cells, doc.status = doc.cells[:2], "interrupted"


def _errored(doc):
    doc.cells[1].status, doc.status = Status.ERROR, "error"


@pytest.mark.parametrize("change, code", [(_never_finished, 4), (_stopped, 130), (_errored, 4)])
def test_report_with_a_baseline_decides_as_compare_does(tmp_path, change, code):
    """`runner report NEW --baseline BASE` exited 0 for a run that never finished, where `runner compare` exited 4."""
    new = copy.deepcopy(matrix())
    change(new)
    path = save(new, tmp_path / "new")
    compared = run_cli("compare", MATRIX, path)
    reported = run_cli("report", path, "--baseline", MATRIX, "--no-plots")
    assert compared.code == reported.code == code, (compared.err, reported.err)
    if new.status != "error":
        assert "only the cells it holds were compared" in reported.err


def test_a_figure_the_baseline_has_and_this_run_lacks_fails_the_comparison(tmp_path):
    """`latency_ns: null` now read `✅ No regression... 1 figure of the baseline not measured now`, a skipped test case, exit 0."""
    new = copy.deepcopy(matrix())
    cell = new.cells[1]
    t = main_thread(cell)
    cell.threads[cell.threads.index(t)] = t.model_copy(update={"figures": t.figures.model_copy(update={"latency_ns": None})})
    path = save(new, tmp_path / "new")
    junit = tmp_path / "c.xml"
    done = run_cli("compare", MATRIX, path, "--junit", str(junit))
    assert done.code == 1, done.err
    headline = done.out.split("\n\n")[1]
    assert "✅" not in headline and headline.startswith(f"❌ **1 regression** in 1 of 5 cells: {cell.id}.")
    assert f"1 figure of the baseline not measured now: latency.p99 ({cell.id})." in headline
    assert "<failure" in junit.read_text() and "wake-up latency p99: not measured in this run (baseline" in junit.read_text()
    assert run_cli("compare", MATRIX, path, "--threshold", "latency.p99=off").code == 0  # a figure never judged is not judged missing


def test_a_thread_only_the_baseline_has_is_compared_and_fails():
    """The threads compared came from the new run alone: a thread that vanished was never looked at."""
    from runner.report.markdown import render_comparison
    from runner.report.outcomes import Outcome, cell_checks

    base = matrix()
    new = copy.deepcopy(base)
    cell = new.cells[2]
    gone = main_thread(cell)
    cell.threads.remove(gone)
    result = cmp.compare(base, new)
    assert result.threads_gone == [(cell.id, gone.key)]
    lost = [f for f in result.figures if f.cell == cell.id and f.thread == gone.key]
    assert lost and {f.verdict for f in lost} == {cmp.Verdict.MISSING}
    assert result.regressions == len(lost) and result.regressed_cells() == [cell.id]
    headline = render_comparison(result, "b", "n").split("\n\n")[1]
    assert "✅" not in headline
    assert f"1 thread of the baseline not in this run: minimal_schedul/minimal_schedul (main) ({cell.id})." in headline
    checks = [c for suite in cell_checks(new, result, run=False) for c in suite.checks if c.outcome is Outcome.FAILED]
    assert len(checks) == len(lost) and all("the thread is not in this run" in c.message for c in checks)


def test_a_figure_the_baseline_has_and_this_run_lacks_is_in_the_headline():
    base = matrix()
    cell = base.cells[1].id
    from runner.report.markdown import render_comparison

    text = render_comparison(cmp.compare(base, with_figures(base, cell, invol_mean=float("nan"))), "b", "n")
    assert f"1 figure of the baseline not measured now: involuntary.per_callback_mean ({cell})." in text.split("\n\n")[1]


def _headline(result: cmp.Comparison) -> str:
    from runner.report.markdown import render_comparison

    return render_comparison(result, "b", "n").split("\n\n")[1]


def test_another_version_of_the_scenario_is_said_first_in_the_headline_without_a_check_mark(tmp_path):
    """A baseline of another scenario_hash compared as `✅ No regression`: report/ never looked at the plan's hashes."""
    base, new = copy.deepcopy(matrix()), copy.deepcopy(matrix())
    base.plan.scenario_hash, new.plan.scenario_hash = "1111111111111111", "2222222222222222"
    done = run_cli("compare", save(base, tmp_path / "base"), save(new, tmp_path / "new"))
    assert done.code == 0, done.err  # every cell's resolved settings agree: compared, and said
    headline = done.out.split("\n\n")[1]
    assert headline.startswith(
        "⚠️ **Another version of the scenario**: the baseline ran another version of the scenario file "
        "(plan.scenario_hash 1111111111111111 there, 2222222222222222 now); only its cells whose resolved settings are the same "
        "were compared. No regression in 5 cells"
    )
    assert "✅" not in headline and "warning:" in done.err and "another version of the scenario file" in done.err
    new.plan.scenario_hash = None  # a file that does not record it (an older runner's) is not held against it
    assert _headline(cmp.compare(base, new)).startswith("✅ No regression in 5 cells")


@pytest.mark.parametrize(
    "change, words",
    [
        (
            lambda doc: setattr(doc.plan, "expect_hash", "2222"),
            "⚠️ The cells were judged by other expectations than the baseline's (plan.expect_hash 1111 there, 2222 now): "
            "a status may differ for that alone.",
        ),
        (
            lambda doc: setattr(doc.machine, "hostname", "other"),
            "⚠️ The baseline ran on vm (kernel 6.18.44-fc-v669), this run on other (kernel 6.18.44-fc-v669): "
            "figures may differ for that alone.",
        ),
    ],
)
def test_other_expectations_or_another_host_are_said_in_the_headline_without_a_check_mark(change, words):
    """Another host or kernel was a note below the facts, under a ✅ headline; other expectations were not said at all."""
    base = copy.deepcopy(matrix())
    base.plan.expect_hash = "1111"
    new = copy.deepcopy(base)
    new.plan.expect_hash = "1111"
    assert _headline(cmp.compare(base, new)).startswith("✅ No regression")
    change(new)
    headline = _headline(cmp.compare(base, new))
    assert headline == f"No regression in 5 cells compared with the baseline. {words}"


def _traced(lost: int = 0, untracked: int = 0, p99: int = 40_000):
    """The recorded matrix as if traced: every periodic thread with trace figures, its first cell's trace losing events."""
    from runner.results.document import TraceInfo
    from runner.results.threadfigures import Spread

    doc = copy.deepcopy(matrix())
    for n, cell in enumerate(doc.cells):
        t = main_thread(cell)
        wakeup = Spread(min=1_000, p50=2_000, p90=3_000, p99=p99, p999=p99, max=p99)
        cell.threads[cell.threads.index(t)] = t.model_copy(
            update={"figures": t.figures.model_copy(update={"wakeup_ns": wakeup, "preemptions": 3})}
        )
        cell.trace = TraceInfo(enabled=True, events=10_000, lost=lost if n == 0 else 0, untracked=untracked if n == 0 else 0)
    return doc


@pytest.mark.parametrize("loss", [{"lost": 7}, {"untracked": 7}])
@pytest.mark.parametrize("lossy_run", ["new", "base"])
def test_trace_figures_are_not_comparable_where_the_trace_lost_events_in_either_run(loss, lossy_run, tmp_path):
    """A trace that lost events undercounts what it measured: wake-up p99 read as 10 times worse (or better) regardless."""
    base = _traced(p99=4_000, **(loss if lossy_run == "base" else {}))
    new = _traced(p99=40_000, **(loss if lossy_run == "new" else {}))
    result = cmp.compare(base, new, [cmp.parse_threshold("wakeup.p99=+20%"), cmp.parse_threshold("preemptions=+0")])
    verdicts = {(f.cell, f.figure.name): f.verdict for f in result.figures}
    lossy, clean = base.cells[0].id, base.cells[1].id
    assert verdicts[(lossy, "wakeup.p99")] == verdicts[(lossy, "preemptions")] == cmp.Verdict.UNCOMPARABLE
    assert verdicts[(clean, "wakeup.p99")] == cmp.Verdict.REGRESSION  # where nothing was lost, compared as ever
    assert lossy not in result.regressed_cells()
    headline = _headline(result)
    assert "✅" not in headline
    now, there = (7, 0) if lossy_run == "new" else (0, 7)
    assert (
        f"⚠️ The scheduler trace lost events in 1 cell: {lossy} ({now} lost or untracked now, {there} in the baseline): "
        "the figures taken from it there (wakeup.p99, preemptions) are not compared."
    ) in headline
    from runner.report.junit import junit_xml

    xml = junit_xml(new, result, run=False).decode()
    assert "waking-to-running latency (scheduler trace) p99 4.0 µs → 40.0 µs: not comparable (the scheduler trace lost events" in xml


def test_the_registry_marks_the_figures_taken_from_the_scheduler_trace():
    from runner import figures as fg

    traced = {f.name for f in fg.REGISTRY if f.traced}
    assert traced == {"preemptions"} | {f.name for f in fg.REGISTRY if f.path[0] == "wakeup_ns"}


def test_a_regression_against_the_baseline_is_said_on_the_terminal_not_only_in_report_md(tmp_path):
    """A run (or merge, or report) with --baseline printed `passed` and exit 1, the regressions only in report.md: a CI
    log read as a pass that failed.  The terminal now has the comparison's headline, in plain words."""
    new = copy.deepcopy(matrix())
    cell = new.cells[1]
    t = main_thread(cell)
    cell.threads[cell.threads.index(t)] = t.model_copy(update={"figures": t.figures.model_copy(update={"latency_ns": None})})
    path = save(new, tmp_path / "new")
    done = run_cli("report", path, "--baseline", MATRIX, "--no-plots")
    assert done.code == 1, done.err
    line = next(x for x in done.out.splitlines() if x.startswith(f"compared with {MATRIX}: "))
    assert f"❌ 1 regression in 1 of 5 cells: {cell.id}." in line and "**" not in line and line.endswith("report.md)")
    same = run_cli("report", MATRIX, "--baseline", MATRIX, "--no-plots", "-o", str(tmp_path / "r.md"))
    assert same.code == 0 and f"compared with {MATRIX}: ✅ No regression in 5 cells compared with the baseline." in same.out, same.out
    merged = run_cli("merge", path, "--out", str(tmp_path / "merged"), "--baseline", MATRIX, "--no-plots")  # as a run does
    said = next(x for x in merged.out.splitlines() if x.startswith(f"compared with {MATRIX}: "))
    assert merged.code == 1 and "❌ 1 regression" in said and said.endswith(f"{tmp_path / 'merged' / 'comparison.md'})"), merged.out


def test_a_figure_given_two_thresholds_is_refused_not_the_last_one_kept(tmp_path):
    """`--threshold latency.p99=+20% --threshold latency.p99=off` judged nothing: the last one silently won."""
    done = run_cli("compare", MATRIX, MATRIX, "--threshold", "latency.p99=+20%", "--threshold", "latency.p99=off")
    assert done.code == 2 and "--threshold latency.p99 is given twice" in done.err, done.err
    assert run_cli("compare", MATRIX, MATRIX, "--threshold", "latency.p99=+20%", "--threshold", "latency.max=off").code == 0


def test_the_headline_names_at_most_five_cells_of_each_kind():
    """A 1,000-cell matrix's headline (and the terminal line `compared with BASE: ...`) listed every regressed,
    missing and new cell: thousands of characters.  Each list is cut at five, `and N more`, as threads and figures are."""
    from runner.report.markdown import build_comparison

    base = matrix()
    template = base.cells[0]
    extra = [template.model_copy(update={"id": f"z{i}"}, deep=True) for i in range(8)]
    base.cells += [template.model_copy(update={"id": f"gone{i}"}, deep=True) for i in range(8)] + extra
    new = copy.deepcopy(matrix())
    new.cells += [c.model_copy(update={"id": f"added{i}"}, deep=True) for i, c in enumerate(extra)]
    new.cells += [c.model_copy(update={"id": c.id, "status": Status.FAILED}, deep=True) for c in extra]
    headline = str(build_comparison(cmp.compare(base, new), "base", "new").headline)
    assert "z0, z1, z2, z3, z4 and 3 more." in headline and "z5" not in headline, headline
    assert "8 cells of the baseline not in this run: gone0, gone1, gone2, gone3, gone4 and 3 more." in headline, headline
    assert "8 cells not in the baseline: added0, added1, added2, added3, added4 and 3 more." in headline, headline


def test_a_thread_or_a_cell_of_the_baseline_not_in_this_run_is_never_a_check_mark():
    """A thread gone whose figures' thresholds are all off read `✅ No regression ... 1 thread of the baseline not in this run`."""
    base = matrix()
    new = copy.deepcopy(base)
    new.cells[1].threads = [t for t in new.cells[1].threads if not t.has_callbacks]  # its one compared thread gone
    off = [cmp.Threshold(t.figure) for t in cmp.DEFAULT_THRESHOLDS]
    result = cmp.compare(base, new, off)
    assert result.threads_gone and result.regressions == 0
    from runner.report.markdown import build_comparison

    headline = str(build_comparison(result, "base", "new").headline)
    assert "1 thread of the baseline not in this run" in headline and "✅" not in headline, headline
    fewer = copy.deepcopy(base)
    fewer.cells = fewer.cells[:-1]
    headline = str(build_comparison(cmp.compare(base, fewer), "base", "new").headline)
    assert "1 cell of the baseline not in this run" in headline and "✅" not in headline, headline


def test_a_cell_failed_in_both_runs_fails_the_merge_not_the_comparison_as_the_docs_say(tmp_path):
    """The docs' "Exit codes" (README's, now docs/commands.md's) said run, merge, compare and report --baseline decide
    alike, yet a cell whose expectation failed in both runs made merge exit 1 and compare exit 0: compare judges
    regressions, not the run's own expectations."""
    from conftest import REPO

    runs = []
    for name in ("base", "new"):
        doc = copy.deepcopy(matrix())
        doc.cells[1].status, doc.status = Status.FAILED, "failed"
        runs.append(save(doc, tmp_path / name))
    assert run_cli("merge", runs[1], "--out", str(tmp_path / "m"), "--no-plots", "--baseline", runs[0]).code == 1
    assert run_cli("compare", *runs).code == 0
    assert run_cli("report", runs[1], "--baseline", runs[0], "--no-plots").code == 0
    with open(os.path.join(REPO, "docs", "commands.md"), encoding="utf-8") as handle:
        words = " ".join(handle.read().split("## Exit codes")[1].split("|")[0].split())
    assert "a cell that failed in both runs exits 0 there while the run or merge that produced it exited 1" in words, words
