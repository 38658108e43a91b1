"""cyclictest's formats and the HdrHistogram log from a cell's histograms (pure), `runner report`'s options for them, and
against a real cyclictest where one is installed; the log is decoded by HdrHistogram's own Python package."""

from __future__ import annotations

import email.utils
import json
import os
import random
import re
import shutil
import subprocess
from typing import Any

import pytest
from conftest import run_cli
from hdrh.histogram import HdrHistogram
from hdrh.log import HistogramLogReader
from hypothesis import example
from hypothesis import given as examples
from hypothesis import strategies as st
from kernelrun import needs_rt

from runner import histogram as hg
from runner.errors import UsageError
from runner.report.export import histogram_text, json_summary, pick_cell
from runner.report.hdrlog import encode, hdr_log
from runner.results.document import CellResult, MachineInfo, RunDocument, Status, ThreadHistograms, ThreadResult
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
    return CellResult(id=cell_id, spec_hash="x", status=Status.PASSED, threads=[thread], started_at="2026-11-22T00:48:56+00:00")


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


_MONTHS = "Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec"
_RFC2822 = re.compile(rf"(Mon|Tue|Wed|Thu|Fri|Sat|Sun), \d\d ({_MONTHS}) \d{{4}} \d\d:\d\d:\d\d [+-]\d{{4}}")


def read_cyclictest_json(data: dict[str, Any]) -> list[str]:
    """What a script written for `cyclictest --json` (rt-tests 2.x) takes from it, as strictly as cyclictest writes it;
    its per-thread lines as Linaro's rt-tests parser prints them (`t0-max-latency pass 35 us`).

    Each key is read as rt-utils.c's `rt_write_json` and cyclictest's `write_stats` write it: the version
    `"%1.2f"` (a number in text), times as `strftime("%a, %d %b %Y %T %z")` (RFC 2822), `sysinfo` from
    uname and /sys/kernel/realtime, and per thread a histogram of counts, cycles, min, max, avg, cpu, node.
    """
    assert data["file_version"] == 1
    assert isinstance(data["cmdline:"], str) and float(data["rt_test_version:"]) >= 0
    for key in ("start_time", "end_time"):
        assert _RFC2822.fullmatch(data[key]), (key, data[key])
        assert email.utils.parsedate_to_datetime(data[key]).tzinfo is not None
    assert isinstance(data["return_code"], int)
    info = data["sysinfo"]
    assert all(isinstance(info[k], str) for k in ("sysname", "nodename", "release", "version", "machine")), info
    assert info["realtime"] in (0, 1)
    assert isinstance(data["resolution_in_ns"], int)
    lines = []
    for n in range(int(data["num_threads"])):
        thread = data["thread"][str(n)]
        assert all(isinstance(k, str) and k.isdigit() and isinstance(v, int) for k, v in thread["histogram"].items())
        assert all(isinstance(thread[k], int) for k in ("cycles", "min", "max", "cpu", "node"))
        assert isinstance(thread["avg"], (int, float))
        lines += [f"t{n}-{key}-latency pass {thread[key]} us" for key in ("min", "avg", "max")]
    return lines


def _shape(value: Any) -> Any:
    """The JSON types of `value`, key by key (a histogram's keys are data, so only its values' type counts)."""
    if isinstance(value, dict):
        if all(k.isdigit() and isinstance(v, int) for k, v in value.items()):  # an empty histogram too
            return "counts"
        return {k: _shape(v) for k, v in value.items()}
    return "number" if isinstance(value, (int, float)) and not isinstance(value, bool) else type(value).__name__


def test_the_json_summary_has_cyclictests_shape():
    doc = RunDocument(command=["runner", "x.yaml"], cells=[_cell()])
    out = json_summary(doc, doc.cells[0])
    assert set(out) >= {"file_version", "cmdline:", "rt_test_version:", "num_threads", "resolution_in_ns", "thread", "sysinfo"}
    t = out["thread"]["0"]
    assert (t["cycles"], t["min"], t["max"], t["cpu"]) == (5, 3, 2000, 1)
    assert sum(t["histogram"].values()) == 5 and t["histogram"]["3"] == 2
    assert read_cyclictest_json(json.loads(json.dumps(out)))[2] == "t0-max-latency pass 2000 us"


