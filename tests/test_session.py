"""The run path without processes: the session's cell loop, resume, repeats, shuffle, interrupts and exit codes.

A fake backend (tests/fakebackend.py) stands in for the kernel; everything above it
(the session, the pure evaluation core, results, the report) is the real code.
Exit codes are written as the numbers README documents, not taken from the code.
"""

from __future__ import annotations

import errno
import gc
import json
import os
import signal

import pytest
from conftest import SCENARIOS, run_cli
from fakebackend import Act, Died, FakeBackend

from runner.cli import _run_parser
from runner.errors import RunnerError, ScenarioError, UsageError
from runner.scenario.loader import load_scenario
from runner.session import RunOptions, run_scenario

MATRIX = os.path.join(SCENARIOS, "policy_matrix.yaml")
FIFO80 = os.path.join(SCENARIOS, "fifo80.yaml")
OTHER = "policy=other,priority=0"
FIFO_CELLS = ["policy=fifo,priority=10", "policy=fifo,priority=80", "policy=rr,priority=10", "policy=rr,priority=80"]


def run(scenario: str, out, backend: FakeBackend, *args: str) -> tuple[int, dict]:
    ns = _run_parser().parse_args([scenario, "--out", str(out), "--quiet", "--settle", "0", "--no-plots", *args])
    code = run_scenario(load_scenario(scenario), RunOptions.from_namespace(ns, env={}), backend)
    with open(os.path.join(out, "results.json")) as handle:
        return code, json.load(handle)


def preempted_other() -> dict[str, Act]:
    """The matrix as the seed describes it: OTHER preempted in every callback, FIFO and RR never."""
    return {OTHER: Act(nivcsw=5)}


def test_a_matrix_that_meets_its_expectations_exits_0(tmp_path):
    backend = FakeBackend(preempted_other())
    code, results = run(MATRIX, tmp_path / "r", backend)
    assert code == 0
    assert results["status"] == "passed" and [c["status"] for c in results["cells"]] == ["passed"] * 5
    assert sorted(backend.ran) == sorted(FIFO_CELLS + [OTHER]) and backend.closed and backend.cells_over
    assert os.path.exists(tmp_path / "r" / "report.md")


def test_each_cells_own_write_is_timed_and_in_the_runs_last_write(tmp_path):
    _, results = run(MATRIX, tmp_path / "r", FakeBackend(preempted_other()))
    saves = [c["overhead_ns"]["save"] for c in results["cells"]]
    assert len(saves) == 5 and all(isinstance(ns, int) and ns > 0 for ns in saves)


def test_a_failed_expectation_exits_1(tmp_path):
    code, results = run(MATRIX, tmp_path / "r", FakeBackend({OTHER: Act(nivcsw=0)}))
    assert code == 1
    other = next(c for c in results["cells"] if c["id"] == OTHER)
    assert other["status"] == "failed" and not other["expectations"][0]["passed"]


@pytest.mark.parametrize(
    "act, words",
    [
        (Act(failures=("process minimal_schedul[0] (pid 4242) was killed by SIGKILL",)), "killed by SIGKILL"),
        (Act(failures=("the cell overran its deadline and was killed by the watchdog",)), "watchdog"),
        (Act(incidents=("background hog hog[0] (pid 4343) killed by SIGKILL 1.0s into the cell",)), "background hog"),
        (Act(incidents=("process minimal_schedul[0] (pid 4242) was stopped (SIGSTOP or a debugger) 0.5s into the cell",)), "stopped"),
    ],
)
def test_a_run_error_in_a_cell_exits_4_with_its_reason(tmp_path, act, words):
    code, results = run(FIFO80, tmp_path / "r", FakeBackend({"default": act}), "--duration", "1s")
    assert code == 4
    cell = results["cells"][0]
    assert cell["status"] == "error" and words in cell["reason"]
    assert results["status"] == "error"


def test_a_process_released_after_the_common_start_is_a_warning_in_words(tmp_path):
    late = Act(released_late=(("process minimal_schedul[0]", 3_400_000),))
    code, results = run(FIFO80, tmp_path / "r", FakeBackend({"default": late}), "--duration", "1s")
    cell = results["cells"][0]
    assert code == 0 and cell["status"] == "passed"
    said = [w for w in cell["warnings"] if w.startswith("process minimal_schedul[0] was released 3.40 ms after the common start")]
    assert said and "runner's doing" in said[0], cell["warnings"]
    _, results = run(FIFO80, tmp_path / "s", FakeBackend(), "--duration", "1s")
    assert not [w for w in results["cells"][0]["warnings"] if "common start" in w]


