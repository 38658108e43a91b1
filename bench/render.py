"""Benchmark: reports that do not grow with threads (targets: a 1,000-cell matrix's report under 1 s; a
256-thread cell's report and plots under 2 s).

The matrix is the recorded policy_matrix run in tests/data, its cells copied under new ids (10
threads each); the bench times `report.render_run` and the comparison of that matrix against
itself.  The 256-thread cell (8 processes, 1,000 callbacks per thread, native histograms and a
samples file of 256,000 rows) is synthetic, built by tests/reportdata.py's `many_threads`, never
run; the bench times `publish.write_report` on it, plots included, in a fresh process as a user
would meet it (matplotlib's import counted), and counts the plots drawn.

    python bench/render.py [--cells 1000] [--threads 256] [--quick]

`--quick` (100 cells, 64 threads, for CI) checks that the bench runs and prints its figures,
and exits 0 whatever they are.  Uses the installed runner package.
"""

from __future__ import annotations

import argparse
import copy
import os
import subprocess
import sys
import tempfile
import time

from runner.collector import collector_paused
from runner.report import compare
from runner.report import markdown as report
from runner.results.document import RunDocument
from runner.results.read import load

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

TARGET_S = 1.0  # the 1,000-cell report
CELL_TARGET_S = 2.0  # the 256-thread cell's report and plots
CELL_SCRIPT = """
import os, sys, time
sys.path.insert(0, os.path.join(sys.argv[1], "tests"))
from reportdata import many_threads
doc = many_threads(sys.argv[2], threads=int(sys.argv[3]))
began = time.perf_counter()
from runner.report.publish import write_report
write_report(doc, sys.argv[2])
print(time.perf_counter() - began, len(os.listdir(os.path.join(sys.argv[2], "plots"))))
"""


def big_matrix(cells: int) -> RunDocument:
    doc = load(os.path.join(REPO, "tests", "data", "policy_matrix"))
    base = doc.cells
    out = []
    for i in range(cells):
        cell = copy.deepcopy(base[i % len(base)])
        cell.id = f"{cell.id},load={i // len(base)}"
        cell.matrix = {**cell.matrix, "load": i // len(base)}
        out.append(cell)
    doc.cells = out
    doc.matrix_cells = [c.id for c in out]
    doc.cell_ids = list(doc.matrix_cells)
    return doc


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", type=int, default=1000)
    p.add_argument("--threads", type=int, default=256)
    p.add_argument("--quick", action="store_true", help="100 cells, 64 threads; exit 0 whatever the time (CI)")
    ns = p.parse_args()
    if ns.quick:
        ns.cells, ns.threads = 100, 64
    doc = big_matrix(ns.cells)
    report.render_run(doc)  # warm up: templates compiled once per process
    with collector_paused():  # as the report writer renders, and `runner report` and `runner compare` run
        began = time.perf_counter()
        text = report.render_run(doc)
        render_s = time.perf_counter() - began
        began = time.perf_counter()
        cmp = compare.compare(doc, doc)
        section = report.render_comparison(cmp, "base", "new")
        compare_s = time.perf_counter() - began
    print(
        f"{ns.cells} cells: report {render_s:.2f} s ({len(text) / 1e6:.1f} MB), compare {compare_s:.2f} s "
        f"({len(section) / 1e6:.1f} MB); target {TARGET_S:.1f} s for the report"
    )
    with tempfile.TemporaryDirectory() as folder:
        done = subprocess.run(
            [sys.executable, "-c", CELL_SCRIPT, REPO, os.path.join(folder, "run"), str(ns.threads)],
            capture_output=True,
            text=True,
            check=True,
        )
    cell_s, plots = done.stdout.split()
    print(
        f"{ns.threads} threads in one cell: report and plots {float(cell_s):.2f} s, {plots} plots; "
        f"target {CELL_TARGET_S:.1f} s for 256 threads"
    )
    return 0 if ns.quick or (render_s < TARGET_S and float(cell_s) < CELL_TARGET_S) else 1


if __name__ == "__main__":
    raise SystemExit(main())
