"""Honest figures against the real kernel: a thread that cannot keep up, clean fault counts, the sample ring.

Every scenario here runs for a second or two with process names of its own, so it never
meets the seed scenarios' processes.  The effects asserted are large (0 against many,
negative against positive), never exact timings.
"""

from __future__ import annotations

import csv
import gzip
import os

import pytest
import yaml
from kernelrun import finish, needs_rt, ran_cleanly, start_runner, thread

from runner import histogram as hg
from runner.results.samplesfile import SAMPLE_COLUMNS
from runner.run.samples import Sample, stats_of

pytestmark = [pytest.mark.kernel, needs_rt]

PERIOD = 30_000_000


def run(tmp_path, scenario: dict, *args: str):
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / f"{scenario['name']}.yaml"
    path.write_text(yaml.safe_dump(scenario))
    out = tmp_path / "out"
    done = finish(start_runner(str(path), "--out", str(out), "--settle", "0", *args, cwd=str(tmp_path)), str(out))
    assert done.results is not None, done.err
    return done, str(out)


def rows(out: str, results: dict) -> dict[str, list[dict[str, int | None]]]:
    """The samples file's rows by thread key, as integers (None where a column is empty: no slack, no chain)."""
    cell = results["cells"][0]
    by: dict[str, list[dict[str, int | None]]] = {}
    if not cell["samples_file"]:
        return by
    with gzip.open(os.path.join(out, cell["samples_file"]), "rt", newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader)
        assert tuple(header) == SAMPLE_COLUMNS
        for fields in reader:
            numbers = {k: int(v) if v else None for k, v in zip(header[1:], fields[1:]) if k != "lock_waits"}
            by.setdefault(fields[0], []).append(numbers)
    return by


OVERLOADED = {
    "name": "overload",
    "duration": "2s",
    "processes": [
        {
            "name": "ovl",
            "main": {"cpus": [0], "work": {"kind": "periodic", "period": "30ms", "burn": "20ms"}},
            "threads": [{"name": "ovl_peer", "cpus": [0], "work": {"kind": "periodic", "period": "30ms", "burn": "20ms"}}],
        }
    ],
    "expect": [{"thread": "ovl", "metric": "missed_releases", "max": 0}],
}


def test_a_thread_that_cannot_keep_up_says_so_and_fails_its_expectation(tmp_path):
    # Two threads on one CPU, each burning 20 ms of CPU per 30 ms period: each gets half the CPU, so a
    # callback takes about 40 ms of wall time and every other release is skipped.
    done, _ = run(tmp_path, OVERLOADED)
    main = thread(done.results, "ovl")["figures"]
    assert done.code == 1 and "could not keep up" in done.out
    assert main["missed_releases"] >= 10 and main["overruns"] >= 10 and main["slack_ns"]["min"] < 0
    assert main["releases"] == main["callbacks"] + main["missed_releases"]
    # latency counts the skipped releases: they waited about a period for the next wake-up
    assert main["latency_ns"]["max"] > PERIOD // 2
    cell = done.results["cells"][0]
    assert cell["status"] == "failed" and any("could not keep up" in w for w in cell["warnings"])
    # the scenario's own bound on ovl, and the implicit one on its peer, which no expectation names
    assert [(v["thread"], v["metric"], v["passed"], v["line"]) for v in cell["expectations"]] == [
        ("ovl/ovl (main)", "missed_releases", False, v0["line"] if (v0 := cell["expectations"][0]) else None),
        ("ovl/ovl_peer #1", "missed_releases", False, None),
    ]
    assert "could not keep up" in cell["expectations"][1]["note"]


