"""`runner merge`: shards become one results file and one report; mixed inputs are refused."""

from __future__ import annotations

import copy
import errno
import json
import os
from pathlib import Path

import pytest
from conftest import run_cli
from hypothesis import given, settings
from hypothesis import strategies as st
from reportdata import MATRIX, matrix

from runner.results.document import Status
from runner.results.files import SLUG_MAX, cell_dir, slug
from runner.results.read import load


def split(tmp_path, parts):
    """Write the recorded matrix as shards: parts is a list of cell index lists."""
    out = []
    full = matrix()
    for n, idx in enumerate(parts):
        doc = copy.deepcopy(full)
        doc.cells = [doc.cells[i] for i in idx]
        doc.cell_ids = [c.id for c in doc.cells]  # what a shard's run is asked for
        doc.shard = f"{n + 1}/{len(parts)}"
        folder = tmp_path / f"shard-{n + 1}"
        folder.mkdir()
        for cell in doc.cells:  # carry the samples over, as a CI artifact would
            src = os.path.join(MATRIX, cell.samples_file)
            dst = folder / cell.samples_file
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.write_bytes(Path(src).read_bytes())
        doc.save(str(folder / "results.json"))
        out.append(str(folder))
    return out


def test_a_samples_file_a_full_disk_refused_is_named_and_exits_4(tmp_path, monkeypatch):
    """shutil's copy named no file when the write failed: the message once ended in `results :` and nothing else."""
    from runner import safefs

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")  # as the kernel says it: no file named

    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    monkeypatch.setattr(safefs.os, "fsync", no_space)  # the first file the merge writes is the first samples file
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"), "--no-plots")
    assert done.code == 4 and "Traceback" not in done.err, done.err
    target = tmp_path / "merged" / "cells" / "policy=fifo,priority=10" / "samples.csv.gz"
    assert done.err.startswith(f"runner: cannot write the merged results {target}: No space left on device; the disk is full"), done.err
    assert not (tmp_path / "merged" / "results.json").exists()


def test_merged_shards_equal_the_full_run(tmp_path):
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"), "--no-plots")
    assert done.code == 0, done.err
    merged, full = load(str(tmp_path / "merged")), matrix()
    assert [c.id for c in merged.cells] == [c.id for c in full.cells]  # matrix order, not shard order
    assert [c.threads for c in merged.cells] == [c.threads for c in full.cells]
    assert [c.expectations for c in merged.cells] == [c.expectations for c in full.cells]
    assert merged.merged_from == [os.path.join(s, "results.json") for s in shards]
    for cell in merged.cells:
        assert os.path.exists(merged.samples_path(cell))  # the merged folder stands on its own
    report = (tmp_path / "merged" / "report.md").read_text()
    assert "## Matrix summary" in report and "| Merged from" in report


def test_a_missing_shard_is_a_warning_and_the_report_says_so(tmp_path):
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    done = run_cli("merge", shards[0], "--out", str(tmp_path / "merged"), "--no-plots")
    assert done.code == 0
    assert "2 cell(s) of the matrix are in no input: policy=fifo,priority=80, policy=rr,priority=80" in done.err
    assert ", 2 not run" in (tmp_path / "merged" / "report.md").read_text()


@pytest.mark.parametrize("status", ["running", "error"])
def test_a_shard_whose_run_did_not_finish_makes_the_merge_an_error(tmp_path, status):
    """A shard killed outright (status running) or stopped by an error, or lacking cells it was asked for, is no pass."""
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    killed = load(shards[1])
    killed.status, killed.cells = status, killed.cells[:1]  # the runner died during its second cell
    killed.save(os.path.join(shards[1], "results.json"))
    junit = tmp_path / "merged.xml"
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"), "--no-plots", "--junit", str(junit))
    assert done.code == 4, done.err
    assert f"{shards[1]}/results.json: " in done.err and ("1 of its 2 cell runs" in done.err or "1 of the 2 cell runs" in done.err)
    assert load(str(tmp_path / "merged")).status == "error"
    xml = junit.read_text()
    assert 'errors="1"' in xml and "not run: the run ended before it" in xml


def test_a_merge_merged_again_with_the_last_shard_is_whole(tmp_path):
    """A merge's cell_ids are the whole matrix: merged again, it is not taken for a run that lacks cells."""
    shards = split(tmp_path, [[0, 2], [4], [1, 3]])
    first = run_cli("merge", shards[0], shards[1], "--out", str(tmp_path / "m12"), "--no-plots")
    assert first.code == 0, first.err
    done = run_cli("merge", str(tmp_path / "m12"), shards[2], "--out", str(tmp_path / "m123"), "--no-plots")
    assert done.code == 0 and "the merged run is an error" not in done.err, done.err
    assert load(str(tmp_path / "m123")).status == "passed"


def test_a_shard_asked_to_stop_is_interrupted_not_an_error(tmp_path):
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    stopped = load(shards[1])
    stopped.status, stopped.cells = "interrupted", stopped.cells[:1]
    stopped.save(os.path.join(shards[1], "results.json"))
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"), "--no-plots")
    assert done.code == 130 and "merged run is an error" not in done.err, done.err


