"""The markdown report of a run: the per-cell sections and the report's model, with its public entry points.

Pure: a results document in, markdown out (no file access).  The layout lives in
`templates/report.md.j2`; this module gathers the rows into the model the template
arranges.  The report leads with its verdict (`headline`: passed, failed or regressed, and each
failure with its `file:line`), then the findings, the tables, the cells (each with its verdicts
first), and closes with the machine's facts in a collapsed block.  What a cell shows about its
programs beyond every thread's tables is added in one place, `program_sections`.  The words
live in `findings`, the tables (the facts among them) (GitHub-flavoured markdown from
`fmt.pipe_table`, not tabulate, which is too slow for a 1,000-cell report) in `tables`, the
comparison with a baseline in `compareview`; the names callers use are re-exported here
(`render_run`, `render_comparison`, `build_comparison`, `Table`, `Plot`, ...).
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from runner.report import system
from runner.report.callbackview import callback_tables
from runner.report.compareview import build_comparison, change_text, interval_ends, interval_text, render_comparison
from runner.report.findings import (
    ICON,
    callback_threads,
    cell_finding,
    entries_by_thread,
    figure,
    first_runs,
    matrix_finding,
    policy_label,
    thread_finding,
    thread_labels,
)
from runner.report.fmt import Markdown, environment, md_code, md_code_block, md_text
from runner.report.headline import Headline, headline
from runner.report.selection import REPORT_ROWS, lines_shown, ps_rows_shown, threads_shown
from runner.report.tables import (
    Table,
    across_cells,
    anchor,
    events_table,
    facts,
    faults_table,
    latency_table,
    outside_tables,
    phases_table,
    preemption_lines,
    program_lines,
    section_title,
    spread_table,
    summary_tables,
    switches_table,
    threads_table,
    timing_table,
    trace_line,
    verdict_table,
)
from runner.results.document import Background, BackgroundKind, CellResult, RunDocument
from runner.results.pstable import render_ps

if TYPE_CHECKING:
    from runner.history.judge import NightVerdict
    from runner.report.compare import Comparison

__all__ = [  # the face of the report: what callers (publish, the CLI, plots, outcomes, tests) take from here
    "MAX_THREAD_VIEWS",
    "Plot",
    "ReportModel",
    "Table",
    "build",
    "build_comparison",
    "change_text",
    "interval_ends",
    "interval_text",
    "matrix_order",
    "policy_label",
    "preemption_lines",
    "program_lines",
    "render",
    "render_comparison",
    "render_run",
    "thread_finding",
    "thread_labels",
    "threads_of_interest",
    "threads_table",
    "trace_line",
]

MAX_SIDE_BY_SIDE = 12  # cells shown in a thread's across-cells view; beyond that the summary table serves

# ---------------------------------------------------------------- the report


@dataclass(frozen=True)
class Plot:
    title: str
    path: str  # relative to the report


@dataclass(frozen=True)
class Block:
    """A captioned table in a cell's section, about its programs (`program_sections`)."""

    caption: Markdown
    table: Table


@dataclass
class CellSection:
    cell: CellResult
    title: str
    anchor: str
    icon: str
    finding: Markdown
    ps: Markdown | None
    threads: Table
    switches: Table
    latency: Table | None
    timing: Table | None
    faults: Table
    blocks: list[Block]
    verdicts: Table | None
    degraded: list[str]
    load: Markdown
    programs: list[Markdown] = field(default_factory=list)
    outside: Table | None = None  # from /proc
    traced: Table | None = None  # from the scheduler trace
    preemptions: list[str] = field(default_factory=list)
    trace: str | None = None
    warnings: list[str] = field(default_factory=list)
    shown: str = ""  # which threads the tables show, when not every one


@dataclass
class ThreadView:
    """One periodic thread of interest across the cells of a matrix: its figures in a row per cell."""

    label: str
    tables: list[tuple[str, Table]]  # (caption, table)
    cells: int


@dataclass
class ReportModel:
    title: str
    headline: Headline
    description: str
    facts: Table
    findings: list[Markdown]
    summary: list[Table]
    spread: Table | None
    threads: list[ThreadView]
    sections: list[CellSection]
    comparison: Markdown | None = None
    notes: list[str] = field(default_factory=list)
    plots: list[Plot] = field(default_factory=list)
    plots_note: Markdown | None = None  # why there are no plots, when they were asked for


