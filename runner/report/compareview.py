"""The comparison view: a run against its baseline, as markdown.

`runner.report.compare` decides (what changed, by how much, is it a regression);
this module says it: the headline, the table of changed figures with their intervals,
and the words for one change (`change_text`), which the outcome pages reuse.  Pure.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from runner import figures as fg
from runner.report.findings import thread_labels
from runner.report.fmt import LEFT, RIGHT, Markdown, environment, md_code, md_text
from runner.report.tables import Table, known, when
from runner.results.document import Status

if TYPE_CHECKING:
    from runner.report.compare import Comparison, FigureChange
    from runner.results.estimates import Estimate


# ---------------------------------------------------------------- comparison with a baseline

VERDICT_ICON = {
    "regression": "❌ regression",
    "better": "🟢 better",
    "within threshold": "✅ within threshold",
    "not checked": "⏸️ not checked (threshold off)",
    "no baseline": "🆕 no baseline",
    "missing": "❌ missing",
    "run error": "💥 run error",
    "not comparable": "⚠️ not comparable (trace events lost)",
    "within noise": "〰️ within noise",
    "not judged": "⏸️ not judged",
}


@dataclass
class ComparisonModel:
    headline: Markdown
    facts: Table
    regressions: Table | None
    cells: Table
    figures: Table | None
    notes: list[str]


HEADLINE_NAMES = 5  # names a headline lists of each kind (cells, threads, figures) before "and N more"


def _capped(names: Sequence[str], most: int = HEADLINE_NAMES) -> str:
    """`a, b, c, d, e and 995 more`: a headline names a few of each kind; the tables below name them all.

    The headline is also the terminal line `compared with BASE: ...` (`publish.say_comparison`), which
    on a matrix of a thousand cells listed every one of them.
    """
    shown = ", ".join(names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def build_comparison(cmp: Comparison, base_name: str, new_name: str) -> ComparisonModel:
    """What the comparison section shows: a headline, regressions first, then every figure compared."""
    labels = thread_labels(cmp.base.cells + cmp.new.cells)
    regressed = cmp.regressed_cells()
    total = len(cmp.compared())
    incomplete = cmp.incomplete  # what it holds may compare well; what it lacks was never measured: never ✅
    errored = [c for c in cmp.cells if c.new_status in (Status.ERROR, Status.INTERRUPTED)]  # cells that did not run to the end: never ✅
    gone, new_cells = cmp.unmatched("missing"), cmp.unmatched("no baseline")
    # a thread or a cell of the baseline this run lacks was never compared (even with every threshold off): never ✅
    headline = (
        f"❌ **{cmp.regressions} regression{'s' if cmp.regressions != 1 else ''}** in {len(regressed)} of {total} "
        f"cell{'s' if total != 1 else ''}: {_capped([md_text(c) for c in regressed])}."
        if regressed
        else f"{'' if incomplete or errored or not cmp.alike or cmp.threads_gone or gone else '✅ '}"
        f"No regression in {total} cell{'s' if total != 1 else ''} compared with the baseline."
    )
    if cmp.nothing:  # a shard with no cell: nothing compared is neither a pass nor a failure
        headline = f"Nothing to compare: this run holds no cell ({md_text(cmp.nothing)})."
    for difference in cmp.differences:  # what could explain a change (or hide one) besides the scheduling: never ✅
        headline += f" ⚠️ {md_text(difference)}"
    if errored:
        shown = _capped([f"{md_text(c.cell)} ({c.new_status.value if c.new_status else '?'})" for c in errored])
        which = "cell of this run could not run or was" if len(errored) == 1 else "cells of this run could not run or were"
        headline = f"💥 **{len(errored)} {which} cut short**: {shown}. {headline}"
    if incomplete:
        headline = f"⚠️ This run is incomplete: {md_text(incomplete)}. {headline}"
    if cmp.other_version:  # first: every figure below is of another version of the scenario
        headline = f"⚠️ **Another version of the scenario**: {md_text(cmp.other_version)}. {headline}"
    gone_threads = set(cmp.threads_gone)
    if gone_threads:  # its figures are missing too: said once, as the thread
        where = [f"{md_text(labels.get(key, key))} ({md_text(cell)})" for cell, key in cmp.threads_gone]
        headline += f" {len(where)} thread{'s' if len(where) != 1 else ''} of the baseline not in this run: {_capped(where)}."
    lost = [f for f in cmp.figures if f.verdict == "missing" and (f.cell, f.thread) not in gone_threads]
    if lost:
        where = sorted({f"{f.figure.name} ({md_text(f.cell)})" for f in lost})
        headline += f" {len(lost)} figure{'s' if len(lost) != 1 else ''} of the baseline not measured now: {_capped(where)}."
    if gone:
        shown = _capped(list(map(md_text, gone)))
        headline += f" {len(gone)} cell{'s' if len(gone) != 1 else ''} of the baseline not in this run: {shown}."
    if new_cells:
        shown = _capped(list(map(md_text, new_cells)))
        headline += f" {len(new_cells)} cell{'s' if len(new_cells) != 1 else ''} not in the baseline: {shown}."
    facts = Table(
        ["", "Baseline", "This run"],
        [
            ["Results", md_code(base_name, in_table=True), md_code(new_name, in_table=True)],
            ["Started", when(cmp.base.started_at), when(cmp.new.started_at)],
            [
                "Host, kernel",
                f"{known(cmp.base.machine.hostname)}, {known(cmp.base.machine.kernel)}",
                f"{known(cmp.new.machine.hostname)}, {known(cmp.new.machine.kernel)}",
            ],
        ],
    )
    notes = [
        "A figure regresses when it is worse than its baseline by more than its threshold: "
        + "; ".join(f"{fg.figure(t.figure).words} {t.describe()}" for t in cmp.thresholds)
        + ", and by more than sampling explains. Each figure is shown with its 95% interval [low, high] (a quantile's "
        "from the order statistics of its histogram, a count's exact binomial or Poisson one, a mean's standard error); "
        "the change is tested exactly against both runs' samples, and the p-values are adjusted by Holm's method over "
        "every figure tested, so that a whole comparison would call a false regression at most 5% of the time if each "
        "callback were an independent sample of one unchanged host. Neither quite holds: one hiccup delays several "
        "callbacks, and a host varies from night to night (of 19 identical nights on a 2-CPU VM, 6 were called "
        "regressions against the night before). For a nightly verdict, judge against a history (--history), which "
        "learns each figure's variation between nights. A change past its threshold that sampling explains is within "
        "noise; a figure with too few samples for an interval is not judged, and says what it needs."
    ] + list(cmp.notes)

    def figure_rows(items: Iterable[FigureChange]) -> list[list[str]]:
        rows = []
        for f in items:
            sc = fg.scale(f.figure.unit, (f.base, f.new, *interval_ends(f.base_estimate), *interval_ends(f.new_estimate)))
            rows.append(
                [
                    f.cell,
                    labels.get(f.thread, f.thread),
                    sc.header(f.figure.words),
                    sc.number(f.base) + interval_text(f.base_estimate, sc),
                    sc.number(f.new) + interval_text(f.new_estimate, sc),
                    change_text(f, sc),
                    VERDICT_ICON[f.verdict],
                    md_text(f.why) if f.why else "–",
                ]
            )
        return rows

    headers = ["Cell", "Thread", "Figure", "Baseline", "This run", "Change", "Verdict", "Why"]
    align = [LEFT, LEFT, LEFT, RIGHT, RIGHT, RIGHT, LEFT, LEFT]
    bad = [f for f in cmp.figures if f.verdict in ("regression", "missing")]  # a figure of the baseline this run lacks fails too
    status_rows = [
        [
            c.cell,
            c.base_status.value if c.base_status else "–",
            c.new_status.value if c.new_status else "–",
            VERDICT_ICON["regression" if c.cell in regressed and c.verdict != "run error" else c.verdict]
            + (f" ({c.note})" if c.note else ""),
        ]
        for c in cmp.cells
    ]
    return ComparisonModel(
        headline=Markdown(headline),
        facts=facts,
        regressions=Table(headers, figure_rows(bad), align) if bad else None,
        cells=Table(["Cell", "Baseline status", "Status now", "Verdict"], status_rows),
        figures=Table(headers, figure_rows(cmp.figures), align) if cmp.figures else None,
        notes=notes,
    )


def interval_ends(est: Estimate | None) -> tuple[float, ...]:
    """The ends of an estimate's interval, to choose a row's scale with (none when it has none)."""
    if est is None or est.low is None or est.high is None:
        return ()
    return (est.low, est.high)


def interval_text(est: Estimate | None, sc: fg.Scale) -> str:
    """` [49, 66]`: an estimate's interval in the scale of its row; "" when it has none."""
    if est is None or est.low is None or est.high is None:
        return ""
    return f" [{sc.number(est.low)}, {sc.number(est.high)}]"


def change_text(f: FigureChange, sc: fg.Scale, with_unit: bool = False) -> str:
    """`+316 (+373%)` (`+316 µs (+373%)` `with_unit`): how much a compared figure moved, in the scale of its row.

    One minus sign, U+2212, as in every number the report writes.
    """
    if f.base is None or f.new is None:
        return "–"
    delta = f.new - f.base
    text = sc.number(delta, sign=True) + (f" {sc.unit}" if with_unit and sc.unit else "")
    if f.base:
        percent = fg.scale(fg.Unit.COUNT).number(delta / abs(f.base) * 100, sign=True)
        text += f" ({percent}%)"
    return text


def render_comparison(cmp: Comparison, base_name: str, new_name: str) -> Markdown:
    """The comparison as a markdown section (`## Comparison with the baseline`)."""
    text = environment().get_template("compare.md.j2").render(c=build_comparison(cmp, base_name, new_name))
    return Markdown(re.sub(r"\n{3,}", "\n\n", text).strip("\n") + "\n")
