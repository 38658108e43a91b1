"""Benchmark: what storing a large matrix's results costs as its cells finish (target: at most 10 ms per
cell for 1,000 cells, about 2% of a 0.5 s cell, and bytes written within 5 times the final results.json).

The cells are the recorded policy_matrix run in tests/data, copied under new ids (34 KB each in
results.json).  The bench stores them one by one through `runner.results.journal.ResultsStore`,
as a run does after each cell (the journal line, synced, and results.json rewritten when due),
then finishes; it reports the time and the bytes written.  `--whole` times what runs did
before the journal, results.json rewritten after every cell, for comparison.

    python bench/store.py [--cells 1000] [--whole] [--quick]

`--quick` (200 cells, for CI) checks that the bench runs and prints its figures, and exits 0
whatever they are.  Uses the installed runner package.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from render import big_matrix

from runner.results.document import CellResult, RunDocument
from runner.results.journal import ResultsStore

TARGET_PER_CELL_S = 0.010
TARGET_BYTES_RATIO = 5.0


class _Counting(ResultsStore):
    """The store, counting what it writes."""

    written: int = 0

    def rewrite(self, doc: RunDocument) -> None:
        super().rewrite(doc)
        self.written += self.saved_bytes

    def _append(self, cell: CellResult) -> int:
        n = super()._append(cell)
        self.written += n
        return n


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", type=int, default=1000)
    p.add_argument("--whole", action="store_true", help="rewrite results.json after every cell, as before the journal")
    p.add_argument("--quick", action="store_true", help="200 cells; exit 0 whatever the figures (CI)")
    ns = p.parse_args()
    if ns.quick:
        ns.cells = 200
    cells = big_matrix(ns.cells).cells
    doc = big_matrix(0)
    with tempfile.TemporaryDirectory() as folder:
        store = _Counting(os.path.join(folder, "results.json"))
        began = time.perf_counter()
        store.begin(doc)
        for cell in cells:
            doc.cells.append(cell)
            if ns.whole:
                store.rewrite(doc)
            else:
                store.add(doc, cell)
        store.finish(doc)
        took = time.perf_counter() - began
    per_cell, ratio = took / ns.cells, store.written / store.saved_bytes
    how = "results.json rewritten after every cell" if ns.whole else "journal"
    print(
        f"{ns.cells} cells ({how}): {took:.2f} s, {per_cell * 1e3:.1f} ms per cell, {store.written / 1e6:.0f} MB written for a "
        f"{store.saved_bytes / 1e6:.1f} MB results.json ({ratio:.1f}x); targets {TARGET_PER_CELL_S * 1e3:.0f} ms per cell, "
        f"{TARGET_BYTES_RATIO:.0f}x"
    )
    return 0 if ns.quick or (per_cell <= TARGET_PER_CELL_S and ratio <= TARGET_BYTES_RATIO) else 1


if __name__ == "__main__":
    raise SystemExit(main())