def test_the_json_summary_says_the_machine_the_dates_and_the_version_as_cyclictest_writes_them():
    """Issue 41: `--json` had no `sysinfo`, ISO dates where cyclictest writes RFC 2822, and `rt_test_version:` was
    `runner 0.1.0`, which a script reading cyclictest's number could not read.  The machine is the one the run
    recorded, not the one exporting it."""
    machine = MachineInfo(hostname="rt-box", kernel="6.12.0-rt5", kernel_version="#1 SMP PREEMPT_RT Tue", arch="aarch64", preempt_rt=True)
    cell = _cell().model_copy(update={"started_at": "2026-11-22T00:48:56+00:00", "duration_ns": 61_500_000_000, "machine": machine})
    doc = RunDocument(command=["runner", "x.yaml"], cells=[cell])
    out = json_summary(doc, cell)
    assert out["sysinfo"] == {
        "sysname": "Linux",
        "nodename": "rt-box",
        "release": "6.12.0-rt5",
        "version": "#1 SMP PREEMPT_RT Tue",
        "machine": "aarch64",
        "realtime": 1,
    }
    assert (out["start_time"], out["end_time"]) == ("Sun, 22 Nov 2026 00:48:56 +0000", "Sun, 22 Nov 2026 00:49:57 +0000")
    assert out["rt_test_version:"] == "0.10" and float(out["rt_test_version:"]) == 0.1 and out["runner_version"] == "0.1.0"
    assert read_cyclictest_json(out)


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
@needs_rt  # cyclictest refuses to start without it, whatever its --policy
def test_the_formats_match_a_real_cyclictests(tmp_path):
    out = tmp_path / "c.json"
    done = subprocess.run(
        ["cyclictest", "-q", "-l", "20", "-i", "1000", "-h", "50", f"--json={out}"], capture_output=True, text=True, timeout=30
    )
    theirs = json.loads(out.read_text())
    doc = RunDocument(cells=[_cell().model_copy(update={"started_at": "2026-11-22T00:48:56+00:00", "machine": MachineInfo()})])
    ours = json.loads(json.dumps(json_summary(doc, doc.cells[0])))
    assert read_cyclictest_json(theirs) and read_cyclictest_json(ours)  # the reader is cyclictest's shape, and ours reads as it
    assert set(theirs) <= set(ours) and set(theirs["sysinfo"]) == set(ours["sysinfo"])
    assert set(theirs["thread"]["0"]) <= set(ours["thread"]["0"])
    their_shape, our_shape = _shape(theirs), _shape(ours)
    for key in set(theirs) - {"thread"}:
        assert their_shape[key] == our_shape[key], key  # every key of the same JSON type, sysinfo's too
    assert their_shape["thread"]["0"].items() <= our_shape["thread"]["0"].items()
    their_rows = [line for line in done.stdout.splitlines() if line and not line.startswith("#")]
    our_rows = [line for line in histogram_text(doc.cells[0], 50).splitlines() if not line.startswith("#")]
    shape = re.compile(r"\d{6} \d{6}")
    assert their_rows and all(shape.fullmatch(r) for r in their_rows) and all(shape.fullmatch(r) for r in our_rows)
    trailer = [line.split(":")[0] for line in done.stdout.splitlines() if line.startswith("# ") and ":" in line]
    ours_trailer = [line.split(":")[0] for line in histogram_text(doc.cells[0], 50).splitlines() if line.startswith("# ") and ":" in line]
    assert [t for t in trailer if not t.startswith("# /dev")][:6] == ours_trailer[:6]


def _intervals(path: str) -> list[HdrHistogram]:
    reader = HistogramLogReader(path, HdrHistogram(1, 2, 2))
    out = []
    while (h := reader.get_next_interval_histogram()) is not None:
        out.append(h)
    return out


def _latency_cell(*histograms: hg.Histogram) -> CellResult:
    cell = _cell().model_copy(update={"started_at": "2026-11-22T00:48:56+00:00", "duration_ns": 61_500_000_000})
    threads = [
        cell.threads[0].model_copy(update={"name": f"w{i}", "index": i, "histograms": ThreadHistograms(latency=h)})
        for i, h in enumerate(histograms)
    ]
    return cell.model_copy(update={"threads": threads})