def test_the_native_figures_are_the_documented_definitions_of_the_rows_written(tmp_path):
    """The histograms the native core kept equal those recomputed in Python from every sample row it wrote."""
    done, out = run(tmp_path, OVERLOADED)
    written = rows(out, done.results)
    for t in done.results["cells"][0]["threads"]:
        samples = [
            Sample(
                r["scheduled_ns"],
                r["wake_ns"],
                r["end_ns"],
                r["burn_wall_ns"],
                r["seq"],
                r["nivcsw"],
                r["nvcsw"],
                r["minflt"],
                r["majflt"],
                r["cpu_start"],
                r["cpu_end"],
                r["missed"],
                period_ns=r["period_ns"] or 0,
                next_ns=(r["scheduled_ns"] or 0) + PERIOD,  # periodic work: its next release is a period after its own
            )
            for r in written[t["key"]]
        ]
        assert len(samples) == t["figures"]["callbacks"] == t["samples_written"] and t["samples_lost"] == 0
        assert {s.period_ns for s in samples} == {PERIOD}, "every row says the period it was measured against"
        assert [r["latency_ns"] for r in written[t["key"]]] == [s.release_latency() for s in samples]
        mirror = stats_of(samples)
        assert mirror.latency is not None and mirror.slack is not None
        assert hg.Histogram.model_validate(t["histograms"]["latency"]) == mirror.latency
        assert hg.Histogram.model_validate(t["histograms"]["slack"]) == mirror.slack
        assert t["figures"]["overruns"] == mirror.overruns
        assert t["figures"]["latency_ns"]["mean"] == round(mirror.lat_mean)


def test_a_locked_preallocated_thread_shows_no_minor_fault_at_all(tmp_path):
    # 3000 callbacks write 3000 samples (47 pages of ring) and their histogram counters: the thread
    # wrote every page of its slot before the start gate, so none of them faults during the run.
    scenario = {
        "name": "nofaults",
        "duration": "3s",
        "processes": [
            {
                "name": "nf",
                "memory": {"lock": True, "prealloc": "16MiB"},
                "main": {"sched": "fifo:80", "work": {"kind": "periodic", "period": "1ms"}},
            }
        ],
    }
    done, out = run(tmp_path, scenario)
    f = thread(done.results, "nf")["figures"]
    assert ran_cleanly(done.code, done.results) and f["callbacks"] >= 2000, done.err
    assert f["faults"]["minor"] == 0 and f["faults"]["major"] == 0
    assert len(rows(out, done.results)["nf[0]/nf (main)"]) == f["callbacks"]


def _sampled(samples: str, **extra) -> dict:
    return {
        "name": "sampled",
        "duration": "1s",
        "samples": samples,
        **extra,
        "processes": [{"name": "smp", "main": {"sched": "fifo:70", "work": {"kind": "periodic", "period": "2ms"}}}],
    }


def test_samples_last_n_keeps_the_last_callbacks_and_none_keeps_no_file(tmp_path):
    done, out = run(tmp_path / "last", _sampled("last 50"))
    kept = rows(out, done.results)["smp[0]/smp (main)"]
    callbacks = thread(done.results, "smp")["figures"]["callbacks"]
    assert callbacks > 100 and [r["seq"] for r in kept] == list(range(callbacks - 50, callbacks))
    done, out = run(tmp_path / "none", _sampled("none"))
    assert ran_cleanly(done.code, done.results) and done.results["cells"][0]["samples_file"] is None, done.err
    assert thread(done.results, "smp")["figures"]["latency_ns"]["p99"] > 0  # the figures do not need the rows


def test_samples_outliers_writes_only_callbacks_past_the_bound(tmp_path):
    done, out = run(tmp_path, _sampled("outliers", latency_bound="1us"))  # every wake-up takes longer than 1 us
    kept = rows(out, done.results)["smp[0]/smp (main)"]
    f = thread(done.results, "smp")["figures"]
    assert f["latency_ns"]["above_bound"] == f["releases"] and len(kept) == f["callbacks"]
    done, out = run(tmp_path / "high", _sampled("outliers", latency_bound="1s"))
    f = thread(done.results, "smp")["figures"]
    kept = rows(out, done.results).get("smp[0]/smp (main)", [])
    assert f["latency_ns"]["above_bound"] == 0 and f["callbacks"] > 300
    assert len(kept) < 10 and all(r["missed"] or r["slack_ns"] < 0 for r in kept)  # only a callback that fell behind


def test_spin_waiting_gives_up_the_cpu_never_while_sleeping_does_every_period(tmp_path):
    def spec(wait: str) -> dict:
        return {
            "name": f"wait_{wait}",
            "duration": "1s",
            "processes": [{"name": f"w{wait}", "main": {"work": {"kind": "periodic", "period": "100us", "wait": wait}}}],
        }

    sleeping, _ = run(tmp_path / "sleep", spec("sleep"))
    spinning, _ = run(tmp_path / "spin", spec("spin"))
    slept = thread(sleeping.results, "wsleep")["figures"]
    spun = thread(spinning.results, "wspin")["figures"]
    assert slept["voluntary"]["total"] >= 1000 and spun["voluntary"]["total"] <= 10
    assert spun["callbacks"] >= 5000  # 10,000 releases in the second


