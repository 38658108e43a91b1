"""Memory and percentiles of a long run: does the runner stay bounded, and do its histograms keep p99?

    python bench/longrun.py [--seconds 600] [--threads 4] [--period 100us] [--quick]

Runs one cell of N FIFO-70 threads with a 100 us period, memory locked, keeping every
sample (`samples: all`, streamed to samples.csv.gz), as a user runs it: report and plots
included (`--no-plots` leaves them out, to see what they cost).  While it runs, samples the memory
of the runner and every process it started (the sum of their PSS from
/proc/PID/smaps_rollup, which counts a shared page once), and says the peak while the cell ran
and while its results, report and plots were written (once the samples file is in place).  After it, recomputes each
thread's exact nearest-rank p50 / p99 / p99.9 of every release's latency from every row
of the samples file (a row that skipped k releases stands for k + 1 of them) and prints
them beside the figures the native histograms gave.
Targets: peak memory that does not grow with the run, plots included (5 s and 60 s within
10% of each other), about 100 MB for 4 threads (matplotlib is some 40 MB of the report's);
each percentile within the histogram's precision (1/128) of the exact one.
`--quick` (3 s, for CI) checks that the bench runs and prints its figures; its numbers
are not the ones to quote.
"""

from __future__ import annotations

import argparse
import csv
import glob
import gzip
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time

from runner import units

SCENARIO = """\
name: longrun
duration: {seconds}s
samples: all
processes:
  - name: longrun
    memory: {{lock: true}}
    main:
      sched: fifo:70
      work: {{kind: periodic, period: {period}}}
    threads:
      - name: lr
        count: {extra}
        sched: fifo:70
        work: {{kind: periodic, period: {period}}}
"""


def _pss_kib(pid: int) -> int:
    """Proportional set size: private pages plus a share of shared ones, so a sum over processes counts each page once."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as handle:
            for line in handle:
                if line.startswith("Pss:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def _family(root: int) -> list[int]:
    """`root` and every descendant, from /proc's parent links."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as handle:
                    parents[int(entry)] = int(handle.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    out, frontier = [root], [root]
    while frontier:
        frontier = [p for p, parent in parents.items() if parent in frontier]
        out += frontier
    return out


def _nearest_rank(ordered: list[int], q: float) -> int:
    return ordered[max(1, math.ceil(q * len(ordered))) - 1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=int, default=600)
    parser.add_argument("--threads", type=int, default=4)
    parser.add_argument("--period", default="100us")
    parser.add_argument("--no-plots", action="store_true", help="run the cell without drawing the plots")
    parser.add_argument("--quick", action="store_true", help="3 s, to check the bench runs (CI)")
    args = parser.parse_args()
    seconds = 3 if args.quick else args.seconds
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "longrun.yaml")
        with open(path, "w") as handle:
            handle.write(SCENARIO.format(seconds=seconds, period=args.period, extra=args.threads - 1))
        out = os.path.join(tmp, "out")
        began = time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, "-m", "runner", path, "--out", out, "--quiet", *(["--no-plots"] if args.no_plots else [])],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            cwd=tmp,  # not the checkout: `-m runner` must find the installed package, native core built
        )
        peak = [0, 0]  # KiB: while the cell runs, once it has ended (its samples file renamed into place)

        def watch() -> None:
            while proc.poll() is None:
                ended = bool(glob.glob(os.path.join(out, "cells", "*", "samples.csv.gz")))
                peak[ended] = max(peak[ended], sum(_pss_kib(p) for p in _family(proc.pid)))
                time.sleep(0.2)  # often enough to see the report's peak, which lasts a second or two

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        _, err = proc.communicate()
        watcher.join()
        wall = time.monotonic() - began
        if proc.returncode not in (0, 1):
            print(err, file=sys.stderr)
            return 1
        with open(os.path.join(out, "results.json")) as handle:
            cell = json.load(handle)["cells"][0]
        period = units.parse_duration(args.period)
        latencies: dict[str, list[int]] = {}
        with gzip.open(os.path.join(out, cell["samples_file"]), "rt", newline="") as handle:
            for row in csv.DictReader(handle):
                latency, missed = int(row["latency_ns"]), int(row["missed"])  # from the oldest release answered
                latencies.setdefault(row["thread"], []).extend(latency - k * period for k in range(missed + 1))
        size = os.path.getsize(os.path.join(out, cell["samples_file"]))
        print(f"{args.threads} threads, period {args.period}, {seconds} s: wall {wall:.1f} s, samples file {size / 2**20:.1f} MiB")
        plots = "without plots" if args.no_plots else "report and plots included"
        print(
            f"peak resident memory of the runner and its processes ({plots}): {max(peak) / 1024:.1f} MiB "
            f"(while the cell ran {peak[0] / 1024:.1f} MiB, writing the results and report {peak[1] / 1024:.1f} MiB)"
        )
        print(f"{'thread':<24} {'callbacks':>10} {'missed':>7} {'figure':>7} {'histogram us':>13} {'exact us':>10} {'error':>8}")
        worst = 0.0
        for t in cell["threads"]:
            f = t["figures"]
            ordered = sorted(latencies.get(t["key"], []))
            counted = t["histograms"]["latency"]["buckets"]
            releases = sum(n for _, _, n in counted)
            if len(ordered) != releases:  # rows not written (samples_lost): the exact percentiles are of another set
                print(
                    f"{t['key']:<24} {f['callbacks']:>10} {f['missed_releases']:>7}  rows for {len(ordered)} of {releases} releases "
                    f"({t['samples_lost']} samples lost): not compared"
                )
                worst = max(worst, 1.0)
                continue
            for name, q in (("p50", 0.5), ("p99", 0.99), ("p999", 0.999)):
                ours, exact = f["latency_ns"][name], _nearest_rank(ordered, q)
                error = (ours - exact) / exact if exact else 0.0
                worst = max(worst, abs(error))
                key, n, missed = t["key"], f["callbacks"], f["missed_releases"]
                print(f"{key:<24} {n:>10} {missed:>7} {name:>7} {ours / 1000:>13.2f} {exact / 1000:>10.2f} {error:>+8.2%}")
        print(f"largest percentile error: {worst:.2%} (histogram precision {1 / 128:.2%})")
        return 0 if worst <= 1 / 128 else 1


if __name__ == "__main__":
    raise SystemExit(main())