def test_the_session_prepares_the_backend_once_with_the_trace_choice(tmp_path):
    backend = FakeBackend()
    run(FIFO80, tmp_path / "r", backend, "--duration", "1s")
    assert backend.prepared is True
    backend = FakeBackend()
    run(FIFO80, tmp_path / "s", backend, "--duration", "1s", "--no-trace")
    assert backend.prepared is False


def test_unapplied_settings_are_an_error_unless_degraded_runs_are_allowed(tmp_path):
    code, results = run(FIFO80, tmp_path / "a", FakeBackend({"default": Act(degrade=True)}), "--duration", "1s")
    assert code == 4 and results["cells"][0]["status"] == "error"
    assert "fifo:80 requested, other applied (Operation not permitted)" in results["cells"][0]["reason"]
    code, results = run(FIFO80, tmp_path / "b", FakeBackend({"default": Act(degrade=True)}), "--duration", "1s", "--allow-degraded")
    assert code == 0 and results["cells"][0]["status"] == "degraded"


def test_missed_releases_are_counted_to_the_end_of_the_cell(tmp_path):
    _, results = run(FIFO80, tmp_path / "r", FakeBackend({"default": Act(served=0.25)}), "--duration", "2s")
    main = next(t for t in results["cells"][0]["threads"] if t["index"] == 0)
    assert main["figures"]["callbacks"] == 5 and main["figures"]["missed_releases"] == 15  # 20 releases of 100 ms in 2 s, 5 served


def test_an_interrupt_stops_after_the_cell_and_exits_130_with_results_and_report(tmp_path):
    backend = FakeBackend({FIFO_CELLS[1]: Act(signals=3)})
    code, results = run(MATRIX, tmp_path / "r", backend)
    assert code == 130
    assert backend.ran == FIFO_CELLS[:2], "no cell may start after the interrupt"
    assert results["status"] == "interrupted"
    assert [c["status"] for c in results["cells"]] == ["passed", "interrupted"]
    assert os.path.exists(tmp_path / "r" / "report.md")


def test_a_shard_that_holds_no_cell_exits_0_and_says_nothing_ran(tmp_path, capsys):
    """More CI jobs than cells: the empty shard stays green, but never reads as cells that passed."""
    backend = FakeBackend(preempted_other())
    code, results = run(MATRIX, tmp_path / "r", backend, "--shard", "7/7")
    assert code == 0 and backend.ran == [] and results["cells"] == []
    out = capsys.readouterr().out
    assert "policy_matrix: shard 7/7 holds none of the scenario's 5 cells; nothing to run, results in " in out
    assert "policy_matrix: shard 7/7 holds none of the scenario's 5 cells; nothing ran; results: " in out
    assert "0 cells to run" not in out and "passed" not in out


def test_a_shard_that_holds_no_cell_with_a_baseline_has_nothing_to_compare_and_exits_0(tmp_path, capsys):
    """`--shard 7/7 --baseline B` exited 2 (no cell in common ... compare runs of the same scenario), listed or run,
    though such a job stays green; a baseline of another scenario is still refused."""
    run(MATRIX, tmp_path / "base", FakeBackend(preempted_other()), "--duration", "1s")
    base = str(tmp_path / "base")
    listed = run_cli(MATRIX, "--shard", "7/7", "--baseline", base, "--list")
    assert listed.code == 0, listed.err
    capsys.readouterr()
    code, results = run(MATRIX, tmp_path / "r", FakeBackend(), "--shard", "7/7", "--duration", "1s", "--baseline", base)
    out = capsys.readouterr().out
    assert code == 0 and results["cells"] == [], out
    assert f"compared with {base}: Nothing to compare: this run holds no cell (shard 7/7 holds none of the scenario's 5 cells)." in out
    for done in (run_cli("compare", base, str(tmp_path / "r")), run_cli("report", str(tmp_path / "r"), "--baseline", base, "--no-plots")):
        assert done.code == 0 and "Nothing to compare" in done.out and "✅" not in done.out, (done.out, done.err)
    other = run_cli(FIFO80, "--shard", "2/2", "--baseline", base, "--list")  # fifo80's one cell is in shard 1/2
    assert other.code == 2 and "no cell in common with the baseline" in other.err, other.err


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_a_stop_while_the_runner_prepares_runs_no_cell_and_exits_130_with_results(tmp_path, sig):
    backend = FakeBackend(signal_on_prepare=sig)
    code, results = run(MATRIX, tmp_path / "r", backend)
    assert code == 130, "a stop before the first cell is an interrupted run, not a killed runner"
    assert backend.ran == [] and backend.closed
    assert results["status"] == "interrupted" and results["cells"] == []
    assert os.path.exists(tmp_path / "r" / "report.md")