def _load_line(cell: CellResult) -> Markdown:
    hogs = [b for b in cell.background if b.kind is BackgroundKind.HOG]
    commands = [b for b in cell.background if b.kind is BackgroundKind.COMMAND]
    parts = []
    if hogs:
        parts.append(f"{len(hogs)} busy-loop hog{'s' if len(hogs) != 1 else ''}")
    parts += [_command(c) for c in commands]
    return Markdown(", ".join(parts) or "none")


def _command(c: Background) -> str:
    """A background command as the load line names it: `stress-ng --cpu 2`, or by its name when the scenario gave it one."""
    line = md_code(shlex.join(c.argv))
    return f"{md_text(c.name)} ({line})" if c.name and c.argv and c.name != c.argv[0] else line


def program_sections(cell: CellResult, labels: dict[str, str]) -> list[Block]:
    """What a cell's section shows about its programs beyond the tables every thread has, in order: the one place a
    section about programs is added (a call each), shown after the thread tables and before the page faults."""
    blocks = []
    events = events_table(cell, labels)
    if events is not None:
        blocks.append(
            Block(
                Markdown(
                    "Events of each program (`kind: phases`): a lock's wait and who held the mutex, a timer's or a resume's "
                    "wake-up latency, the wall time of the rest"
                ),
                _compact(events),
            )
        )
    phases = phases_table(cell, labels)
    if phases is not None:
        caption = "Phases of each program, with the settings the thread read back from the kernel as it entered each one"
        blocks.append(Block(Markdown(caption), _compact(phases)))
    blocks += [Block(caption, _compact(table)) for caption, table in callback_tables(cell)]
    return blocks


def _compact(t: Table) -> Table:
    """`t` without the columns empty in every row (`Table.compact`), or as it is when only its first would be left."""
    return t.compact() or t


def _section(cell: CellResult, labels: dict[str, str], repeated: bool, pid_width: int) -> CellSection:
    picked = threads_shown(cell, REPORT_ROWS)
    rows = [(labels[t.key], t) for t in picked.threads]
    ps_rows, _ = ps_rows_shown(cell.thread_table, picked)
    warnings, more_warnings = lines_shown(cell.warnings, REPORT_ROWS)
    degraded, more_degraded = lines_shown([f"{labels[t.key]}: {why}" for t in cell.threads for why in t.degraded], REPORT_ROWS)
    latency, timing, verdicts = latency_table(rows), timing_table(rows), verdict_table(cell)
    outside, traced = outside_tables(rows)
    return CellSection(
        cell=cell,
        title=section_title(cell, repeated),
        anchor=anchor(cell, repeated),
        icon=ICON[cell.status],
        finding=cell_finding(cell, labels),
        ps=md_code_block(render_ps(ps_rows, pid_width=pid_width), "text") if cell.thread_table else None,
        threads=_compact(threads_table(rows)),
        switches=_compact(switches_table(rows)),
        latency=_compact(latency) if latency else None,
        timing=_compact(timing) if timing else None,
        faults=_compact(faults_table(rows)),
        blocks=program_sections(cell, labels),
        verdicts=verdicts,
        degraded=degraded + ([f"... {more_degraded:,} more: see results.json"] if more_degraded else []),
        warnings=warnings + ([f"... {more_warnings:,} more warnings: see results.json"] if more_warnings else []),
        shown=picked.note(),
        load=_load_line(cell),
        programs=program_lines(cell),
        outside=outside,
        traced=traced,
        preemptions=preemption_lines(rows),
        trace=trace_line(cell),
    )


def matrix_order(doc: RunDocument) -> list[CellResult]:
    """The cells in the matrix's order (repeats after their first run), not the order they ran in."""
    order = {cell_id: i for i, cell_id in enumerate(doc.matrix_cells)}
    return sorted(doc.cells, key=lambda c: (order.get(c.id, len(order)), c.repeat))


MAX_THREAD_VIEWS = 4  # periodic threads shown across cells and plotted one by one: the worst by wake-up p99