def test_duplicate_cells_are_refused(tmp_path):
    shards = split(tmp_path, [[0, 1], [1, 2]])
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"))
    assert done.code == 2
    assert "cells.policy=fifo,priority=80: cell is also in" in done.err
    assert not (tmp_path / "merged" / "results.json").exists()


def merge_edited(tmp_path, parts, edit, *extra):
    """Split the recorded run into shards, let `edit` change the last shard's document, merge them."""
    shards = split(tmp_path, parts)
    doc = load(shards[-1])
    edit(doc)
    doc.save(os.path.join(shards[-1], "results.json"))
    return run_cli("merge", *shards, "--out", str(tmp_path / "merged"), *extra)


def test_mixed_scenarios_are_refused(tmp_path):
    done = merge_edited(tmp_path, [[0], [1]], lambda doc: setattr(doc.scenario, "name", "other_scenario"))
    assert done.code == 2 and "is 'other_scenario', but" in done.err


def test_mixed_specs_are_refused(tmp_path):
    def edit(doc):
        doc.cells[0].spec_hash = "ffffffffffffffff"
        doc.cells[0].repeat = 1  # not a duplicate run: a second repeat, but of a different spec
        doc.plan.repeat = 2
        doc.cells.insert(0, doc.cells[0].model_copy(update={"repeat": 0}))  # the run's first repeat, as it would hold it

    done = merge_edited(tmp_path, [[0], [0]], edit)
    assert done.code == 2 and "ran a different scenario spec than in" in done.err


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("duration_ns", 300_000_000, "ran its cells for another --duration"),
        ("scenario_hash", "ffffffffffffffff", "ran another version of the scenario file"),
        ("expect_hash", "ffffffffffffffff", "judged its cells by other expectations"),
        ("trace", False, "traced the scheduler where the other did not (--no-trace)"),
        ("dma_latency_us", 10, "held /dev/cpu_dma_latency otherwise (--dma-latency)"),
        ("repeat", 2, "ran each cell another number of times (--repeat)"),
    ],
)
def test_shards_of_different_runs_are_refused(tmp_path, key, value, words):
    """Shards at 200 ms and 300 ms, or of a scenario edited between jobs, once merged into one run that said neither."""

    def edit(doc):
        setattr(doc.plan, key, value)
        if key == "repeat":  # every cell run twice, as such a shard holds them
            doc.cells += [c.model_copy(update={"repeat": 1}) for c in doc.cells]

    def recorded(doc):  # both shards record the hashes and the trace, as this runner writes them
        doc.plan.scenario_hash = doc.plan.scenario_hash or "0123456789abcdef"
        doc.plan.expect_hash = doc.plan.expect_hash or "0123456789abcdef"
        doc.plan.trace = True if doc.plan.trace is None else doc.plan.trace

    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    for n, shard in enumerate(shards):
        doc = load(shard)
        recorded(doc)
        if n == 1:
            edit(doc)
        doc.save(os.path.join(shard, "results.json"))
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"))
    assert done.code == 2 and f"plan.{key}: {words}" in done.err, done.err
    assert not (tmp_path / "merged" / "results.json").exists()


def test_merge_exit_code_follows_the_cells(tmp_path):
    def fail(doc):
        doc.cells[0].status, doc.status = Status.FAILED, "failed"  # as the run would have written it

    done = merge_edited(tmp_path, [[0], [1]], fail, "--no-plots")
    assert done.code == 1


# ---------------------------------------------------------------- cell folder names


SAFE_NAME = r"[A-Za-z0-9_.=,+~-]+"


@settings(max_examples=300, derandomize=True, database=None)
@given(st.lists(st.text(max_size=200), min_size=2, max_size=6, unique=True))
def test_cell_folder_names_are_injective_safe_and_bounded(ids):
    import re

    names = [slug(i) for i in ids]
    assert len(set(names)) == len(ids), dict(zip(ids, names))
    for i, name in zip(ids, names):
        assert re.fullmatch(SAFE_NAME, name) and not name.startswith("."), name
        assert len(name) <= SLUG_MAX + 13
        assert slug(i) == name  # deterministic


@given(st.from_regex(r"[A-Za-z0-9_=,+-][A-Za-z0-9_.=,+-]{0,119}", fullmatch=True))
@settings(max_examples=100, derandomize=True, database=None)
def test_a_safe_id_is_its_own_folder_name(cell_id):
    assert slug(cell_id) == cell_id


def test_matrix_values_that_read_alike_get_their_own_folders():
    ids = ["v=a/b", "v=a_b", "v=a:b", "..", ".", "", "x" * 200, "x" * 201]
    assert len({cell_dir(i, 0, False) for i in ids}) == len(ids)
    assert slug("v=a_b") == "v=a_b" and slug("v=a/b").startswith("v=a_b~")
    assert slug("policy=fifo,priority=80") == "policy=fifo,priority=80"  # recorded runs keep their folders