def test_a_signal_ignored_on_entry_stays_ignored(tmp_path, monkeypatch):
    """Under nohup SIGHUP is ignored: logging out must not stop the run."""
    from runner.session import StopSignals

    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with StopSignals() as stop:
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN and signal.getsignal(signal.SIGTERM) == stop._handle
            os.kill(os.getpid(), signal.SIGHUP)
            assert not stop.requested()
    finally:
        signal.signal(signal.SIGHUP, previous)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_after_the_last_cell_leaves_the_results_whole_and_exits_130(tmp_path, sig, capfd):
    code, results = run(FIFO80, tmp_path / "r", FakeBackend(signal_on_close=sig), "--duration", "1s")
    assert code == 130
    assert results["status"] == "passed" and [c["status"] for c in results["cells"]] == ["passed"]
    died = FakeBackend({"default": Act(failures=("a worker died",))}, signal_on_close=sig)
    code, _ = run(FIFO80, tmp_path / "s", died, "--duration", "1s")
    assert code == 4, "a run error stays the error it was"


def test_a_stop_during_the_report_is_said_and_the_report_still_written(tmp_path, capfd, monkeypatch):
    import runner.report.publish as publish

    finish = publish.finish

    def interrupted_finish(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        return finish(*args, **kwargs)

    monkeypatch.setattr(publish, "finish", interrupted_finish)
    code, results = run(FIFO80, tmp_path / "r", FakeBackend(), "--duration", "1s")
    assert code == 130 and results["status"] == "passed"
    assert os.path.exists(tmp_path / "r" / "report.md")
    assert "asked to stop; the cells are done, finishing the results and the report" in capfd.readouterr().err


def test_a_baseline_that_cannot_be_read_is_refused_before_any_cell_runs(tmp_path):
    backend = FakeBackend()
    with pytest.raises(ScenarioError, match="cannot read results"):
        run(FIFO80, tmp_path / "r", backend, "--duration", "1s", "--baseline", str(tmp_path / "nosuch.json"))
    assert backend.ran == [] and not os.path.exists(tmp_path / "r" / "results.json")


def test_a_baseline_the_run_could_not_be_compared_with_is_refused_before_any_cell_runs(tmp_path):
    """Another scenario's baseline, or one whose cells ran another spec or length, is refused up front, not after the run."""
    run(MATRIX, tmp_path / "other", FakeBackend(preempted_other()), "--duration", "1s")
    backend = FakeBackend()
    with pytest.raises(ScenarioError, match="no cell in common with the baseline"):
        run(FIFO80, tmp_path / "r", backend, "--duration", "1s", "--baseline", str(tmp_path / "other"))
    longer = r"cells\.policy=fifo,priority=80: differs from the baseline .*ran for 1s in the baseline, 2s now"
    with pytest.raises(ScenarioError, match=longer):
        run(MATRIX, tmp_path / "r2", backend, "--duration", "2s", "--baseline", str(tmp_path / "other"))
    assert backend.ran == [] and not os.path.exists(tmp_path / "r" / "results.json") and not os.path.exists(tmp_path / "r2")
    code, _ = run(MATRIX, tmp_path / "r3", FakeBackend(preempted_other()), "--duration", "1s", "--baseline", str(tmp_path / "other"))
    assert code == 0, "the same scenario and length compare"


@pytest.mark.parametrize("name", ["..", ".", "x" * 300])
def test_the_default_results_folder_stays_under_reports_whatever_the_scenario_is_named(tmp_path, monkeypatch, name):
    """`name: ..` once put the results beside reports/, and a 300-character name failed the run (File name too long)."""
    scenario = tmp_path / "s.yaml"
    scenario.write_text(open(FIFO80).read().replace("name: fifo80", f"name: '{name}'"))
    monkeypatch.chdir(tmp_path)
    ns = _run_parser().parse_args([str(scenario), "--quiet", "--no-plots", "--duration", "1s", "--settle", "0"])
    assert run_scenario(load_scenario(str(scenario)), RunOptions.from_namespace(ns, env={}), FakeBackend()) == 0
    (kept,) = os.listdir(tmp_path / "reports")
    assert len(kept) <= 160 and ".." not in kept and "/" not in kept
    assert sorted(os.listdir(tmp_path)) == ["reports", "s.yaml"]


def test_resume_runs_only_what_did_not_finish(tmp_path):
    out = tmp_path / "r"
    acts = preempted_other()
    run(MATRIX, out, FakeBackend({**acts, FIFO_CELLS[1]: Act(signals=1)}))
    backend = FakeBackend(acts)
    ns = _run_parser().parse_args([MATRIX, "--resume", str(out), "--quiet", "--no-plots"])
    code = run_scenario(load_scenario(MATRIX), RunOptions.from_namespace(ns, env={}), backend)
    results = json.load(open(out / "results.json"))
    assert code == 0
    assert backend.ran == FIFO_CELLS[1:] + [OTHER]
    assert [c["id"] for c in results["cells"]] == FIFO_CELLS + [OTHER]
    assert results["status"] == "passed"


def test_list_reads_and_checks_the_baseline_and_the_resumed_run_as_the_run_would(tmp_path):
    """`--list --baseline X` and `--list --resume DIR` once listed every cell whatever X or DIR was."""
    listed = run_cli(FIFO80, "--list", "--baseline", str(tmp_path / "nosuch.json"))
    assert listed.code == 2 and "nosuch.json:1:1: cannot read results: No such file or directory" in listed.err
    listed = run_cli(FIFO80, "--list", "--resume", str(tmp_path / "nosuch"))
    assert listed.code == 2 and "cannot read results" in listed.err
    out = tmp_path / "r"
    run(MATRIX, out, FakeBackend({FIFO_CELLS[0]: Act(signals=1)}), "--cell", "policy=fifo*", "--duration", "1s")
    listed = run_cli(FIFO80, "--list", "--baseline", str(out))
    assert listed.code == 2 and "no cell in common with the baseline" in listed.err
    listed = run_cli(FIFO80, "--list", "--resume", str(out))
    assert listed.code == 2 and "scenario.name: is 'policy_matrix', but " in listed.err
    listed = run_cli(MATRIX, "--list", "--resume", str(out))  # the cells and the length the resumed run would take
    assert listed.code == 0 and "2 of 5 cells" in listed.out and listed.out.count("duration 1s)") == 2, listed.err


def resume(scenario: str, out, backend: FakeBackend, *args: str) -> tuple[int, dict]:
    ns = _run_parser().parse_args([scenario, "--resume", str(out), "--quiet", "--no-plots", *args])
    code = run_scenario(load_scenario(scenario), RunOptions.from_namespace(ns, env={}), backend)
    with open(os.path.join(out, "results.json")) as handle:
        return code, json.load(handle)


@pytest.mark.parametrize(
    ("given", "said"),
    [
        (["--duration", "1s"], "--duration 1s was given, but the run recorded no --duration (the scenario's)"),
        (["--cell", "*"], "--cell * was given, but the run recorded no --cell (every cell)"),
        (["--repeat", "2"], "--repeat 2 was given, but the run recorded --repeat 1"),
        (["--shuffle"], "--shuffle (a random seed) was given, but the run recorded no --shuffle"),
        (["--settle", "1s"], "--settle 1s was given, but the run recorded --settle 0s"),
        (["--shard", "1/2"], "--shard 1/2 was given, but the run recorded no --shard"),
        (["--no-trace"], "--no-trace was given, but the run recorded tracing (no --no-trace)"),
        (["--dma-latency", "5"], "--dma-latency 5 was given, but the run recorded --dma-latency 0"),
        (["--no-dma-latency"], "--no-dma-latency was given, but the run recorded --dma-latency 0"),
    ],
)
def test_resume_refuses_options_that_would_run_the_rest_differently(tmp_path, given, said):
    out = tmp_path / "r"
    run(MATRIX, out, FakeBackend({**preempted_other(), FIFO_CELLS[1]: Act(signals=1)}))
    done = run_cli(MATRIX, "--resume", str(out), "--quiet", *given)
    assert done.code == 2 and "Traceback" not in done.err, done.err
    assert f"finishes DIR's run with the options it recorded: {said}; leave out {given[0]}, or start a new run" in done.err


def test_resume_takes_options_equal_to_the_recorded_ones(tmp_path):
    """The command line that started the run, given again with --resume, finishes it (1000ms is the 1s recorded)."""
    out = tmp_path / "r"
    started = ["--duration", "1s", "--cell", "policy=*", "--cell", "policy=fifo*", "--shuffle", "7", "--dma-latency", "10"]
    run(MATRIX, out, FakeBackend({**preempted_other(), FIFO_CELLS[1]: Act(signals=1)}), *started)
    again = ["--duration", "1000ms", "--cell", "policy=fifo*", "--cell", "policy=*", "--shuffle", "7", "--dma-latency", "10"]
    backend = FakeBackend(preempted_other())
    code, results = resume(MATRIX, out, backend, *again, "--settle", "0", "--repeat", "1")
    assert code == 0 and FIFO_CELLS[1] in backend.ran and len(backend.ran) < 5 and backend.dma_requests == [10]
    assert sorted(c["id"] for c in results["cells"]) == sorted(FIFO_CELLS + [OTHER]) and results["status"] == "passed"


def test_resume_runs_the_rest_traced_and_held_as_the_run_began(tmp_path):
    out = tmp_path / "r"
    first = FakeBackend({**preempted_other(), FIFO_CELLS[1]: Act(signals=1)})
    run(MATRIX, out, first, "--no-trace", "--dma-latency", "100", "--duration", "300ms")
    assert first.prepared is False and first.dma_requests == [100]
    backend = FakeBackend(preempted_other())
    code, results = resume(MATRIX, out, backend)
    assert code == 0 and backend.ran == FIFO_CELLS[1:] + [OTHER]
    assert backend.prepared is False, "the run began untraced: its rest is untraced too"
    assert backend.dma_requests == [100]
    mains = [t for c in results["cells"] for t in c["threads"] if t["index"] == 0]
    assert len(mains) == 5 and {t["figures"]["callbacks"] for t in mains} == {3}, "every cell ran the 300 ms the run began with"


def test_a_run_from_before_trace_was_recorded_resumes_with_the_options_given_again(tmp_path):
    """An older file does not say how it traced: --no-trace and --dma-latency may restore its start's options."""
    out = tmp_path / "r"
    run(MATRIX, out, FakeBackend({**preempted_other(), FIFO_CELLS[1]: Act(signals=1)}), "--no-trace", "--dma-latency", "10")
    doc = json.loads((out / "results.json").read_text())
    for key in ("trace", "dma_latency_us", "expect_hash", "scenario_hash"):
        doc["plan"].pop(key)
    (out / "results.json").write_text(json.dumps(doc))
    backend = FakeBackend(preempted_other())
    code, _ = resume(MATRIX, out, backend, "--no-trace", "--dma-latency", "10")
    assert code == 0 and backend.prepared is False and backend.dma_requests == [10]


def test_resume_refuses_a_scenario_whose_expectations_changed(tmp_path):
    out = tmp_path / "r"
    run(MATRIX, out, FakeBackend({**preempted_other(), FIFO_CELLS[1]: Act(signals=1)}))
    edited = tmp_path / "policy_matrix.yaml"
    text = open(MATRIX).read()
    assert "metric: latency.p99, max: 2ms" in text
    edited.write_text(text.replace("metric: latency.p99, max: 2ms", "metric: latency.p99, max: 1us"))
    backend = FakeBackend(preempted_other())
    with pytest.raises(ScenarioError, match="changed its expectations since this run started"):
        resume(str(edited), out, backend)
    assert backend.ran == []
    code, _ = resume(MATRIX, out, FakeBackend(preempted_other()))  # the file as it was: resumed
    assert code == 0


def test_resume_runs_again_a_cell_the_disk_spoiled(tmp_path):
    out = tmp_path / "r"
    code, results = run(MATRIX, out, FakeBackend({**preempted_other(), FIFO_CELLS[1]: Act(oserror=28)}))
    assert code == 4 and [c["status"] for c in results["cells"]] == ["passed", "error"] and results["cells"][1]["unwritten"]
    backend = FakeBackend(preempted_other())
    code, results = resume(MATRIX, out, backend)
    assert code == 0 and backend.ran == FIFO_CELLS[1:] + [OTHER], "space freed, the spoiled cell runs again"
    assert [c["status"] for c in results["cells"]] == ["passed"] * 5 and not any(c["unwritten"] for c in results["cells"])


def test_a_relative_out_stores_each_samples_file_relative_to_the_results_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, results = run(MATRIX, "nightly/shard-1", FakeBackend(preempted_other()))
    assert code == 0
    assert all(c["samples_file"].startswith("cells/") for c in results["cells"]), [c["samples_file"] for c in results["cells"]]
    assert all(os.path.exists(tmp_path / "nightly" / "shard-1" / c["samples_file"]) for c in results["cells"])


def test_repeats_and_a_shuffle_seed_give_one_folder_per_repeat_and_a_recorded_order(tmp_path):
    backend = FakeBackend(preempted_other())
    code, results = run(MATRIX, tmp_path / "r", backend, "--repeat", "2", "--shuffle", "7")
    assert code == 0
    assert sorted(backend.ran) == sorted((FIFO_CELLS + [OTHER]) * 2)
    assert backend.ran != (FIFO_CELLS + [OTHER]) * 2, "seed 7 should not give the expansion order"
    assert results["plan"]["shuffle_seed"] == 7 and results["plan"]["repeat"] == 2
    assert sorted((c["id"], c["repeat"]) for c in results["cells"]) == sorted((c, r) for c in FIFO_CELLS + [OTHER] for r in (0, 1))
    assert all(os.path.exists(tmp_path / "r" / c["samples_file"]) for c in results["cells"])
    assert all("/repeat-" in c["samples_file"] for c in results["cells"])
    again = FakeBackend(preempted_other())
    run(MATRIX, tmp_path / "s", again, "--repeat", "2", "--shuffle", "7")
    assert again.ran == backend.ran, "the same seed gives the same order"


def test_a_cell_whose_files_cannot_be_made_stops_the_run_with_exit_4(tmp_path, capsys):
    backend = FakeBackend({FIFO_CELLS[1]: Act(oserror=28)})
    code, results = run(MATRIX, tmp_path / "r", backend)
    assert code == 4
    assert backend.ran == FIFO_CELLS[:2]
    assert [c["status"] for c in results["cells"]] == ["passed", "error"]
    assert "No space left on device" in results["cells"][1]["reason"] and results["status"] == "error"
    assert "No space left on device" in capsys.readouterr().err


def test_follow_prints_the_backends_lines(tmp_path, capsys):
    run(FIFO80, tmp_path / "r", FakeBackend({"default": Act(follow_lines=3)}), "--duration", "1s", "--follow")
    out = capsys.readouterr().out
    assert [line for line in out.splitlines() if line.startswith("[INFO] [fake]")] == [f"[INFO] [fake] callback {n}" for n in range(3)]


def test_a_regression_against_the_baseline_exits_1(tmp_path):
    """40 s at 100 ms: 400 callbacks, enough for a p99 to be judged (a 1 s run's 10 are not)."""
    run(FIFO80, tmp_path / "base", FakeBackend({"default": Act(latency_ns=50_000)}), "--duration", "40s")
    code, _ = run(
        FIFO80,
        tmp_path / "new",
        FakeBackend({"default": Act(latency_ns=900_000)}),
        "--duration",
        "40s",
        "--baseline",
        str(tmp_path / "base"),
    )
    assert code == 1
    assert "regression" in open(tmp_path / "new" / "comparison.md").read()


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [
        ("--duration", "99999999h", "100ms to 24h"),
        ("--duration", "10ms", "100ms to 24h"),
        ("--settle", "2h", "0s to 1h"),
        ("--repeat", "100000000000", "1 to 1,000,000"),
    ],
)
def test_duration_options_out_of_range_are_refused_before_anything_runs(tmp_path, option, value, expected):
    """The CLI holds --duration to the range a scenario file is held to: a day-long buffer is not created to fail."""
    done = run_cli(FIFO80, "--out", str(tmp_path / "r"), "--quiet", option, value)
    assert done.code == 2, done.err
    assert f"{option} {value} is out of range; expected {expected}" in done.err and "Traceback" not in done.err
    assert not os.path.exists(tmp_path / "r" / "results.json")


