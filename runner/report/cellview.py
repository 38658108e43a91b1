"""A finished cell as the terminal shows it: the ps-style table, a per-thread summary, verdicts.

Pure text (the caller hands it to `runner.terminal.say`): the same selection of rows as the
report (`runner.report.selection`) and the same words for a figure (`runner.report.fmt`), cut
to what a terminal holds.  It lives with the report, not with the writer, so the writer at
the bottom of the house imports nothing of the stages above it.
"""

from __future__ import annotations

from runner import figures as fg
from runner.printable import for_terminal
from runner.report.fmt import fmt_figure, samples_words
from runner.report.selection import TERMINAL_ROWS, lines_shown, ps_rows_shown, threads_shown, verdicts_shown
from runner.results.document import CellResult
from runner.results.pstable import render_ps

_MARK = {"passed": "passed", "degraded": "DEGRADED", "failed": "FAILED", "error": "ERROR", "interrupted": "INTERRUPTED"}  # by Status value


def _cell_value(value: fg.Number | None, fig: fg.Figure) -> str:
    """A figure in the terminal's table: durations in us (the header says so), means to two places."""
    if value is None:
        return "-"
    if fig.is_duration:
        return f"{value / 1000:.1f}"
    if fig.unit is fg.Unit.PER_CALLBACK:
        return f"{value:.2f}"
    return f"{value:.1f}" if fig.unit is fg.Unit.PER_SECOND else str(value)


def _callbacks(cell: CellResult) -> list[str]:
    """The ROS 2 callbacks of the cell's programs, a row each (the registry's columns a callback has), the most shown."""
    if not cell.callbacks:
        return []
    from tabulate import tabulate

    overloaded = not all(fg.kept_up(c.figures) for c in cell.callbacks)
    shown = [f for f in fg.REGISTRY if f.column and fg.has(fg.CALLBACK, f) and (overloaded or not f.overload)]
    headers = ["callback", "threads"] + [f"{f.column} us" if f.is_duration else str(f.column) for f in shown]
    rows = [
        [for_terminal(c.label), ",".join(str(t.tid) for t in c.threads)] + [_cell_value(fg.value(c.figures, f), f) for f in shown]
        for c in cell.callbacks[:TERMINAL_ROWS]
    ]
    out = ["", *("  " + line for line in tabulate(rows, headers=headers, tablefmt="simple", disable_numparse=True).splitlines())]
    if len(cell.callbacks) > TERMINAL_ROWS:
        out.append(f"  ({len(cell.callbacks) - TERMINAL_ROWS:,} more callbacks: see the report or results.json)")
    return out


def render_cell(cell: CellResult, pid_width: int = 5) -> str:
    """Thread table, per-thread summary (the registry's figures that have a column), verdicts and degradations.

    Every name and reason in it (from the scenario, the kernel, a results file) as `for_terminal` shows it.
    """
    from tabulate import tabulate  # only when a cell is drawn: `runner --list` and the rest never need it

    warned = f", {len(cell.warnings)} warning{'s' if len(cell.warnings) > 1 else ''}" if cell.warnings else ""
    reason = f" - {cell.reason}" if cell.reason else ""
    out = [for_terminal(f"cell {cell.id}: {_MARK[cell.status.value]}{warned} ({cell.duration_s:.1f}s){reason}")]
    picked = threads_shown(cell, TERMINAL_ROWS)
    if cell.thread_table:
        ps_rows, _ = ps_rows_shown(cell.thread_table, picked)
        out.append("")
        out.extend("  " + line for line in render_ps(ps_rows, pid_width=pid_width).splitlines())
    periodic = [t for t in picked.threads if t.has_callbacks]
    if periodic:
        overloaded = not all(fg.kept_up(t.figures) for t in periodic)
        shown = [f for f in fg.REGISTRY if f.column and (overloaded or not f.overload)]
        headers = ["thread", "tid", "applied"] + [f"{f.column} us" if f.is_duration else str(f.column) for f in shown]
        rows = [
            [
                for_terminal(f"{t.name}{' (main)' if t.index == 0 else ''}"),
                str(t.tid),
                ", ".join(s.label() for s in t.callback_settings()) or "?",  # as read back where its callbacks ran
            ]
            + [_cell_value(fg.value(t.figures, f), f) for f in shown]
            for t in periodic
        ]
        out.append("")
        out.extend("  " + line for line in tabulate(rows, headers=headers, tablefmt="simple", disable_numparse=True).splitlines())
    if picked.hidden:
        out.append(f"  ({picked.note()})")
    out += _callbacks(cell)
    verdicts, more = verdicts_shown(cell.expectations, TERMINAL_ROWS)
    for v in verdicts:
        if v.unmeasured:  # said in place of the value: "measured not measured" reads as nothing
            said = f"{v.thread}: {v.metric} {v.limit}: {v.unmeasured}"
        else:
            measured = fmt_figure(v.measured, v.figure.unit)
            if v.samples is not None:
                measured += f", of {samples_words(v.figure, v.samples)}"
            said = f"{v.thread}: {v.metric} {v.limit} (measured {measured}){' - ' + v.note if v.note else ''}"
        out.append(f"  {'ok  ' if v.passed else 'FAIL'} {for_terminal(said)}")
    if more:
        failed = sum(not v.passed for v in cell.expectations) - sum(not v.passed for v in verdicts)
        out.append(f"  ... {more:,} more verdicts ({failed:,} of them failed): see the report or results.json")
    degraded, more = lines_shown([f"{t.process}/{t.name}: {why}" for t in cell.threads for why in t.degraded], TERMINAL_ROWS)
    out.extend(f"  DEGRADED {for_terminal(line)}" for line in degraded)
    if more:
        out.append(f"  ... {more:,} more degraded settings: see the report or results.json")
    warnings, more = lines_shown(cell.warnings, TERMINAL_ROWS)
    out.extend(f"  WARNING {for_terminal(text)}" for text in warnings)
    if more:
        out.append(f"  ... {more:,} more warnings: see the report or results.json")
    return "\n".join(out) + "\n"
