"""A night's verdicts against its history as the report's section and the terminal's headline.  Pure.

`## Against the history`: a headline (regressions first, or what was judged and how many nights it
stood on), the night's notes (cells whose spec changed), the regressions and changes of level (and those continued) with
their words, and every figure judged.
"""

from __future__ import annotations

from runner.history.judge import FAILED, FigureVerdict, NightVerdict, Verdict, change_point_detection
from runner.history.store import shown
from runner.report.fmt import LEFT, RIGHT, Markdown, md_text
from runner.report.tables import Table

ICON = {
    Verdict.REGRESSION: "❌ regression",
    Verdict.MISSING: "❌ missing",
    Verdict.BETTER: "🟢 better",
    Verdict.WITHIN: "✅ within history",
    Verdict.CONTINUING: "↪️ continuing a change",
    Verdict.LEARNING: "📚 learning",
    Verdict.NEW: "🆕 new",
    Verdict.FEW: "⏸️ not judged",
}


def headline(verdict: NightVerdict, target: str) -> str:
    """One line for the terminal and the section: how the night stands against its history."""
    failed = [f for f in verdict.figures if f.verdict in FAILED]
    judged = [f for f in verdict.figures if f.verdict in (Verdict.WITHIN, Verdict.BETTER, Verdict.REGRESSION)]
    learning = sum(f.verdict in (Verdict.LEARNING, Verdict.NEW) for f in verdict.figures)
    if failed:
        cells = list(dict.fromkeys(f.cell for f in failed))
        named = ", ".join(f"{f.figure.name} of {f.thread} ({f.cell})" for f in failed[:3])
        named += f" and {len(failed) - 3} more" if len(failed) > 3 else ""
        plural, cells_plural = "s" if len(failed) != 1 else "", "s" if len(cells) != 1 else ""
        text = f"❌ {len(failed)} regression{plural} against the history in {len(cells)} cell{cells_plural}: {named}."
    elif judged:
        most = max(f.nights for f in judged)
        text = f"✅ No regression against the history: {len(judged)} figures judged against up to {most} past nights."
    else:
        text = "Nothing judged against the history yet."
    if learning:
        text += f" {learning} figure{'s' if learning != 1 else ''} still learning (fewer than 5 past nights)."
    continuing = sum(f.verdict == Verdict.CONTINUING for f in verdict.figures)
    if continuing:
        text += f" {continuing} continuing a change reported on an earlier night."
    return text + f" (history: {shown(target)})"


def render(verdict: NightVerdict, target: str) -> Markdown:
    lines = ["## Against the history", "", md_text(headline(verdict, target)), ""]
    for note in verdict.notes:
        lines += [f"> {md_text(note)}", ""]
    if not change_point_detection():
        lines += [
            "> Changes of level are found by ruptures (`pip install 'runner[history]'`), not installed here: each figure's range "
            "is learnt from every night since its last reported change.",
            "",
        ]
    lines += [
        "> A night is a regression when a figure is past its threshold from its past nights' median, outside the range "
        "those nights vary within (their median and MAD, on a log scale, never narrower than their sampling error), with "
        "its own interval, at 1% family-wise over the night's figures (Holm). A change of level is reported once, on its "
        "first night, with what changed in the environment that night.",
        "",
    ]
    bad = [f for f in verdict.figures if f.verdict in (*FAILED, Verdict.BETTER, Verdict.CONTINUING)]
    if bad:
        lines += ["### Regressions and changes", "", _table(bad).render(), ""]
    if verdict.figures:
        lines += ["<details><summary>Every figure judged</summary>", "", _table(verdict.figures).render(), "", "</details>", ""]
    return Markdown("\n".join(lines).rstrip("\n") + "\n")


def _table(items: list[FigureVerdict]) -> Table:
    rows = [
        [
            f.cell,
            f.thread,
            f.figure.name,
            str(f.nights) if f.nights else "–",
            ICON[f.verdict],
            f.words or "–",
        ]
        for f in items
    ]
    return Table(["Cell", "Thread", "Figure", "Nights", "Verdict", "Why"], rows, [LEFT, LEFT, LEFT, RIGHT, LEFT, LEFT])