def test_a_duration_that_ends_before_a_threads_first_release_is_refused(tmp_path):
    scenario = tmp_path / "s.yaml"
    main = "{work: {kind: periodic, period: 100ms, offset: 1s}}"
    scenario.write_text(f"name: late\nduration: 2s\nprocesses:\n  - name: a\n    main: {main}\n")
    backend = FakeBackend()
    with pytest.raises(UsageError, match=r"--duration 500ms: offset 1s is not before the cell ends \(500ms\)"):
        run(str(scenario), tmp_path / "r", backend, "--duration", "500ms")
    assert backend.ran == []
    assert run(str(scenario), tmp_path / "s", FakeBackend(), "--duration", "1500ms")[0] == 0


def test_repeats_times_cells_beyond_a_million_are_refused_before_anything_runs(tmp_path):
    backend = FakeBackend()
    with pytest.raises(UsageError, match=r"--repeat 300,000 of 5 cells is 1,500,000 cell runs; at most 1,000,000 in one run"):
        run(MATRIX, tmp_path / "r", backend, "--repeat", "300000")
    assert backend.ran == [] and not os.path.exists(tmp_path / "r")


@pytest.mark.parametrize(("key", "value"), [("duration_ns", 10**18), ("settle_ns", 10**18), ("repeat", 10**11)])
def test_resume_refuses_a_recorded_plan_out_of_range(tmp_path, key, value):
    """--resume reuses the recorded plan: a plan no run could have written (hand-edited, corrupted) is refused, not run."""
    out = tmp_path / "r"
    run(FIFO80, out, FakeBackend({"default": Act(signals=1)}))
    doc = json.loads((out / "results.json").read_text())
    doc["plan"][key] = value
    (out / "results.json").write_text(json.dumps(doc))
    backend = FakeBackend({})
    ns = _run_parser().parse_args([FIFO80, "--resume", str(out), "--quiet", "--no-plots"])
    with pytest.raises(ScenarioError, match=f"plan.{key}"):
        run_scenario(load_scenario(FIFO80), RunOptions.from_namespace(ns, env={}), backend)
    assert backend.ran == []
    done = run_cli(FIFO80, "--resume", str(out), "--quiet")  # as a user sees it: one line, exit 2
    assert done.code == 2 and f"plan.{key}" in done.err and "Traceback" not in done.err, done.err


