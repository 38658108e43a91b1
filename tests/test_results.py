"""The results document: one typed declaration, runner.results/2 in integer ns, the upgrade from /1, its JSON Schema."""

from __future__ import annotations

import copy
import json
import os
import re
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
from conftest import REPO, run_cli
from hypothesis import given, settings
from hypothesis import strategies as st
from reportdata import DATA, MATRIX, MEMORY, matrix

from runner.errors import ScenarioError
from runner.figures import REGISTRY
from runner.report import markdown as report
from runner.report.compare import compare
from runner.results.document import SCHEMA, CellResult, RunDocument, Status, ThreadResult, Verdict, results_schema, thread_label
from runner.results.legacy import upgrade_v1
from runner.results.pstable import ThreadRow
from runner.results.read import load
from runner.results.threadfigures import Faults, Involuntary, Spread, ThreadFigures, Voluntary
from runner.scenario.model import Metric, Policy
from runner.scenario.plan import Settings

RUNS = ["memory_lock", "policy_matrix"]  # the runs recorded in the first schema (the others are in the current one)
V1 = {name: json.loads(Path(DATA, name, "results.json").read_text(encoding="utf-8")) for name in RUNS}


def saved(doc: RunDocument, folder: Path) -> Path:
    """`doc` written as a results folder (with the recorded samples beside it), as a run writes it."""
    shutil.copytree(MATRIX if doc.name == "policy_matrix" else MEMORY, folder, dirs_exist_ok=True)
    doc.save(str(folder / "results.json"))
    return folder


def edited(tmp_path: Path, change) -> str:
    """The recorded matrix saved as /2, its JSON changed by `change(data)`; the results file's path."""
    folder = saved(matrix(), tmp_path / "run")
    path = folder / "results.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    change(data)
    path.write_text(json.dumps(data), encoding="utf-8")
    return str(path)


def refusal(path: str) -> str:
    with pytest.raises(ScenarioError) as err:
        load(path)
    return str(err.value)


# ---------------------------------------------------------------- /1 files load, upgraded


def test_recorded_v1_files_are_kept_as_they_are():
    assert {data["schema"] for data in V1.values()} == {"runner.results/1"}


@pytest.mark.parametrize("name", RUNS)
def test_a_v1_file_round_trips_through_v2_unchanged(tmp_path, name):
    old = load(os.path.join(DATA, name))
    old.save(str(tmp_path / "results.json"))
    text = (tmp_path / "results.json").read_text(encoding="utf-8")
    assert json.loads(text)["schema"] == SCHEMA == "runner.results/2"
    again = load(str(tmp_path))
    assert again.cells == old.cells
    assert again.model_dump(exclude={"folder", "source"}) == old.model_dump(exclude={"folder", "source"})
    again.save(str(tmp_path / "again.json"))
    assert (tmp_path / "again.json").read_text(encoding="utf-8") == text  # saving is deterministic


@pytest.mark.parametrize("name", RUNS)
def test_an_old_file_and_its_upgrade_give_the_same_report_and_comparison(tmp_path, name):
    old = load(os.path.join(DATA, name))
    new = load(str(saved(old, tmp_path / "run")))
    assert report.render_run(new) == report.render_run(old)
    assert report.render_comparison(compare(old, new), "b", "n") == report.render_comparison(compare(old, old), "b", "n")
    assert compare(old, new).regressions == 0


def test_upgrade_converts_every_duration_to_integer_ns():
    data = upgrade_v1(V1["policy_matrix"])
    cell, old = data["cells"][0], V1["policy_matrix"]["cells"][0]
    main = cell["threads"][0]["figures"]
    assert main["latency_ns"] == {"min": 26316, "p50": 29923, "p90": 31660, "p99": 58366, "p999": 58366, "max": 58366}
    assert main["callback_wall_ns"]["min"] == 40004350 and old["threads"][0]["callback_wall_us"]["min"] == 40004.35
    assert cell["threads"][1]["figures"]["latency_ns"] is None
    latency = next(v for v in cell["expectations"] if v["metric"] == "latency.p99")
    assert latency["measured"] == 58366 and "unit" not in latency  # was 58.366 (us)
    invol = next(v for v in cell["expectations"] if v["metric"] == "involuntary.per_callback_mean")
    assert invol["measured"] == 0.0  # a count keeps its unit
    assert cell["duration_ns"] == 1_331_000_000 and "duration_s" not in cell
    assert cell["overhead_ns"] == {"start_to_first_callback": 224_300_000, "last_callback_to_exit": 147_100_000}
    assert data["plan"]["settle_ns"] == 200_000_000 and "settle_s" not in data["plan"]
    assert data["machine"]["rt_throttling"] == {"runtime_ns": 950_000_000, "period_ns": 1_000_000_000, "enabled": True}
    assert cell["thread_table"][0]["policy"] == 1 and cell["thread_table"][1]["policy"] == 0  # FF, TS
    assert data == upgrade_v1(V1["policy_matrix"]) and V1["policy_matrix"]["schema"] == "runner.results/1"  # pure


