"""cyclictest's formats from a cell's histograms (pure), `runner report`'s options for them, and against a real cyclictest
where one is installed."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import pytest
from conftest import run_cli

from runner import histogram as hg
from runner.errors import UsageError
from runner.report.export import histogram_text, json_summary, pick_cell
from runner.results.document import CellResult, RunDocument, Status, ThreadHistograms, ThreadResult
from runner.results.threadfigures import Faults, Involuntary, Spread, ThreadFigures, Voluntary
from runner.scenario.plan import Settings

LATENCIES = [3_400, 3_900, 12_000, 250_000, 2_000_000]  # ns: 3 us twice, 12 us, 250 us (a wide bucket), 2 ms


def _cell(cell_id: str = "default") -> CellResult:
    hist = hg.from_values(LATENCIES)
    figures = ThreadFigures(
        callbacks=5,
        missed_releases=0,
        involuntary=Involuntary(total=0),
        voluntary=Voluntary(total=5),
        latency_ns=Spread(min=3_400, p50=12_000, p90=2_000_000, p99=2_000_000, p999=2_000_000, max=2_000_000, mean=453_860),
        faults=Faults(minor=0, major=0),
        cpus_seen=(1,),
        complete=True,
    )
    thread = ThreadResult(
        process="p",
        instance=0,
        index=0,
        name="p",
        pid=1,
        tid=1,
        work="periodic",
        periodic=True,
        requested=Settings(),
        applied=Settings(),
        figures=figures,
        histograms=ThreadHistograms(latency=hist),
    )
    return CellResult(id=cell_id, spec_hash="x", status=Status.PASSED, threads=[thread])


def test_the_histogram_reads_as_cyclictest_prints_it_and_never_shows_a_latency_smaller():
    text = histogram_text(_cell(), size=300)
    lines = text.splitlines()
    rows = [line for line in lines if not line.startswith("#")]
    assert lines[0] == "# Histogram" and len(rows) == 300
    assert all(re.fullmatch(r"\d{6} \d{6}", row) for row in rows)
    counts = {int(row.split()[0]): int(row.split()[1]) for row in rows}
    assert counts[3] == 2 and counts[12] == 1 and sum(counts.values()) == 4
    assert sum(n for us, n in counts.items() if us < 250) == 3  # 250 us sits in a bucket at or above 250 us
    assert "# Total: 000000004" in lines and "# Histogram Overflows: 00001" in lines
    assert "# Min Latencies: 00003" in lines and "# Max Latencies: 02000" in lines and "# Avg Latencies: 00453" in lines


def test_the_json_summary_has_cyclictests_shape():
    doc = RunDocument(command=["runner", "x.yaml"], cells=[_cell()])
    out = json_summary(doc, doc.cells[0])
    assert set(out) >= {"file_version", "cmdline:", "rt_test_version:", "num_threads", "resolution_in_ns", "thread"}
    t = out["thread"]["0"]
    assert (t["cycles"], t["min"], t["max"], t["cpu"]) == (5, 3, 2000, 1)
    assert sum(t["histogram"].values()) == 5 and t["histogram"]["3"] == 2


def test_a_worst_latency_of_an_hour_exports_as_few_entries_as_it_has_buckets():
    """The JSON summary once made a list of one slot per microsecond up to the worst value: 3.6e9 for an hour."""
    cell = _cell()
    hist = hg.from_values([*LATENCIES, 3_600_000_000_000])
    thread = cell.threads[0].model_copy(update={"histograms": ThreadHistograms(latency=hist)})
    doc = RunDocument(command=["runner", "x.yaml"], cells=[cell.model_copy(update={"threads": [thread]})])
    t = json_summary(doc, doc.cells[0])["thread"]["0"]
    assert len(t["histogram"]) <= len(hist.buckets) and sum(t["histogram"].values()) == 6
    assert t["max"] == 3_600_000_000 and list(map(int, t["histogram"])) == sorted(map(int, t["histogram"]))


def test_a_run_of_several_cells_needs_cell_and_a_wrong_one_is_named():
    doc = RunDocument(cells=[_cell("a=1"), _cell("a=2")])
    with pytest.raises(UsageError, match="--cell"):
        pick_cell(doc, None)
    with pytest.raises(UsageError, match=r"no cell 'a=3'"):
        pick_cell(doc, "a=3")
    assert pick_cell(doc, "a=2").id == "a=2"


@pytest.mark.kernel
@pytest.mark.skipif(shutil.which("cyclictest") is None, reason="cyclictest (rt-tests) not installed")
def test_the_formats_match_a_real_cyclictests(tmp_path):
    out = tmp_path / "c.json"
    done = subprocess.run(
        ["cyclictest", "-q", "-l", "20", "-i", "1000", "-h", "50", f"--json={out}"], capture_output=True, text=True, timeout=30
    )
    theirs = json.loads(out.read_text())
    doc = RunDocument(cells=[_cell()])
    ours = json_summary(doc, doc.cells[0])
    assert set(theirs) - {"sysinfo"} <= set(ours)
    assert set(theirs["thread"]["0"]) <= set(ours["thread"]["0"])
    their_rows = [line for line in done.stdout.splitlines() if line and not line.startswith("#")]
    our_rows = [line for line in histogram_text(doc.cells[0], 50).splitlines() if not line.startswith("#")]
    shape = re.compile(r"\d{6} \d{6}")
    assert their_rows and all(shape.fullmatch(r) for r in their_rows) and all(shape.fullmatch(r) for r in our_rows)
    trailer = [line.split(":")[0] for line in done.stdout.splitlines() if line.startswith("# ") and ":" in line]
    ours_trailer = [line.split(":")[0] for line in histogram_text(doc.cells[0], 50).splitlines() if line.startswith("# ") and ":" in line]
    assert [t for t in trailer if not t.startswith("# /dev")][:6] == ours_trailer[:6]


def test_cell_and_histogram_max_without_the_export_they_shape_are_refused(tmp_path):
    """`runner report RUN --cell X` or `--histogram-max US` alone once re-rendered the whole report, ignoring them."""
    path = str(tmp_path / "results.json")
    RunDocument(cells=[_cell("a=1"), _cell("a=2")]).save(path)
    for given, words in (
        (["--cell", "a=2"], "--cell a=2 chooses the cell to export; give --histogram FILE or --json FILE too"),
        (["--histogram-max", "50", "-o", "-"], "--histogram-max 50 sets the size of the histogram; give --histogram FILE too"),
        (["--json", "-", "--cell", "a=2", "--histogram-max", "50"], "--histogram-max 50 sets the size of the histogram; "),
    ):
        done = run_cli("report", path, *given)
        assert done.code == 2 and done.out == "" and done.err.startswith(f"runner report: {words}"), (given, done.err)
    assert not os.path.exists(tmp_path / "report.md")
    done = run_cli("report", path, "--histogram", "-", "--cell", "a=2", "--histogram-max", "50")
    assert done.code == 0 and done.out == histogram_text(_cell("a=2"), 50), done.err
    done = run_cli("report", path, "--histogram", "-", "--cell", "a=2")  # cyclictest -h's usual 1000 us
    assert done.code == 0 and done.out == histogram_text(_cell("a=2"), 1000), done.err


@pytest.mark.parametrize("export", ["--json", "--histogram"])
def test_an_export_to_a_full_disk_exits_4_naming_it(tmp_path, export):
    """/dev/full refuses every write with ENOSPC: not invalid input (it once exited 2), but a disk to free or another file."""
    path = str(tmp_path / "results.json")
    RunDocument(cells=[_cell("a=1")]).save(path)
    done = run_cli("report", path, export, "/dev/full")
    assert done.code == 4 and "Traceback" not in done.err, done.err
    assert done.err.startswith("runner: cannot write the export /dev/full: No space left on device; the disk is full: free some space")


def test_a_baseline_with_only_an_export_is_refused_not_ignored(tmp_path):
    """`runner report RUN --json FILE --baseline BASE` exported and exited 0, the baseline never read, where `runner
    compare` on the same files failed: an export writes no report and decides no exit code."""
    path = str(tmp_path / "results.json")
    RunDocument(cells=[_cell("a=1")]).save(path)
    for given in (["--baseline", path], ["--threshold", "latency.p99=+1%"]):
        done = run_cli("report", path, "--json", str(tmp_path / "j.json"), *given)
        assert done.code == 2 and "alone write no report" in done.err and not os.path.exists(tmp_path / "j.json"), done.err
    done = run_cli("report", path, "--json", str(tmp_path / "j.json"), "-o", str(tmp_path / "r.md"), "--baseline", path)
    assert done.code != 2 and os.path.exists(tmp_path / "j.json") and "compared" in done.err, done.err  # with -o: compared