def test_cells_whose_ids_read_alike_keep_their_own_samples_when_merged(tmp_path):
    shards = split(tmp_path, [[0], [1]])
    for shard, new_id in zip(shards, ["v=a/b", "v=a:b"]):
        doc = load(shard)
        doc.cells[0].id = new_id
        doc.matrix_cells = doc.cell_ids = []
        doc.save(os.path.join(shard, "results.json"))
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"), "--no-plots")
    assert done.code == 0, done.err
    merged = load(str(tmp_path / "merged"))
    paths = [merged.samples_path(c) for c in merged.cells]
    assert len(set(paths)) == 2 and all(p and os.path.exists(p) for p in paths)
    full = matrix()
    for cell, source in zip(merged.cells, full.cells[:2]):
        with open(merged.samples_path(cell), "rb") as a, open(full.samples_path(source), "rb") as b:
            assert a.read() == b.read()


# ---------------------------------------------------------------- samples paths stay inside the results folder


def _with_samples_file(tmp_path, value):
    shards = split(tmp_path, [[0], [1]])
    path = os.path.join(shards[1], "results.json")
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    data["cells"][0]["samples_file"] = value
    with open(path, "w", encoding="utf-8") as handle:
        json.dump(data, handle)
    return shards, data["cells"][0]["id"]


@pytest.mark.parametrize("value", ["/etc/passwd", "../../x", "cells/../../outside.csv.gz"])
def test_merge_refuses_samples_paths_outside_the_results_folder(tmp_path, value):
    shards, cell_id = _with_samples_file(tmp_path, value)
    for argv in (("merge", *shards, "--out", str(tmp_path / "merged")), ("report", shards[1], "-o", "-"), ("compare", MATRIX, shards[1])):
        done = run_cli(*argv)
        assert done.code == 2, (argv, done.err)
        where = os.path.join(shards[1], "results.json")
        assert f"{where}:1:1: cells.{cell_id}.samples_file: {value!r}" in done.err
        assert f"expected a path inside {os.path.abspath(shards[1])}" in done.err
        assert "Traceback" not in done.err
    assert not os.path.exists(tmp_path / "merged" / "results.json")


def test_merge_refuses_a_samples_file_that_is_a_symlink_out_of_the_folder(tmp_path):
    shards = split(tmp_path, [[0], [1]])
    cell = load(shards[1]).cells[0]
    target = os.path.join(shards[1], cell.samples_file)
    os.unlink(target)
    os.symlink("/etc/passwd", target)
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"))
    assert done.code == 2 and f"cells.{cell.id}.samples_file:" in done.err and "through a symlink" in done.err
    assert not any(
        "passwd" in Path(d, f).read_text(errors="replace") for d, _, fs in os.walk(tmp_path / "merged") for f in fs if f.endswith(".gz")
    )


def test_shards_of_one_file_on_machines_of_different_sizes_agree_on_its_hash(tmp_path):
    """The spec of a `count: cpus` cell differs with the machine; the file's hash, which merge holds shards to, does not."""
    from runner.scenario import limits as lim
    from runner.scenario.loader import load_scenario

    path = tmp_path / "s.yaml"
    path.write_text("name: x\nprocesses:\n  - name: app\n    threads: [{name: t, count: cpus}]\n")
    small = load_scenario(str(path), lim.MachineLimits(cpus=(0, 1)))
    large = load_scenario(str(path), lim.MachineLimits(cpus=(0, 1, 2, 3)))
    assert small.cells[0].spec_hash != large.cells[0].spec_hash
    assert small.source_hash == large.source_hash != ""
    path.write_text(path.read_text().replace("count: cpus", "count: 3"))
    assert load_scenario(str(path), lim.MachineLimits(cpus=(0, 1))).source_hash != small.source_hash


def test_a_merge_of_an_unfinished_shard_is_never_green_against_a_baseline(tmp_path):
    """A shard killed before its first cell (running, no cells) merged, then compared: `✅ No regression in 3 cells`, exit 0.

    A merge asks for no cell runs of its own, so its incompleteness is its status: merge --baseline,
    compare and report --baseline all say it is incomplete and exit 4, never with a ✅.
    """
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    killed = load(shards[1])
    killed.status, killed.cells = "running", []
    killed.save(os.path.join(shards[1], "results.json"))
    merged = str(tmp_path / "m1")
    done = run_cli("merge", *shards, "--out", merged, "--no-plots", "--baseline", MATRIX)
    line = next(line for line in done.out.splitlines() if line.startswith("compared with"))
    assert done.code == 4 and "✅" not in line, (line, done.err)
    assert "the merge's inputs did not finish (results.json says error): 2 of its 5 cells are missing" in line, line
    compared = run_cli("compare", MATRIX, merged)
    headline = next(line for line in compared.out.splitlines() if "This run is incomplete" in line)
    assert compared.code == 4 and "✅" not in headline, (compared.out, compared.err)
    reported = run_cli("report", merged, "--baseline", MATRIX, "--no-plots")
    assert reported.code == 4 and "✅" not in next(line for line in reported.out.splitlines() if line.startswith("compared with"))