@settings(max_examples=300, derandomize=True, database=None)
@given(st.integers(min_value=0, max_value=10**15))
def test_a_v1_microsecond_value_becomes_its_exact_ns(ns):
    data = copy.deepcopy(V1["policy_matrix"])
    data["cells"][0]["threads"][0]["latency_us"]["p99"] = ns / 1000  # how /1 wrote it: us, to 3 decimals
    assert upgrade_v1(data)["cells"][0]["threads"][0]["figures"]["latency_ns"]["p99"] == ns


def test_a_v1_spread_with_a_figure_that_was_not_a_number_is_no_spread(tmp_path):
    data = copy.deepcopy(V1["policy_matrix"])
    data["cells"][0]["threads"][0]["latency_us"]["p99"] = None  # /1 wrote NaN as null
    folder = tmp_path / "run"
    shutil.copytree(MATRIX, folder)
    (folder / "results.json").write_text(json.dumps(data), encoding="utf-8")
    assert load(str(folder)).cells[0].threads[0].figures.latency_ns is None


def test_v1_problems_name_v1_keys(tmp_path):
    data = copy.deepcopy(V1["policy_matrix"])
    data["cells"][0]["threads"][0]["latency_us"]["p99"] = "fast"
    path = tmp_path / "results.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    assert "cells[0].threads[0].latency_us.p99: input should be a valid number" in refusal(str(path))


# ---------------------------------------------------------------- /2 files: strict, tolerant of newer keys


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda d: d["cells"][0]["threads"][0]["figures"].update(callbacks="10"),
            "cells[0].threads[0].figures.callbacks: input should be a valid integer; got '10'",
        ),
        (
            lambda d: d["cells"][0]["threads"][0]["figures"].update(callbacks=True),
            "cells[0].threads[0].figures.callbacks: input should be a valid integer; got True",
        ),
        (
            lambda d: d["cells"][0]["threads"][0]["figures"]["latency_ns"].update(p99=58.366),
            "cells[0].threads[0].figures.latency_ns.p99: input should be a valid integer; got 58.366",
        ),
        (
            lambda d: d["cells"][0]["threads"][0]["figures"]["latency_ns"].update(p99=2**64),
            "cells[0].threads[0].figures.latency_ns.p99: 18446744073709551616 is out of range; expected a 64-bit integer",
        ),
        (lambda d: d["cells"][0]["threads"][0]["figures"].pop("faults"), "cells[0].threads[0].figures.faults: field required"),
        (
            lambda d: d["cells"][0]["threads"][0]["figures"]["faults"].update(extra=1),
            "cells[0].threads[0].figures.faults.extra: extra inputs are not permitted",
        ),
        (lambda d: d["cells"][0]["expectations"][0].update(metric="latency.p98"), "did you mean 'latency.p99'"),
        (lambda d: d["cells"][0].update(duration_ns=1.5), "cells[0].duration_ns: input should be a valid integer"),
        (lambda d: d["cells"][0].update(status="splendid"), "cells[0].status: input should be"),
        (lambda d: d["cells"][0]["threads"][0]["requested"].update(cpus="0-"), "cells[0].threads[0].requested.cpus: cannot read CPUs"),
        (
            lambda d: d["cells"][0]["thread_table"][0].update(cpus=[0, "1"]),
            "cells[0].thread_table[0].cpus[1]: input should be a valid integer",
        ),
        (lambda d: d["plan"].update(settle_ns=-1), "plan.settle_ns: input should be greater than or equal to 0"),
        (lambda d: d.update(status="done"), "status: expected one of running, error"),
        (lambda d: d.update(schema="runner.results/3"), "runner.results/3 is a newer results format than this runner"),
        (
            lambda d: d.update(schema="runner.results/0"),
            "expected a runner.results/2 (or runner.results/1) results file, got 'runner.results/0'",
        ),
    ],
)
def test_v2_files_are_read_strictly_with_one_line_problems(tmp_path, change, message):
    path = edited(tmp_path, change)
    text = refusal(path)
    assert message in text, text
    assert all(line.startswith(path + ":1:1: ") for line in text.splitlines()), text
    done = run_cli("report", path, "-o", "-")
    assert done.code == 2 and message in done.err and "Traceback" not in done.err