class _CollectorWatch(FakeBackend):
    """Notes whether Python's cyclic collector was on while each cell ran."""

    def __init__(self, acts: dict[str, Act]):
        super().__init__(acts)
        self.collector_on: list[bool] = []

    def run_cell(self, cell, folder, start, options):
        self.collector_on.append(gc.isenabled())
        return super().run_cell(cell, folder, start, options)


@pytest.mark.parametrize(
    "act", [Act(), Act(oserror=28), Act(dies=True)], ids=["cells run", "a cell's files cannot be made", "a cell raises"]
)
def test_the_cyclic_collector_is_off_while_cells_run_and_on_again_after(tmp_path, act):
    assert gc.isenabled()
    backend = _CollectorWatch({FIFO_CELLS[1]: act})
    if act.dies:  # an exception out of the cell (here a BaseException, as KeyboardInterrupt is) passes through the pause
        with pytest.raises(Died):
            run(MATRIX, tmp_path / "r", backend)
    else:
        run(MATRIX, tmp_path / "r", backend)
    assert backend.collector_on and not any(backend.collector_on)
    assert gc.isenabled(), "the run left Python's collector off"


def test_a_run_stopped_before_any_cell_the_baseline_holds_finished_exits_130_without_a_comparison(tmp_path, capsys):
    """A CI job cancelled in its first cell is a stopped run (130), not invalid input (2): the baseline was fine."""
    run(MATRIX, tmp_path / "base", FakeBackend(preempted_other()), "--duration", "1s", "--shard", "2/2")
    base = json.loads((tmp_path / "base" / "results.json").read_text())
    first = FIFO_CELLS[0]
    assert first not in [c["id"] for c in base["cells"]], "the baseline holds the first cell: this test proves nothing"
    backend = FakeBackend({**preempted_other(), first: Act(signals=1)})
    code, results = run(MATRIX, tmp_path / "r", backend, "--duration", "1s", "--baseline", str(tmp_path / "base"))
    assert code == 130 and results["status"] == "interrupted"
    assert "no comparison was made" in capsys.readouterr().err
    assert os.path.exists(tmp_path / "r" / "report.md")


