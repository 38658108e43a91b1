"""Recorded results used by the report, compare and merge tests (real runs on the development VM)."""

from __future__ import annotations

import copy
import dataclasses
import os

from runner.results import CellResult, RunDocument, ThreadResult, load

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
MATRIX = os.path.join(DATA, "policy_matrix")  # 5 cells, 1 s each, one hog per CPU
MEMORY = os.path.join(DATA, "memory_lock")  # 3 cells: unlocked, locked, locked + preallocated


def matrix() -> RunDocument:
    return load(MATRIX)


def memory() -> RunDocument:
    return load(MEMORY)


def main_thread(cell: CellResult) -> ThreadResult:
    return next(t for t in cell.threads if t.periodic)


def with_figures(doc: RunDocument, cell_id: str, **changes: object) -> RunDocument:
    """A copy of `doc` where the periodic thread of `cell_id` has some figures changed (latency_p99=..., invol_mean=...)."""
    out = copy.deepcopy(doc)
    cell = next(c for c in out.cells if c.id == cell_id)
    i = cell.threads.index(main_thread(cell))
    t = cell.threads[i]
    f = t.figures
    if "latency_p99" in changes:
        f = dataclasses.replace(f, latency_us={**(f.latency_us or {}), "p99": changes["latency_p99"]})
    if "invol_mean" in changes:
        f = dataclasses.replace(f, involuntary=dataclasses.replace(f.involuntary, per_callback_mean=changes["invol_mean"]))
    cell.threads[i] = dataclasses.replace(t, figures=f)
    return out