PERIOD_50MS = 50_000_000


def test_the_most_preempted_callbacks_are_those_the_kernel_counted_switches_in_and_name_the_hog(tmp_path):
    """The trace's preempted runs of a periodic thread against its own callbacks' rows (getrusage, read by the thread).

    A run (switch-in after a wake-up to the next sleep) is a callback, so each kept run starts
    just before a row's wake-up and has exactly that row's involuntary switches, plus one for a
    preemption in the microseconds between the switch-in and the callback's first read, or between
    its last read and its sleep: the hog then held the CPU for a slice of its own (0.75 ms at the
    least), so the run's start lies that much before the row's wake-up, or its end after the row's.
    Never fewer switches than the thread counted, and all runs but one exactly so explained.
    """
    scenario = {
        "name": "preempted",
        "duration": "1s",
        "processes": [{"name": "prm", "main": {"cpus": [0], "work": {"kind": "periodic", "period": "50ms", "burn": "20ms"}}}],
        "background": {"hogs": [{"count": 1, "kind": "process", "cpus": [0]}]},
        "expect": [{"thread": "prm", "metric": "missed_releases", "max": 20}],
    }
    done, out = run(tmp_path, scenario)
    c = done.results["cells"][0]
    if not c["trace"]["enabled"]:
        pytest.skip(f"no scheduler trace here: {c['trace']['reason']}")
    main = thread(done.results, "prm")
    runs, start = main["preempted_runs"], c["trace"]["window_start_ns"]
    assert len(runs) >= 5, "a SCHED_OTHER callback beside a busy loop on its CPU is preempted in most periods"
    assert [r["preempted_ns"] for r in runs] == sorted((r["preempted_ns"] for r in runs), reverse=True)
    written = rows(out, done.results)[main["key"]]
    unexplained = []
    for r in runs:
        began, ended = start + r["at_ns"], start + r["at_ns"] + r["wall_ns"]
        row = next(w for w in written if began <= w["wake_ns"] <= ended)
        before = row["wake_ns"] - began >= 200_000  # preempted before the callback's first read: a hog slice
        after = ended - row["end_ns"] >= 200_000  # or after its last
        assert row["wake_ns"] - began < (PERIOD_50MS if before else 200_000), (r, row)
        assert row["nivcsw"] <= r["preemptions"] <= row["nivcsw"] + 2, (r, row)
        if row["nivcsw"] + before + after != r["preemptions"]:
            unexplained.append((r, row))
        assert r["preempted_ns"] <= r["wall_ns"] and r["by_ns"] <= r["preempted_ns"]
    # A VM's host may stall the vCPU between a callback's last read and its sleep (a gap with no
    # switch), or a kernel thread take a few microseconds there: once in a run, not in most.
    assert len(unexplained) <= 1, unexplained
    assert sum(r["by"]["comm"] == "hog" for r in runs) >= len(runs) // 2, [r["by"] for r in runs]
    hog = next(b for b in c["background"] if b["kind"] == "hog")
    named = [p for p in main["preempted_by"] if p["comm"] == "hog"] + [r["by"] for r in runs if r["by"]["comm"] == "hog"]
    assert named and all(p["pid"] == hog["pid"] and p["cls"] == "TS" for p in named), "read from /proc while the hog lived"


def test_the_background_load_lasts_until_a_callback_that_ran_past_the_end_is_done(tmp_path):
    """The load ends early only once no measured thread works: never under a callback still running at the end.

    Released 0.95 s into a 1 s cell, a callback of 150 ms of CPU time shares its CPU with a
    hog to its end (about 300 ms of wall); had the hog stopped at the end, it would have run
    alone from there (about 175 ms).  Every callback is as slow as the first ones.
    """
    scenario = {
        "name": "loadend",
        "duration": "1s",
        "processes": [{"name": "ldend", "main": {"cpus": [0], "work": {"kind": "periodic", "period": "475ms", "burn": "150ms"}}}],
        "background": {"hogs": [{"count": 1, "cpus": [0], "name": "ldhog"}]},
        "expect": [{"thread": "ldend", "metric": "overruns", "max": 10}, {"thread": "ldend", "metric": "missed_releases", "max": 10}],
    }
    done, _ = run(tmp_path, scenario)
    main = thread(done.results, "ldend")
    assert main["figures"]["callbacks"] == 3, main["figures"]
    wall = main["figures"]["callback_wall_ns"]
    assert wall["min"] > 250_000_000, f"a callback ran without the hog beside it: {wall}"