def test_a_drawn_shuffle_seed_is_printed_at_the_start_so_the_order_can_be_run_again(tmp_path, capsys):
    """`--shuffle` alone draws a seed; printed on the terminal before the first cell, it is the one results.json records."""
    backend = FakeBackend(preempted_other())
    _, results = run(MATRIX, tmp_path / "r", backend, "--repeat", "2", "--shuffle")
    seed = results["plan"]["shuffle_seed"]
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == f"shuffled with seed {seed}: --shuffle {seed} runs the cells in this order again", lines[:3]
    again = FakeBackend(preempted_other())
    run(MATRIX, tmp_path / "s", again, "--repeat", "2", "--shuffle", str(seed))
    assert again.ran == backend.ran
    assert "shuffled with seed" not in capsys.readouterr().out, "a seed the user gave is not said back"


def _no_space(path: object = None, *args: object, **kwargs: object) -> None:
    """os.makedirs, os.fsync or os.write on a full disk."""
    raise OSError(errno.ENOSPC, "No space left on device", path if isinstance(path, str) else None)


@pytest.mark.parametrize("where", ["the --out folder", "the first results.json"])
def test_a_full_disk_before_the_first_cell_is_a_run_error_not_invalid_input(tmp_path, monkeypatch, where):
    """The command was right and runs once there is room: exit 4, as a disk that fills later (it once was 2)."""
    from runner import outdir
    from runner.results import files

    monkeypatch.setattr(*((outdir.os, "makedirs") if where == "the --out folder" else (files.os, "fsync")), _no_space)
    backend = FakeBackend(preempted_other())
    with pytest.raises(RunnerError) as caught:
        run(MATRIX, tmp_path / "r", backend)
    assert caught.value.exit_code == 4 and backend.ran == []
    said = str(caught.value)
    named = tmp_path / "r" if where == "the --out folder" else tmp_path / "r" / "results.json"
    assert f" {named}: No space left on device; the disk is full: free some space" in said and "\n" not in said


