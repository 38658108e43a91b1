"""Tables that do not grow with threads: which threads a large cell shows, on the terminal and in the report."""

from __future__ import annotations

from pathlib import Path

from reportdata import many_threads
from test_report import tables

from runner.report import selection
from runner.report.cellview import render_cell
from runner.report.publish import write_report
from runner.results.document import Verdict, ps_rows
from runner.results.pstable import ThreadRow


def big_cell(tmp_path: Path, threads: int = 100):
    doc = many_threads(str(tmp_path / "run"), threads=threads, processes=4, callbacks=20)
    return doc, doc.cells[0]


def test_a_small_cell_shows_every_thread_and_says_nothing(tmp_path):
    _, cell = big_cell(tmp_path, threads=12)
    shown = selection.threads_shown(cell, 24)
    assert shown.threads == list(cell.threads) and shown.hidden == 0 and shown.note() == ""


def test_a_large_cell_shows_the_threads_that_matter_before_the_worst_latency(tmp_path):
    _, cell = big_cell(tmp_path)
    quiet = [t for t in cell.threads if t.periodic][:3]  # the lowest worst latencies: never among the worst
    failing, degraded, behind = quiet
    cell.expectations = [
        Verdict(thread=failing.label(True), metric="latency.p99", limit="<= 1us", measured=50_000, passed=False),
        Verdict(thread=quiet[1].label(True), metric="latency.p99", limit="<= 1ms", measured=50_000, passed=True),
    ]
    degraded.degraded = ["fifo:80 requested, other applied (Operation not permitted)"]
    behind.figures = behind.figures.model_copy(update={"missed_releases": 3})
    shown = selection.threads_shown(cell, 24)
    assert len(shown.threads) == 24 and shown.hidden == len(cell.threads) - 24
    assert {id(failing), id(degraded), id(behind)} <= {id(t) for t in shown.threads}
    order = [id(t) for t in cell.threads]
    assert [id(t) for t in shown.threads] == sorted((id(t) for t in shown.threads), key=order.index), "in the cell's order"
    rest = [t for t in shown.threads if t not in quiet]
    worst = sorted((t.figures.latency_ns.p99 for t in cell.threads if t.periodic and t not in quiet), reverse=True)[:21]
    assert sorted(t.figures.latency_ns.p99 for t in rest) == sorted(worst), "then the worst wake-up latency p99"
    assert "24 of 100 threads shown" in shown.note() and "all 100 are in results.json" in shown.note()


def test_the_terminal_summary_of_a_large_cell_stays_short(tmp_path):
    _, cell = big_cell(tmp_path, threads=400)
    cell.thread_table = ps_rows(ThreadRow(4000, 4000 + n, "cb", 0, 0, 0, n % 2, 120, (0, 1)) for n in range(401))
    for n, t in enumerate(cell.threads):
        t.tid = 4000 + n
    cell.expectations = [
        Verdict(thread=t.label(True), metric="missed_releases", limit="<= 0", measured=1, passed=False) for t in cell.threads
    ]
    cell.warnings = [f"{t.label(True)} could not keep up" for t in cell.threads]
    text = render_cell(cell)
    lines = text.splitlines()
    assert len(lines) < 4 * selection.TERMINAL_ROWS + 20, len(lines)
    assert f"{selection.TERMINAL_ROWS} of {len(cell.threads)} threads shown" in text
    assert f"... {len(cell.threads) - selection.TERMINAL_ROWS:,} more verdicts" in text and "more warnings" in text
    assert sum(line.startswith("  FAIL") for line in lines) == selection.TERMINAL_ROWS


def test_the_report_section_of_a_large_cell_has_a_bounded_table_and_says_so(tmp_path):
    doc, _ = big_cell(tmp_path, threads=100)
    text = Path(write_report(doc, str(tmp_path / "run"))).read_text(encoding="utf-8")
    assert f"{selection.REPORT_ROWS} of 100 threads shown" in text
    assert len(tables(text)[1]) == selection.REPORT_ROWS + 1, "the cell's thread table holds the threads shown, not all 100"
