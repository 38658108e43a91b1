"""Benchmark: render the markdown report of a 1,000-cell matrix (target: under 2 s).

Builds the matrix from the recorded policy_matrix run in tests/data (its cells
copied under new ids, 10 threads each), then times `report.render_run` and the
comparison of that matrix against itself.  Plots are not part of the target: they
are drawn per thread, not per cell.

    python bench/render.py [--cells 1000] [--quick]

`--quick` (100 cells, for CI) checks that the bench runs and prints its figures, and
exits 0 whatever they are.  Uses the installed runner package.
"""

from __future__ import annotations

import argparse
import copy
import os
import time

from runner.report import compare
from runner.report import markdown as report
from runner.results.read import load

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

TARGET_S = 2.0


def big_matrix(cells: int):
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
    p.add_argument("--quick", action="store_true", help="100 cells; exit 0 whatever the time (CI)")
    ns = p.parse_args()
    if ns.quick:
        ns.cells = 100
    doc = big_matrix(ns.cells)
    report.render_run(doc)  # warm up: templates compiled once per process
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
    return 0 if ns.quick or render_s < TARGET_S else 1


if __name__ == "__main__":
    raise SystemExit(main())