def test_a_newer_schema_is_refused_saying_so(tmp_path):
    path = edited(tmp_path, lambda d: d.update(schema="runner.results/7", figures_v7={"x": 1}))
    done = run_cli("compare", MATRIX, path)
    assert done.code == 2
    assert "schema: runner.results/7 is a newer results format than this runner" in done.err
    assert "read it with a newer runner" in done.err


def test_keys_a_newer_runner_adds_are_tolerated_and_dropped(tmp_path):
    def add(d):
        d["added_by_a_newer_runner"] = {"x": 1}
        d["machine"]["numa_nodes"] = 2
        d["plan"]["warmup_ns"] = 5
        d["cells"][0]["energy_uj"] = 7
        d["cells"][0]["threads"][0]["stack_bytes"] = 8192
        d["cells"][0]["background"][0]["nice"] = 19

    path = edited(tmp_path, add)
    doc = load(path)
    assert doc.cells == matrix().cells
    doc.save(path)
    text = Path(path).read_text(encoding="utf-8")
    for key in ("added_by_a_newer_runner", "numa_nodes", "warmup_ns", "energy_uj", "stack_bytes", '"nice": 19'):
        assert key not in text


def test_a_thread_key_in_a_file_is_derived_not_read(tmp_path):
    path = edited(tmp_path, lambda d: d["cells"][0]["threads"][0].update(key="something else"))
    assert load(path).cells[0].threads[0].key == "minimal_schedul[0]/minimal_schedul (main)"


def test_nan_is_never_written_and_never_read(tmp_path):
    doc = matrix()
    cell = doc.cells[0]
    cell.expectations[0] = cell.expectations[0].model_copy(update={"measured": float("nan")})
    doc.save(str(tmp_path / "results.json"))
    text = (tmp_path / "results.json").read_text(encoding="utf-8")
    assert "NaN" not in text and json.loads(text)["cells"][0]["expectations"][0]["measured"] is None
    (tmp_path / "results.json").write_text(text.replace('"measured": null', '"measured": NaN', 1), encoding="utf-8")
    assert "NaN is not a number" in refusal(str(tmp_path))


def test_samples_paths_stay_confined_in_v2_files(tmp_path):
    path = edited(tmp_path, lambda d: d["cells"][0].update(samples_file="../../etc/passwd"))
    assert "cells.policy=fifo,priority=10.samples_file: '../../etc/passwd' leaves the results folder" in refusal(path)


# ---------------------------------------------------------------- the records, as the evaluation core builds them


def figures(p99: int = 58_366) -> ThreadFigures:
    spread = Spread(min=1, p50=2, p90=3, p99=p99, p999=p99, max=p99)
    return ThreadFigures(
        callbacks=10,
        missed_releases=0,
        involuntary=Involuntary(total=0, per_callback_mean=0.0, per_callback_max=0, callbacks_with_any=0),
        voluntary=Voluntary(total=10),
        latency_ns=spread,
        callback_wall_ns=spread,
        faults=Faults(minor=0, major=0),
        cpus_seen=(0,),
        complete=True,
    )