def test_a_background_commands_log_keeps_its_first_64_mib_and_counts_the_rest(tmp_path):
    """A load generator that logs at full speed must not fill the disk the results go to: its log is capped, the rest
    read and dropped (the command is never held up), counted in results and said in the cell's warnings."""
    extra = 100_000
    scenario = {
        "name": "cmdlog",
        "duration": "300ms",
        "processes": [{"name": "cmdlog", "main": {"work": {"kind": "periodic", "period": "50ms"}}}],
        "background": {"commands": [{"argv": ["head", "-c", str(64 * 1024 * 1024 + extra), "/dev/zero"], "name": "chatty"}]},
    }
    done, out = run(tmp_path, scenario)
    cell = done.results["cells"][0]
    (command,) = [b for b in cell["background"] if b["kind"] == "command"]
    assert (command["log"], command["output_bytes"], command["output_dropped"]) == ("command-0.log", 64 * 1024 * 1024 + extra, extra)
    assert os.path.getsize(os.path.join(out, "cells", cell["id"], "command-0.log")) == 64 * 1024 * 1024
    assert any(w.startswith("background command chatty wrote 64.1MiB to its log") and "dropped" in w for w in cell["warnings"]), cell[
        "warnings"
    ]


def test_releases_missed_in_a_row_count_the_longest_run_not_all_misses(tmp_path):
    """Control loops survive one lost release, not two in a row: `missed_releases.consecutive_max` from the native core.

    On CPU 0 a FIFO 80 thread runs 35 ms every 200 ms over a FIFO 50 periodic thread of 10 ms: each time the periodic
    callback is held back 35 ms and skips 3 releases in a row.  A program whose timer callback runs 35 ms every tenth
    activation skips 3 in a row of its own.  A FIFO 60 periodic thread alone on CPU 1 misses none.
    """
    steady = [{"timer": {"period": "10ms"}}, {"run": "1ms"}]
    scenario = {
        "name": "in_a_row",
        "duration": "2s",
        "processes": [
            {
                "name": "row",
                "main": {"sched": "fifo:50", "cpus": [0], "work": {"kind": "periodic", "period": "10ms", "burn": "1ms"}},
                "threads": [
                    {
                        "name": "row_hog",
                        "sched": "fifo:80",
                        "cpus": [0],
                        "work": {"kind": "phases", "events": [{"timer": {"period": "200ms"}}, {"run": "35ms"}]},
                    },
                    {
                        "name": "row_prog",
                        "sched": "fifo:40",
                        "cpus": [1],
                        "work": {
                            "kind": "phases",
                            "phases": [{"loop": 9, "events": steady}, {"events": [{"timer": {"period": "10ms"}}, {"run": "35ms"}]}],
                        },
                    },
                    {"name": "row_steady", "sched": "fifo:60", "cpus": [1], "work": {"kind": "periodic", "period": "10ms", "burn": "1ms"}},
                ],
            }
        ],
        "expect": [{"thread": name, "metric": "missed_releases.consecutive_max", "max": 1} for name in ("row", "row_prog", "row_steady")],
    }
    done, _ = run(tmp_path, scenario)
    assert done.results is not None, done.err
    for name in ("row", "row_prog"):
        f = thread(done.results, name)["figures"]
        assert f["missed_consecutive_max"] >= 2 and f["missed_releases"] > f["missed_consecutive_max"], (name, f)
    assert thread(done.results, "row_steady")["figures"]["missed_consecutive_max"] == 0
    verdicts = {
        v["thread"].split()[0]: (v["passed"], v["measured"])
        for v in done.results["cells"][0]["expectations"]
        if v["metric"] == "missed_releases.consecutive_max"
    }
    assert {k: passed for k, (passed, _) in verdicts.items()} == {"row/row": False, "row/row_prog": False, "row/row_steady": True}, verdicts
    assert done.code == 1
