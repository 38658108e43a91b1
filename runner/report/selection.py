"""Which threads a cell's tables show: all of a small cell; of a large one, those that matter and the worst.

A cell of 1,024 threads made a terminal summary and a report section of 1,040 rows per
table, plus a verdict line per thread.  Beyond a bound (24 threads on the terminal, 64 in a report) the tables show, in this
order of precedence and then in the cell's own order: threads with a failed expectation,
degraded ones, periodic threads that could not keep up (most releases missed first), the
worst wake-up latency p99, the processes' main threads.  A line says how many are left
out and that results.json has every one.  Pure: no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

from runner import figures as fg
from runner.results.document import CellResult, ThreadResult, Verdict
from runner.results.pstable import TableRow

Row = TypeVar("Row", bound=TableRow)

TERMINAL_ROWS = 24  # threads in the terminal's tables, and verdict or warning lines, before the rest are counted instead
REPORT_ROWS = 64  # the same in a report's cell section, which is read at leisure


@dataclass(frozen=True)
class Shown:
    """The threads a cell's tables show, in the cell's order, and how many are left out."""

    threads: list[ThreadResult]
    hidden: int

    def note(self) -> str:
        """The line under the tables, or "" when every thread is shown."""
        if not self.hidden:
            return ""
        total = len(self.threads) + self.hidden
        return (
            f"{len(self.threads)} of {total:,} threads shown: those with a failed expectation, degraded, that could not keep up,"
            f" with the worst wake-up latency, and the main threads; all {total:,} are in results.json"
        )


def _p99(t: ThreadResult) -> int:
    latency = t.figures.latency_ns
    return latency.p99 if latency is not None else -1


def threads_shown(cell: CellResult, most: int) -> Shown:
    """At most `most` of the cell's threads, those that matter first (see the module's docstring)."""
    threads = list(cell.threads)
    if len(threads) <= most:
        return Shown(threads, 0)
    failed = {v.thread for v in cell.expectations if not v.passed}
    ranked: list[ThreadResult] = []
    ranked += [t for t in threads if t.label(True) in failed or t.label(False) in failed]
    ranked += [t for t in threads if t.degraded]
    behind = [t for t in threads if t.has_callbacks and not fg.kept_up(t.figures)]
    ranked += sorted(behind, key=lambda t: -(t.figures.missed_releases or 0))
    ranked += sorted((t for t in threads if t.has_callbacks), key=lambda t: -_p99(t))
    ranked += [t for t in threads if t.index == 0]
    chosen: set[int] = set()
    for t in ranked:
        if len(chosen) >= most:
            break
        chosen.add(id(t))
    return Shown([t for t in threads if id(t) in chosen], len(threads) - len(chosen))


def ps_rows_shown(rows: Sequence[Row], shown: Shown) -> tuple[list[Row], int]:
    """The ps rows of the threads shown (all rows when every thread is), and how many rows are left out."""
    if not shown.hidden:
        return list(rows), 0
    tids = {t.tid for t in shown.threads if t.tid}
    kept = [r for r in rows if r.tid in tids]
    return kept, len(rows) - len(kept)


def verdicts_shown(verdicts: Sequence[Verdict], most: int) -> tuple[list[Verdict], int]:
    """At most `most` verdicts, the failed ones first (each group in its own order), and how many are left out."""
    if len(verdicts) <= most:
        return list(verdicts), 0
    ordered = [v for v in verdicts if not v.passed] + [v for v in verdicts if v.passed]
    return ordered[:most], len(verdicts) - most


def lines_shown(lines: Sequence[str], most: int) -> tuple[list[str], int]:
    """The first `most` lines, and how many are left out."""
    return list(lines[:most]), max(0, len(lines) - most)