def built_cell() -> CellResult:
    """A cell made with the keywords the evaluation core uses (the contract with it)."""
    fifo = Settings(Policy.FIFO, 80, 0, None)
    thread = ThreadResult(
        process="p",
        instance=0,
        index=0,
        name="main",
        pid=10,
        tid=10,
        work="periodic 1ms",
        periodic=True,
        requested=fifo,
        applied=Settings(Policy.FIFO, 80, 0, (0, 1)),
        degraded=[],
        figures=figures(),
    )
    verdict = Verdict(
        thread=thread_label("p", 0, 0, "main", show_instance=False),
        metric=Metric("latency.p99"),
        limit="<= 2ms",
        measured=58_366,
        passed=True,
        note="",
    )
    row = ThreadRow(pid=10, tid=10, comm="p", policy=1, rtprio=80, nice=0, psr=1, prio=-81, cpus=(0, 1), voluntary=3, involuntary=0)
    return CellResult(
        id="c",
        matrix={"x": 1},
        spec_hash="h",
        status=Status.PASSED,
        spec={"name": "s"},
        reason="",
        started_at="2026-01-01T00:00:00+00:00",
        duration_ns=1_250_000_000,
        thread_table=[row],
        threads=[thread],
        expectations=[verdict],
        background=[{"kind": "hog", "name": "hog", "pid": 11}],
        overhead_ns={"start_to_first_callback": 1_000, "last_callback_to_exit": None},
        samples_file="cells/c/samples.csv.gz",
        repeat=0,
    )


def test_records_built_by_keyword_are_stored_and_read_back_equal(tmp_path):
    cell = built_cell()
    assert cell.duration_ns == 1_250_000_000 and cell.duration_s == 1.25
    assert cell.expectations[0].metric == "latency.p99" and cell.expectations[0].figure.words == "wake-up latency p99"
    doc = RunDocument(
        scenario={"name": "s", "path": "s.yaml"},
        command=["runner", "s.yaml"],
        started_at="t",
        cell_ids=["c"],
        matrix_cells=["c"],
        plan={"repeat": 1, "settle_ns": 0},
        cells=[cell],
    )
    doc.save(str(tmp_path / "results.json"))
    stored = json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))["cells"][0]
    assert stored["duration_ns"] == 1_250_000_000
    assert stored["threads"][0]["requested"] == {"policy": "fifo", "priority": 80, "nice": 0, "cpus": "all"}
    assert stored["threads"][0]["applied"]["cpus"] == "0-1"
    assert stored["threads"][0]["figures"]["latency_ns"]["p99"] == 58_366
    assert stored["thread_table"][0]["cpus"] == "0-1" and stored["thread_table"][0]["prio"] == -81
    assert stored["expectations"][0] == {
        "thread": "p/main (main)",
        "metric": "latency.p99",
        "limit": "<= 2ms",
        "measured": 58_366,
        "passed": True,
        "note": "",
        "samples": None,  # how many values the figure stands on: not told, for a verdict built by hand
        "line": None,  # where the scenario declares it: none for a verdict built by hand
        "col": None,
    }
    again = load(str(tmp_path)).cells[0]
    assert again == cell
    assert again.threads[0].applied == Settings(Policy.FIFO, 80, 0, (0, 1))
    assert again.thread_table[0] == cell.thread_table[0]


@pytest.mark.parametrize(
    "make",
    [
        lambda: CellResult(id="c", spec_hash="h", status=Status.PASSED, overhead_s={}),
        lambda: Verdict(thread="t", metric="latency.p99", limit="x", measured=1, passed=True, unit="us"),
        lambda: RunDocument(tool_version="1"),
        lambda: RunDocument(plan={"repeat": 1, "settle_s": 0.5}),
        lambda: RunDocument(machine={"hostname": "h", "rt_throttling": {"runtime_us": 950000, "period_us": 1000000}}),
        lambda: CellResult(id="c", spec_hash="h", status=Status.PASSED, background=[{"kind": "hog", "comm": "hog"}]),
        lambda: CellResult(id="c", spec_hash="h", status=Status.PASSED, overhead_ns={"start_to_first_callback_s": 1}),
    ],
)
def test_a_misspelt_keyword_is_an_error_not_a_lost_field(make):
    with pytest.raises(TypeError, match="has no field"):
        make()


def test_a_misspelt_attribute_is_an_error_not_a_new_one():
    cell = CellResult(id="c", spec_hash="h", status=Status.PASSED)
    with pytest.raises(ValueError, match="duration"):
        cell.duration = 5
    with pytest.raises(ValueError, match="enabled_"):
        cell.overhead_ns.enabled_ = True
    assert '"duration":' not in cell.model_dump_json()


def test_an_unknown_figure_is_refused_with_a_suggestion():
    with pytest.raises(ValueError, match=r"did you mean 'latency\.p99'"):
        Verdict(thread="t", metric="latency.p98", limit="x", measured=1, passed=True)


def test_every_figure_of_the_registry_can_be_a_verdict_metric():
    for f in REGISTRY:
        assert Verdict(thread="t", metric=f.name, limit="x", measured=None, passed=False).figure is f


