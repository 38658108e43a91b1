"""The report's first lines: what the run came to, and each failure with the place in the scenario that asked for it.

A reader (a person, a job summary cut short, a CI page) sees the verdict before anything
else: `**❌ failed**: 1 cell run (1 failed); 2 of 3 expectations failed`, then one line per
failed expectation, cell that could not run and regression, each with its `file:line`
(expectations keep the line and column they are written at; a regression or a cell's error
has no line, so the file alone).  The failures are the ones JUnit and the workflow annotations
report (`outcomes.cell_checks`), so the three cannot disagree.  Pure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

from runner.report.fmt import Markdown, md_code, md_text, relative_path
from runner.report.outcomes import CellChecks, Check, Kind, Outcome, cell_checks
from runner.results.document import RunDocument, Status

if TYPE_CHECKING:
    from runner.history.judge import NightVerdict
    from runner.report.compare import Comparison

MAX_LISTED = 10  # failures the headline lists; the rest are counted, every one is in its cell's section

_ICON = {
    Status.PASSED.value: "✅",
    Status.DEGRADED.value: "⚠️",
    Status.FAILED.value: "❌",
    Status.ERROR.value: "💥",
    Status.INTERRUPTED.value: "⏸️",
    "running": "⏳",
}
_MARK = {Kind.EXPECTATION: "❌", Kind.RUN: "💥", Kind.BASELINE: "📉", Kind.HISTORY: "📉"}
_WHAT = {Kind.EXPECTATION: "", Kind.RUN: "", Kind.BASELINE: "regression: ", Kind.HISTORY: "regression against the history: "}


@dataclass(frozen=True)
class Headline:
    verdict: Markdown  # `**✅ passed**: 5 cells run (5 passed); 9 of 9 expectations met`
    failures: list[Markdown]  # a line per failure, at most MAX_LISTED, then how many more


def headline(
    doc: RunDocument, comparison: Optional[Comparison] = None, history: Optional[NightVerdict] = None, cwd: Optional[str] = None
) -> Headline:
    """The verdict of `doc` (with its comparison and history, when it has them) and its failures, paths relative to `cwd`."""
    suites = cell_checks(doc, comparison, True, history)
    regressions = sum(c.outcome is Outcome.FAILED for s in suites for c in s.checks if c.kind in (Kind.BASELINE, Kind.HISTORY))
    word = "regressed" if regressions and doc.status == Status.PASSED.value else doc.status
    icon = "❌" if word == "regressed" else _ICON.get(doc.status, "")
    parts = [_cells(doc)]
    verdicts = [v for cell in doc.cells for v in cell.expectations]
    if verdicts:
        failed = sum(not v.passed for v in verdicts)
        parts.append(
            f"{failed} of {len(verdicts)} expectations failed" if failed else f"{len(verdicts)} of {len(verdicts)} expectations met"
        )
    if comparison is not None or history is not None:
        parts.append(f"{regressions} regression{'s' if regressions != 1 else ''}" if regressions else "no regression")
    verdict = Markdown(f"**{icon} {md_text(word)}**: " + md_text("; ".join(parts)))
    path = relative_path(doc.scenario.path, cwd) if doc.scenario.path else None
    lines = _failures(suites, path, matrix=len({c.id for c in doc.cells}) > 1 or any(c.repeat for c in doc.cells))
    if len(lines) > MAX_LISTED:
        rest = len(lines) - (MAX_LISTED - 1)
        lines = lines[: MAX_LISTED - 1] + [Markdown(f"… {rest:,} more: see the cells' Expectations below, results.json and the JUnit file")]
    return Headline(verdict, lines)


def _cells(doc: RunDocument) -> str:
    """`5 cells run (4 passed, 1 failed), 2 not run`."""
    counts: dict[Status, int] = {}
    for cell in doc.cells:
        counts[cell.status] = counts.get(cell.status, 0) + 1
    outcome = ", ".join(f"{n} {s.value}" for s, n in sorted(counts.items(), key=lambda kv: list(Status).index(kv[0])))
    ran = {cell.id for cell in doc.cells}
    missing = len([c for c in dict.fromkeys(doc.cell_ids) if c not in ran])
    return f"{len(doc.cells)} cell{'s' if len(doc.cells) != 1 else ''} run ({outcome or 'none'})" + (
        f", {missing} not run" if missing else ""
    )


def _failures(suites: list[CellChecks], path: Optional[str], matrix: bool) -> list[Markdown]:
    """A line per failed check, errors and expectations first; an expectation failed in several cells is one line."""
    groups: dict[tuple[Kind, str, Optional[int], Optional[int]], list[tuple[CellChecks, Check]]] = {}
    for suite in suites:
        for check in suite.checks:
            if check.outcome is Outcome.FAILED or (check.outcome is Outcome.ERROR and check.kind is Kind.RUN):
                groups.setdefault((check.kind, check.name, check.line, check.col), []).append((suite, check))
    order = [Kind.RUN, Kind.EXPECTATION, Kind.BASELINE, Kind.HISTORY]
    out = []
    for (kind, _, line, _), found in sorted(groups.items(), key=lambda kv: order.index(kv[0][0])):
        where = f"{path}:{line}" if path and line else path
        place = f"{md_code(where)}: " if where else ""
        suite, check = found[0]
        if len(found) == 1:
            status = f" ({suite.status.value})" if kind is Kind.RUN and suite.status else ""
            cell = f"cell {suite.title}{status}: " if matrix or kind is Kind.RUN else ""
            out.append(Markdown(f"{_MARK[kind]} {place}{md_text(_WHAT[kind] + cell + check.message)}"))
        else:
            cells = ", ".join(s.title for s, _ in found[:5]) + (f" and {len(found) - 5} more" if len(found) > 5 else "")
            text = f"{_WHAT[kind]}{check.name}: in {len(found)} cells ({cells}); in cell {suite.title}: {check.message}"
            out.append(Markdown(f"{_MARK[kind]} {place}{md_text(text)}"))
    return out