def test_a_journal_line_a_full_disk_refused_stops_the_run_keeping_every_cell_before_it(tmp_path, monkeypatch, capsys):
    from runner.results import journal

    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)  # a large run: cells are journaled, not rewritten
    real_open = journal.os.open
    opened = []

    def full_at_the_second_line(path, *args):  # os.open is everyone's: only the journal's opens are counted
        if path.endswith("cells.jsonl"):
            opened.append(path)
            if len(opened) == 2:
                raise OSError(errno.ENOSPC, "No space left on device", path)
        return real_open(path, *args)

    monkeypatch.setattr(journal.os, "open", full_at_the_second_line)
    out = tmp_path / "r"
    backend = FakeBackend(preempted_other())
    code, results = run(MATRIX, out, backend)
    assert code == 4 and len(opened) == 2 and backend.ran == FIFO_CELLS[:3], "no journal line refused: this test proves nothing"
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said.startswith(f"runner: cannot write {out / 'cells.jsonl'}: No space left on device; the run stopped.")
    assert said.endswith(f"free some space, then finish the run with --resume {out}")
    kept = [c["id"] for c in results["cells"]]
    assert kept == FIFO_CELLS[:2] and results["status"] == "error", "the cells rewritten or journaled before it are all kept"
    monkeypatch.setattr(journal.os, "open", real_open)  # space freed
    backend = FakeBackend(preempted_other())
    code, results = resume(MATRIX, out, backend)
    assert code == 0 and backend.ran == FIFO_CELLS[2:] + [OTHER] and [c["id"] for c in results["cells"]] == FIFO_CELLS + [OTHER]