def threads_of_interest(cells: Sequence[CellResult], most: int = MAX_THREAD_VIEWS) -> list[str]:
    """The keys of the periodic threads worth a view of their own: the `most` with the highest wake-up p99 in any cell.

    A matrix of one callback thread shows it; a cell of 256 threads shows the few that did worst,
    so what the report draws does not grow with the threads (every thread stays in the tables).
    Ties keep the order the threads first appear in.
    """
    worst: dict[str, float] = {}
    for cell in cells:
        for t in callback_threads(cell):
            p99 = figure(t, "latency.p99")
            worst[t.key] = max(worst.get(t.key, -1.0), float(p99) if p99 is not None else -1.0)
    order = {key: i for i, key in enumerate(worst)}
    return sorted(worst, key=lambda key: (-worst[key], order[key]))[:most]


def build(
    doc: RunDocument,
    plots: Sequence[Plot] | None = None,
    comparison: str | None = None,
    pid_width: int = 5,
    plots_note: Markdown | None = None,
    compared: Comparison | None = None,
    history: NightVerdict | None = None,
    cwd: str | None = None,
) -> ReportModel:
    """Everything the template shows, as text and tables; `plots` are the plot files drawn beside the report.

    `comparison` is the comparison's section (markdown); `compared` and `history` the comparison and the judgement
    against the past nights it words, whose regressions the headline lists; paths are shown relative to `cwd`.
    """
    cells = matrix_order(doc)
    labels = thread_labels(cells)
    repeated = any(c.repeat for c in cells)
    firsts = first_runs(cells)
    matrix = len(firsts) > 1
    threads = []
    by_thread = entries_by_thread(firsts)
    if matrix:
        for key in threads_of_interest(firsts):
            entries = by_thread[key]
            if len(entries) > 1:
                views = [(caption, _compact(t)) for caption, t in across_cells(entries[:MAX_SIDE_BY_SIDE])]
                threads.append(ThreadView(labels[key], views, len(entries)))
    sections = [_section(cell, labels, repeated, pid_width) for cell in cells]
    findings = matrix_finding(firsts, labels) if matrix else []
    if not findings:
        findings = [
            Markdown(f"{md_text(cell.id)}: {cell_finding(cell, labels)}") if matrix else cell_finding(cell, labels) for cell in firsts
        ]
    findings += system.placement_findings(cells, doc.machine, labels, matrix)
    if repeated:
        findings.append(
            Markdown(
                "Cells ran more than once: the across-cells views and these findings show each cell's "
                "first run; the spread table shows every repeat."
            )
        )
    notes = []
    if any(v.cells > MAX_SIDE_BY_SIDE for v in threads):
        notes.append(f"The across-cells views show the first {MAX_SIDE_BY_SIDE} cells; the summary table has them all.")
    shown_keys = set(threads_of_interest(firsts)) if matrix else set()
    if matrix and len(by_thread) > len(shown_keys):
        notes.append(
            f"Across cells: the {len(shown_keys)} periodic threads with the highest wake-up p99, of {len(by_thread)}; "
            "each cell's tables list every thread."
        )
    return ReportModel(
        title=f"{doc.name}: scheduling report",
        headline=headline(doc, compared, history, cwd),
        description=doc.scenario.description,
        facts=facts(doc, cwd),
        findings=findings,
        summary=[_compact(t) for t in summary_tables(cells, repeated)] if len(cells) > 1 else [],
        spread=spread_table(cells, labels),
        threads=threads,
        sections=sections,
        comparison=Markdown(comparison) if comparison else None,
        notes=notes,
        plots=list(plots or []),
        plots_note=plots_note,
    )


def render(model: ReportModel) -> str:
    """The report as markdown."""
    return re.sub(r"\n{3,}", "\n\n", environment().get_template("report.md.j2").render(r=model))


def render_run(
    doc: RunDocument,
    plots: Sequence[Plot] | None = None,
    comparison: str | None = None,
    pid_width: int = 5,
    plots_note: Markdown | None = None,
    compared: Comparison | None = None,
    history: NightVerdict | None = None,
    cwd: str | None = None,
) -> str:
    return render(build(doc, plots, comparison, pid_width, plots_note, compared, history, cwd))
