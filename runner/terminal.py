"""What the terminal shows after each cell: the ps-style table and a per-thread summary.  Pure."""

from __future__ import annotations

from typing import Optional

from tabulate import tabulate

from .pstable import render_ps
from .results import CellResult, Status

_MARK = {Status.PASSED: "passed", Status.DEGRADED: "DEGRADED", Status.FAILED: "FAILED", Status.ERROR: "ERROR",
         Status.INTERRUPTED: "INTERRUPTED"}


def _num(value: Optional[float], fmt: str = "{:.2f}") -> str:
    return "-" if value is None else fmt.format(value)


def render_cell(cell: CellResult, pid_width: int = 5) -> str:
    """Thread table, per-thread summary, expectation verdicts and degradations of one cell."""
    out = [f"cell {cell.id}: {_MARK[cell.status]} ({cell.duration_s:.1f}s)" + (f" - {cell.reason}" if cell.reason else "")]
    if cell.thread_table:
        out.append("")
        out.extend("  " + line for line in render_ps(cell.thread_table, pid_width=pid_width).splitlines())
    rows = []
    for t in cell.threads:
        f = t.figures
        lat = f.latency_us or {}
        rows.append([
            f"{t.name}{' (main)' if t.index == 0 else ''}",
            t.tid,
            t.applied.label() if t.applied else "?",
            f.callbacks if t.periodic else "-",
            _num(f.involuntary.per_callback_mean) if t.periodic else f"{f.involuntary.total} total",
            _num(f.involuntary.per_callback_max, "{}"),
            _num(lat.get("p50"), "{:.1f}"), _num(lat.get("p99"), "{:.1f}"), _num(lat.get("max"), "{:.1f}"),
            f.faults.minor,
        ])
    if any(t.periodic for t in cell.threads):
        shown = [r for r, t in zip(rows, cell.threads) if t.periodic]
        headers = ["thread", "tid", "applied", "callbacks", "invol/cb", "invol max", "lat p50 us", "p99 us", "max us", "minor faults"]
        out.append("")
        out.extend("  " + line for line in tabulate(shown, headers=headers, tablefmt="simple", disable_numparse=True).splitlines())
    for v in cell.expectations:
        measured = "not measured" if v.measured is None else (
            f"{v.measured / 1000:.1f}us" if v.metric.is_latency else f"{v.measured:g}")
        out.append(f"  {'ok  ' if v.passed else 'FAIL'} {v.thread}: {v.metric.value} {v.limit} (measured {measured}){' - ' + v.note if v.note else ''}")
    for t in cell.threads:
        for why in t.degraded:
            out.append(f"  DEGRADED {t.process}/{t.name}: {why}")
    return "\n".join(out) + "\n"