def test_thread_labels_have_one_form():
    assert thread_label("p", 2, 0, "main") == "p[2]/main (main)"
    assert thread_label("p", 2, 3, "w") == "p[2]/w #3"
    assert thread_label("p", 0, 3, "w", show_instance=False) == "p/w #3"
    t = built_cell().threads[0]
    assert t.key == thread_label(t.process, t.instance, t.index, t.name) and t.label(False) == "p/main (main)"


# ---------------------------------------------------------------- the JSON Schema


def test_results_schema_file_in_the_repository_is_current():
    with open(os.path.join(REPO, "results.schema.json"), encoding="utf-8") as handle:
        assert json.load(handle) == results_schema(), "regenerate with: runner schema --results > results.schema.json"


@pytest.mark.parametrize("name", RUNS)
def test_what_runner_writes_satisfies_the_schema(tmp_path, name):
    load(os.path.join(DATA, name)).save(str(tmp_path / "results.json"))
    jsonschema.validate(json.loads((tmp_path / "results.json").read_text(encoding="utf-8")), results_schema())


@pytest.mark.parametrize(
    "change",
    [
        lambda d: d["cells"][0]["threads"][0]["figures"]["latency_ns"].update(p99=58.366),
        lambda d: d["cells"][0]["expectations"][0].update(metric="latency.p98"),
        lambda d: d.update(schema="runner.results/1"),
        lambda d: d["cells"][0]["threads"][0]["figures"].pop("complete"),
    ],
)
def test_the_schema_refuses_what_the_reader_refuses(tmp_path, change):
    load(MATRIX).save(str(tmp_path / "results.json"))
    data = json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))
    jsonschema.validate(data, results_schema())
    change(data)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(data, results_schema())


def test_rt_throttling_is_stored_in_ns_from_the_kernels_microseconds():
    from runner.results.document import RtThrottling

    assert RtThrottling.from_sysctl(950_000, 1_000_000) == RtThrottling(runtime_ns=950_000_000, period_ns=1_000_000_000, enabled=True)
    assert RtThrottling.from_sysctl(-1, 1_000_000) == RtThrottling(runtime_ns=None, period_ns=1_000_000_000, enabled=False)
    assert RtThrottling.from_sysctl(None, None) == RtThrottling()


def test_a_negative_count_is_refused_where_it_is(tmp_path):
    from reportdata import MATRIX

    text = load(MATRIX).model_dump_json(by_alias=True).replace('"missed_releases":0', '"missed_releases":-1000000', 1)
    (tmp_path / "results.json").write_text(text)
    where = r"cells\[0\]\.threads\[0\]\.figures\.missed_releases"
    with pytest.raises(ScenarioError, match=where + ": input should be greater than or equal to 0"):
        load(str(tmp_path))


def test_a_cell_run_twice_and_a_run_better_than_its_cells_are_refused_at_once(tmp_path):
    from reportdata import MATRIX

    doc = load(MATRIX)
    doc.cells.append(doc.cells[0])
    doc.cells[1].status = Status.ERROR
    doc.save(str(tmp_path / "results.json"))
    with pytest.raises(ScenarioError) as caught:
        load(str(tmp_path))
    said = str(caught.value)
    assert f"cells.{doc.cells[0].id}: cell is in the file twice" in said
    assert "status: the run says passed, but a cell of it says error" in said


def test_a_finished_run_without_cells_it_was_asked_for_is_refused_but_a_merge_may_cover_part_of_the_matrix(tmp_path):
    from reportdata import MATRIX

    doc = load(MATRIX)
    doc.cells = doc.cells[:2]
    doc.save(str(tmp_path / "results.json"))
    with pytest.raises(ScenarioError, match="cells: the run says passed, but 3 of the 5 cell runs it was asked for are not in it"):
        load(str(tmp_path))
    doc.merged_from = ["shard-1/results.json"]
    doc.save(str(tmp_path / "results.json"))
    assert len(load(str(tmp_path)).cells) == 2


