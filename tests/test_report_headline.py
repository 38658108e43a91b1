"""The report leads with its verdict: the headline, the facts collapsed at the end, paths, narrow tables, the job summary."""

from __future__ import annotations

import copy
import os
import re

from reportdata import matrix, traced, with_figures

from runner.report import fmt
from runner.report import markdown as report
from runner.report.compare import compare
from runner.report.publish import append_step_summary, without_empty_headings

GOLDEN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "golden")
REPORTS = sorted(name for name in os.listdir(GOLDEN) if name.endswith(".md") and name != "comparison.md")
VERDICT = re.compile(r"^\*\*(✅ passed|⚠️ degraded|❌ failed|❌ regressed|💥 error|⏸️ interrupted|⏳ running)\*\*: ", re.M)


def _golden(name: str) -> str:
    with open(os.path.join(GOLDEN, name), encoding="utf-8") as handle:
        return handle.read()


def _head(text: str, lines: int = 20) -> str:
    return "\n".join(text.splitlines()[:lines])


def test_the_golden_reports_are_the_runs_the_layout_needs():
    assert {"policy_matrix.md", "memory_lock.md", "traced.md", "own_program.md"} <= set(REPORTS)


def test_the_first_20_lines_of_every_report_hold_its_verdict():
    for name in REPORTS:
        text = _golden(name)
        assert VERDICT.search(_head(text)), name
        assert "| Fact | Value |" not in _head(text, 40), name  # the machine's facts no longer come first


def test_each_failed_expectation_is_in_the_headline_with_its_file_and_line():
    doc = traced()
    failed = [v for cell in doc.cells for v in cell.expectations if not v.passed]
    assert failed and all(v.line for v in failed)
    head = _head(report.render_run(doc))
    assert "**❌ failed**: 1 cell run (1 failed); 1 of 2 expectations failed" in head
    for v in failed:
        assert f"`tests/valid/traced.yaml:{v.line}`: ctl/ctl (main): " in head
    assert "measured 30.5 µs" in head


def test_an_implicit_expectation_has_the_file_alone_and_many_failures_are_counted():
    doc = traced()
    cell = doc.cells[0]
    v = next(v for v in cell.expectations if not v.passed)
    cell.expectations += [v.model_copy(update={"line": None, "col": None, "metric": "missed_releases"})]
    cell.expectations += [v.model_copy(update={"line": 100 + n}) for n in range(20)]
    head = _head(report.render_run(doc))
    assert re.search(r"^- ❌ `tests/valid/traced\.yaml`: ctl/ctl \(main\): ", head, re.M)  # no line: the file
    listed = [line for line in head.split("\n## ")[0].splitlines() if line.startswith("- ")]
    assert len(listed) == 10 and listed[-1].startswith("- … 13 more: see the cells' Expectations below")


def test_a_regression_makes_a_passed_run_regressed_and_is_listed_first():
    base = matrix()
    new = with_figures(base, "policy=rr,priority=80", invol_mean=1.0)
    cmp = compare(base, new)
    assert cmp.regressions
    head = _head(report.render_run(new, compared=cmp))
    assert "**❌ regressed**: 5 cells run (5 passed); 9 of 9 expectations met; " in head
    assert re.search(r"^- 📉 `scenarios/policy_matrix\.yaml`: regression: cell policy=rr,priority=80: .*involuntary", head, re.M)
    clean = _head(report.render_run(base, compared=compare(base, copy.deepcopy(base))))
    assert "**✅ passed**: 5 cells run (5 passed); 9 of 9 expectations met; no regression" in clean


def test_the_machine_facts_are_collapsed_at_the_end_with_the_kernel_command_line():
    text = _golden("traced.md")
    details = text.index("<details>")
    assert text.rstrip().endswith("</details>") and details > text.rindex("\n## ")
    assert text.index("| Kernel command line |") > details and text.index("| Command |") > details
    assert text.count("| Fact | Value |") == 1