def test_a_samples_file_a_full_disk_refused_is_the_file_named(tmp_path, monkeypatch, capsys):
    """Its writes name no file: the run's last line once said results.json could not be written."""
    from runner.results import samplesfile

    def compressed_rows_refused(self: samplesfile.SamplesWriter) -> None:  # gzip's write fails as a file's does: naming nothing
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(samplesfile.SamplesWriter, "_flush", compressed_rows_refused)
    out = tmp_path / "r"
    code, results = run(MATRIX, out, FakeBackend(preempted_other()))
    assert code == 4 and [c["status"] for c in results["cells"]] == ["error"]
    samples = out / "cells" / FIFO_CELLS[0] / "samples.csv.gz"
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said.startswith(f"runner: cannot write {samples}: No space left on device; the run stopped."), said
    assert f"could not be written to {samples}: No space left on device" in results["cells"][0]["reason"]


def test_plots_a_full_disk_refused_leave_the_report_and_junit_and_exit_4(tmp_path, monkeypatch):
    """A plot is never worth the report, but a full disk is no bug in the runner (as the report once said) and no pass."""
    from runner.report import plots

    monkeypatch.setattr(plots, "write_atomic", _no_space)
    out, junit = tmp_path / "r", tmp_path / "junit.xml"
    ns = _run_parser().parse_args([MATRIX, "--out", str(out), "--quiet", "--settle", "0", "--junit", str(junit)])
    with pytest.raises(RunnerError) as caught:
        run_scenario(load_scenario(MATRIX), RunOptions.from_namespace(ns, env={}), FakeBackend(preempted_other()))
    assert caught.value.exit_code == 4
    assert str(caught.value).startswith(f"runner: cannot write the plot {out / 'plots'}/") and "free some space" in str(caught.value)
    report = (out / "report.md").read_text()
    assert "Plots skipped: drawing them failed (runner: cannot write the plot" in report and "a bug in the runner" not in report
    assert junit.exists() and json.loads((out / "results.json").read_text())["status"] == "passed"