def test_a_report_of_results_given_on_standard_input_is_written_beside_the_file_or_refused_for_a_pipe(tmp_path):
    """`runner report /dev/stdin < results.json` once wrote /dev/report.md (as root)."""
    import subprocess
    import sys

    from reportdata import MATRIX

    shutil.copy(os.path.join(MATRIX, "results.json"), tmp_path / "results.json")
    cmd = [sys.executable, "-m", "runner", "report", "/dev/stdin", "--no-plots"]
    with open(tmp_path / "results.json", "rb") as handle:
        done = subprocess.run(cmd, stdin=handle, capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0 and (tmp_path / "report.md").exists(), done.stderr
    piped = subprocess.run(cmd, input=(tmp_path / "results.json").read_text(), capture_output=True, text=True, cwd=tmp_path)
    assert piped.returncode == 2 and "is not a file in a results folder (a pipe?)" in piped.stderr, piped.stderr


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda c: setattr(c.expectations[0], "passed", False), "says passed, but expectation"),
        (lambda c: setattr(c.threads[0], "degraded", ["fifo:80 requested, other applied"]), "says passed, but thread .* did not get"),
    ],
)
def test_a_cell_better_than_its_own_verdicts_is_refused(tmp_path, edit, words):
    """A hand-edited cell said ✅ passed beside its own ❌ FAIL, and merge exited 0 with a failing JUnit case."""
    doc = load(MATRIX)
    cell = next(c for c in doc.cells if c.status == Status.PASSED and c.expectations and c.threads)
    edit(cell)
    doc.save(str(tmp_path / "results.json"))
    with pytest.raises(ScenarioError, match=f"cells\\.{re.escape(cell.id)}\\.status: {words}"):
        load(str(tmp_path))


def test_a_threads_settings_are_stored_with_every_field_they_have():
    """results.document writes plan.Settings through a record of its own: a field added to one and not the other
    would be dropped from every results file, or read back as its default."""
    import dataclasses

    from runner.results.document import _settings_in, _settings_out, _SettingsRecord
    from runner.scenario.model import Policy
    from runner.scenario.plan import Settings

    assert list(_SettingsRecord.model_fields) == [f.name for f in dataclasses.fields(Settings)]
    deadline = Settings(Policy.DEADLINE, 0, 0, (1, 3), 2_000_000, 8_000_000, 10_000_000)
    assert _settings_in(_SettingsRecord.model_validate(_settings_out(deadline))) == deadline


# ---------------------------------------------------------------- what a file may cost to read


def limited_cli(*argv: str, memory: int = 1 << 30) -> subprocess.CompletedProcess[str]:
    """`runner ARGV` in a child process that may use at most `memory` bytes of address space (a runaway read fails, not the machine)."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    code = "import sys; from runner.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, preexec_fn=limit, timeout=300)


@pytest.mark.parametrize("command", ["report", "compare", "merge"])
def test_a_file_asking_for_more_cell_runs_than_any_run_is_refused_before_they_are_counted(tmp_path, command):
    """44 KB asking for 10^6 repeats of 2,000 cells: report, compare and merge took 7 to 9 GB to count its cell runs."""

    def ask(d):
        d["cell_ids"] = [f"c{i}" for i in range(2_000)]
        d["plan"]["repeat"] = 10**6

    path = edited(tmp_path, ask)
    argv = {"report": [path, "-o", "-"], "compare": [MATRIX, path], "merge": [path, "--out", str(tmp_path / "m")]}[command]
    done = limited_cli(command, *argv)
    assert done.returncode == 2, done.stderr
    assert f"{path}:1:1: plan.repeat: asks for 1,000,000 runs of each of 2,000 cells, 2,000,000,000 cell runs; no run asks" in done.stderr
    ask_less = edited(tmp_path / "fits", lambda d: d["plan"].update(repeat=200_000))  # 5 cells: 10^6 cell runs, as a run may ask
    assert "cell runs it was asked for are not in it" in refusal(ask_less)


@pytest.mark.parametrize("name", ["results.json", "cells.jsonl"])
def test_a_results_file_or_journal_past_the_size_cap_is_refused_before_it_is_read(tmp_path, name):
    path = Path(saved(matrix(), tmp_path / "run")) / name
    with open(path, "ab") as handle:
        handle.truncate((512 << 20) + 1)  # sparse: no disk, but read whole it was 512 MiB of bytes, then of text
    done = limited_cli("report", str(tmp_path / "run"), "-o", "-", memory=768 << 20)
    assert done.returncode == 2, done.stderr
    assert f"{path}:1:1: is larger than 512 MiB, the most a results file or journal may be" in done.stderr