def test_the_hdr_log_reads_back_in_hdrhistogram_as_the_cell_measured_it(tmp_path):
    """HdrHistogram's own reader finds the cell untagged (every thread) and each thread under its tag, over the cell's
    window, with the same counts, extremes and percentiles to the bucket (the layouts are the same)."""
    rng = random.Random(41)
    first = hg.from_values([int(rng.lognormvariate(10, 1)) for _ in range(20_000)])
    second = hg.from_values([5_000 + rng.randrange(100_000) for _ in range(5_000)])
    assert first is not None and second is not None
    cell = _latency_cell(first, second)
    path = tmp_path / "cell.hlog"
    path.write_text(hdr_log(RunDocument(cells=[cell]), cell))
    whole, one, two = _intervals(str(path))
    assert (whole.get_tag(), one.get_tag(), two.get_tag()) == (None, "p.w0", "p.w1-1")
    for decoded, hist in ((whole, hg.merge([first, second])), (one, first), (two, second)):
        assert hist is not None and decoded.get_total_count() == hist.count
        assert decoded.get_start_time_stamp() == 1795308536000 and decoded.get_end_time_stamp() == 1795308536000 + 61_500
        assert decoded.values_are_equivalent(decoded.get_min_value(), hist.min)
        assert decoded.values_are_equivalent(decoded.get_max_value(), hist.max)
        assert all(decoded.get_count_at_value(low) == n for low, _, n in hist.buckets)  # bucket by bucket
        for q in (50, 90, 99):  # (hdrh rounds a percentile's rank, the runner takes its ceiling: 99.9% of 25,000 differs)
            assert decoded.values_are_equivalent(decoded.get_value_at_percentile(q), hist.quantile(q / 100)), q
    lines = path.read_text().splitlines()
    assert lines[1] == "#[Histogram log format version 1.3]" and lines[2].startswith("#[StartTime: 1795308536.000 (seconds since epoch), ")
    assert lines[5].startswith("0.000,61.500,1.368,HISTF") and lines[6].startswith("Tag=p.w0,0.000,61.500,1.368,HISTF")


@examples(st.lists(st.integers(min_value=0, max_value=(1 << 45)), min_size=1, max_size=200))
@example([(1 << 40) - (1 << 32), 1 << 40])  # the last bucket's own values, below 2^40: CI found it
def test_any_histogram_encodes_to_the_counts_hdrhistogram_decodes(values):
    """Every bucket's count lands in HdrHistogram's bucket of the same values; none of the native core's last bucket
    (from 2^40 - 2^32 ns, its own width, up to any value above 2^40) is shown below the largest value seen, however far
    above 2^40 it lies."""
    hist = hg.from_values(values)
    assert hist is not None
    decoded = HdrHistogram.decode(encode(hist))
    assert decoded.get_total_count() == len(values)
    assert decoded.values_are_equivalent(decoded.get_max_value(), max(values))
    top = [v for v in values if hg.index(v) == hg.BUCKETS - 1]
    below = sorted(v for v in values if hg.index(v) < hg.BUCKETS - 1)
    for v in set(below):
        assert decoded.get_count_at_value(v) == sum(hg.index(w) == hg.index(v) for w in below)
    if top:
        assert decoded.get_count_at_value(max(values)) >= len(top)


def test_hdr_writes_the_log_and_is_refused_for_a_cell_without_latency(tmp_path):
    path = str(tmp_path / "results.json")
    RunDocument(cells=[_latency_cell(hg.from_values(LATENCIES))]).save(path)  # type: ignore[arg-type]
    done = run_cli("report", path, "--hdr", str(tmp_path / "l.hlog"))
    assert done.code == 0 and done.err == "", done.err
    assert [h.get_total_count() for h in _intervals(str(tmp_path / "l.hlog"))] == [5, 5]
    bare = _cell().model_copy(update={"threads": [_cell().threads[0].model_copy(update={"histograms": None})]})
    RunDocument(cells=[bare]).save(path)
    done = run_cli("report", path, "--hdr", "-")
    assert done.code == 2 and "has no latency histogram" in done.err, done.err


def test_cell_and_histogram_max_without_the_export_they_shape_are_refused(tmp_path):
    """`runner report RUN --cell X` or `--histogram-max US` alone once re-rendered the whole report, ignoring them."""
    path = str(tmp_path / "results.json")
    RunDocument(cells=[_cell("a=1"), _cell("a=2")]).save(path)
    for given, words in (
        (["--cell", "a=2"], "--cell a=2 chooses the cell to export; give --histogram FILE, --json FILE or --hdr FILE too"),
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


@pytest.mark.parametrize("export", ["--json", "--histogram", "--hdr", "--kcidb"])
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