def test_paths_are_relative_to_the_working_directory():
    doc = traced()
    doc.command = ["runner", "/home/ci/work/repo/tests/valid/traced.yaml", "--out=/home/ci/work/repo/out", "--junit", "/tmp/j.xml"]
    doc.scenario.path = "/home/ci/work/repo/tests/valid/traced.yaml"
    text = report.render_run(doc, cwd="/home/ci/work/repo")
    assert "`runner tests/valid/traced.yaml --out=out --junit /tmp/j.xml`" in text  # outside the directory: as given
    assert "traced (`tests/valid/traced.yaml`)" in text and "`tests/valid/traced.yaml:" in _head(text)
    assert "/home/ci" not in text
    assert fmt.relative_path("/home/ci/work/repo", "/home/ci/work/repo/") == "."
    assert fmt.relative_path("/home/ci/work/repository/x", "/home/ci/work/repo") == "/home/ci/work/repository/x"


def test_a_column_empty_in_every_row_is_dropped():
    """The runner's own threads have no rule, no rates and no CPU time from /proc: those columns are gone, not dashes."""
    text = _golden("traced.md")
    assert "| Rule |" not in text and "Involuntary / s" not in text and "| Thread | – |" not in text
    assert "| Thread | Migrations | Preemptions | Wake-ups traced | Waking to running p50 (µs) | p99 (µs) | max (µs) |" in text
    program = _golden("own_program.md")
    assert "| Thread | Involuntary / s | Voluntary / s | CPU time (ms) |" in program


def test_markdown_lines_are_not_padded_to_the_widest_cell():
    table = fmt.pipe_table(["Thread", "Value"], [["a", "x" * 300], ["b", "1"]], [fmt.LEFT, fmt.RIGHT])
    assert table.splitlines() == ["| Thread | Value |", "|:---|---:|", f"| a | {'x' * 300} |", "| b | 1 |"]
    for name in REPORTS:
        for line in _golden(name).splitlines():
            assert "  |" not in line or line.startswith(("```", " ")), (name, line)


def test_no_report_and_no_job_summary_has_an_empty_heading(tmp_path):
    plots = [report.Plot("Wake-up latency", "plots/latency.png")]
    summary = tmp_path / "summary.md"
    append_step_summary(report.render_run(traced(), plots), {"GITHUB_STEP_SUMMARY": str(summary)})
    text = summary.read_text(encoding="utf-8")
    assert "![" not in text and "## Plots" not in text  # its images don't travel, so neither does their heading
    assert VERDICT.search(_head(text)) and "`tests/valid/traced.yaml:" in _head(text)
    for name, markdown in [(n, _golden(n)) for n in REPORTS] + [("summary", text)]:
        lines = markdown.splitlines()
        assert without_empty_headings(lines) == markdown.rstrip("\n") + "\n", name


def test_empty_headings_go_and_nothing_else():
    lines = "# t\n\na\n\n## Plots\n\n## Cell\n\nx\n```\n## not a heading\n```\n\n## Empty\n\n### Empty too\n".splitlines()
    assert without_empty_headings(lines) == "# t\n\na\n\n## Cell\n\nx\n```\n## not a heading\n```\n"


def test_an_expectation_failed_in_several_cells_is_one_line_naming_them():
    doc = matrix()
    for cell in doc.cells[:3]:
        cell.expectations[0] = cell.expectations[0].model_copy(update={"passed": False, "line": 30, "col": 5})  # v1 kept no line
    head = _head(report.render_run(doc))
    listed = [row for row in head.split("\n## ")[0].splitlines() if row.startswith("- ")]
    assert listed == [
        "- ❌ `scenarios/policy_matrix.yaml:30`: minimal_schedul/minimal_schedul (main): involuntary.per_callback_mean <= 0.5: "
        "in 3 cells (policy=fifo,priority=10, policy=fifo,priority=80, policy=rr,priority=10); in cell policy=fifo,priority=10: "
        "minimal_schedul/minimal_schedul (main): involuntary switches per callback <= 0.5, measured 0.00"
    ], listed
