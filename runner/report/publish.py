"""Write a run's report files: report.md and its plots beside results.json, the CI job summary, JUnit XML and annotations.

The I/O half of reporting; `report` renders and `plots` draws.  Files are replaced
atomically, so a reader never sees half a report, and never through a link (runner/safefs.py).
"""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING, Optional

from runner.collector import collector_paused
from runner.errors import OutputError, RunnerError, from_os_error
from runner.outdir import REPORT_NAME
from runner.report import github
from runner.report import markdown as report
from runner.report.compare import Comparison, Threshold, compare
from runner.report.fmt import terminal_text
from runner.report.junit import junit_xml
from runner.results.document import RunDocument, Status
from runner.results.read import load
from runner.safefs import append, write_atomic, write_named
from runner.terminal import note, say, warn

if TYPE_CHECKING:
    from runner.history.judge import NightVerdict

STEP_SUMMARY_LIMIT = 1_000_000  # GitHub refuses job summaries over 1 MiB


def write_report(
    doc: RunDocument, folder: str, comparison: Optional[str] = None, plots: bool = True, pid_width: int = 5, name: str = REPORT_NAME
) -> str:
    """Render `doc` to `folder`/report.md (with plots under `folder`/plots); return the report's path.

    Without matplotlib (plotting is an extra) the report says the plots were skipped and why,
    and so does a warning; `plots=False` (`--no-plots`) draws none and says nothing.  Plots
    that fail to draw are skipped the same way, saying why (`report_files`): the report, and
    the JUnit file written after it, are the run's outcome, and a plot is never worth losing them.
    A plot that could not be written (a full disk) is raised as the OutputError it is, once the
    report is written.
    """
    path, failed = report_files(doc, folder, comparison, plots, pid_width, name)
    if isinstance(failed, OutputError):
        raise failed
    return path


def report_files(
    doc: RunDocument,
    folder: str,
    comparison: Optional[str] = None,
    plots: bool = True,
    pid_width: int = 5,
    name: str = REPORT_NAME,
    quiet_input_errors: bool = False,
    named: bool = False,
    compared: Optional[Comparison] = None,
    history: Optional[NightVerdict] = None,
) -> tuple[str, Optional[RunnerError]]:
    """`write_report`, and the error the plots failed with when it is the input's (a samples file that cannot be read)
    or the output's (an OutputError: a plot file that could not be written, a full disk).

    Whatever makes a plot fail (those errors, or a bug in the runner) is caught here: the report
    is written without plots and says why, and so does a warning.  `runner report`, whose output
    the plots are, passes `quiet_input_errors` to say an input error itself, as its error, once
    the report is written; a run's outcome is its cells, and the warning says it there.  An output
    error is never a warning: every caller raises it once what it writes after the plots is written.
    `named`: the report's file is one the user named (`runner report -o FILE`), written as such
    (safefs.write_named: /dev/null is written into); else it is the results folder's report.md.
    `compared` and `history`: the comparison and the judgement against past nights that `comparison` words, whose
    regressions the report's headline lists.  Paths in the report are relative to the working directory.
    """
    from runner.report import plots as drawing  # matplotlib itself only when a plot is drawn

    links: list[report.Plot] = []
    skipped = None
    failed: Optional[RunnerError] = None
    if plots and drawing.available():
        try:
            links = drawing.write_plots(doc, folder, report.thread_labels(doc.cells))
        except Exception as exc:  # any failure: said in the report and a warning, never the report lost for it
            failure: Exception = exc
            if isinstance(exc, OSError) and exc.filename is not None:  # a plot file, or the plots folder, that could not be written
                failure = from_os_error(exc, "cannot write the plot", before_run=False)
            skipped = drawing.skipped_note(failure)
            failed = failure if isinstance(failure, RunnerError) else None
            if failed is None or not (quiet_input_errors or isinstance(failed, OutputError)):
                warn(skipped)
    elif plots:
        skipped = drawing.skipped_note()
        warn(skipped)
    with collector_paused():
        text = report.render_run(doc, links, comparison, pid_width, skipped, compared, history, os.getcwd())
    path = os.path.join(folder, name)
    (write_named if named else write_atomic)(path, text)
    return path, failed


def append_step_summary(text: str, env: dict[str, str]) -> Optional[str]:
    """Append `text` to $GITHUB_STEP_SUMMARY when it is set (GitHub Actions); return the file's path."""
    path = env.get("GITHUB_STEP_SUMMARY")
    if not path:
        return None
    text = without_empty_headings([line for line in text.splitlines() if not line.startswith("![")])  # plots don't travel
    if len(text.encode()) > STEP_SUMMARY_LIMIT:
        cut = text.encode()[: STEP_SUMMARY_LIMIT - 200].decode(errors="ignore")
        text = cut[: cut.rfind("\n## ")] + "\n\n> Report cut to fit the job summary; the full report is in the artifacts.\n"
    try:
        append(path, text.rstrip("\n") + "\n\n")  # never through a link: one planted there would carry the summary anywhere
    except OSError as exc:  # the summary is a copy: the run's own files are written, so warn, do not fail
        warn(f"cannot append to GITHUB_STEP_SUMMARY {path}: {exc.strerror or exc}")
        return None
    return path


def without_empty_headings(lines: list[str]) -> str:
    """`lines` as text, without the headings that head nothing (the next heading, of the same level or above, or the
    end, follows it): a job summary's `## Plots` once its images are left out.  Lines in code blocks are no headings."""
    out: list[str] = []
    fence = ""
    pending: list[int] = []  # indexes in `out` of headings with nothing under them yet, outermost first
    for line in lines:
        marker = re.match(r" {0,3}(`{3,}|~{3,})", line)
        if fence:
            fence = "" if marker and marker.group(1).startswith(fence) and not line.strip().strip(fence[0]) else fence
        elif marker:
            fence = marker.group(1)
        heading = None if fence or marker else re.match(r" {0,3}(#{1,6})(\s|$)", line)
        if heading:
            level = len(heading.group(1))
            while pending and _level(out[pending[-1]]) >= level:  # closed with nothing under it
                del out[pending.pop() :]
            pending.append(len(out))
        elif line.strip():
            pending = []
        out.append(line)
    for at in reversed(pending):
        del out[at:]
    return "\n".join(out).rstrip("\n") + "\n"


def _level(heading: str) -> int:
    return len(heading.strip().split(" ", 1)[0])


def compare_files(base_path: str, doc: RunDocument, new_path: str, thresholds: list[Threshold]) -> tuple[str, Comparison]:
    """Compare `doc` with the results at `base_path`: the markdown section and the comparison itself."""
    base = load(base_path)
    cmp = compare(base, doc, thresholds, base_name=base_path, new_name=new_path)
    if cmp.other_version:  # every figure compared is of another version of the scenario: said where it is run too
        warn(f"{new_path}: {cmp.other_version}")
    return report.render_comparison(cmp, base_path, new_path), cmp


def comparison_statuses(cmp: Comparison, new_path: str) -> list[Status]:
    """What decides a comparison's exit code beside its regressions (`Comparison.statuses`), an incomplete run said on stderr.

    `runner compare` and `runner report --baseline` both take it, so they decide alike on the same files
    (docs/commands.md, "Exit codes"): a run that never finished is never green, whichever command compares it.
    """
    if cmp.incomplete:  # never green: what it lacks was never compared
        note(f"runner: {new_path}: {cmp.incomplete}; only the cells it holds were compared")
    return cmp.statuses()


def say_comparison(cmp: Comparison, base_name: str, new_name: str, where: str) -> None:
    """The comparison's headline on the terminal, in plain words, and the file that holds the rest (`where`).

    A CI log must say how the comparison went, not only report.md: a run's `passed` above an
    exit code of 1 read as a pass that failed.
    """
    headline = report.build_comparison(cmp, base_name, new_name).headline
    say(f"compared with {base_name}: {terminal_text(headline)} ({where})")


def ci_outputs(
    doc: RunDocument,
    comparison: Optional[Comparison],
    junit: Optional[str],
    env: dict[str, str],
    run: bool = True,
    history: Optional[NightVerdict] = None,
) -> None:
    """What CI systems read: the JUnit XML file (`--junit FILE`), and in GitHub Actions the workflow annotations.

    `run` False: a comparison alone (`runner compare`), without the cells' runs and expectations; `history`: the
    night's verdicts against its past nights, a test case per figure judged.
    """
    if junit:
        try:
            write_named(junit, junit_xml(doc, comparison, run, history))
        except OSError as exc:
            raise from_os_error(exc, "cannot write the JUnit file", path=junit, before_run=False) from None
        say(f"junit: {junit}")
    if github.enabled(env):
        place = github.workspace_path(doc.scenario.path, os.getcwd(), env.get("GITHUB_WORKSPACE"))
        for item in github.for_run(doc, comparison, place, run, history):
            say(item.command())


def finish(
    doc: RunDocument,
    folder: str,
    baseline: Optional[str],
    thresholds: list[Threshold],
    write: bool,
    plots: bool,
    env: dict[str, str],
    junit: Optional[str] = None,
    history: Optional[str] = None,
) -> int:
    """After a run or a merge: compare with the baseline, judge against the history and add the night to it
    (`--history`), write report.md, append the job summary, write the JUnit file and print the GitHub
    annotations (`ci_outputs`).

    Returns the number of regressions against the baseline and the history (0 without either).  A baseline
    that cannot be read or compared (another scenario's), or a history that cannot be read or written (corrupt,
    locked, of a newer schema, a full disk), raises its error once the run's own report and JUnit file are
    written: results.json is written before this is called, and neither costs the run its report.  So does a
    plot that could not be written (a full disk, exit 4), which is raised first.
    """
    results_path = os.path.join(folder, "results.json")
    section, cmp = None, None
    refused: Optional[RunnerError] = None
    if baseline:
        try:
            section, cmp = compare_files(baseline, doc, results_path, thresholds)
        except RunnerError as exc:
            refused = exc
        else:
            write_atomic(os.path.join(folder, "comparison.md"), section)
            say_comparison(cmp, baseline, results_path, os.path.join(folder, "comparison.md"))
    judged, unjudged = None, None
    if history:
        judged, unjudged = _history(doc, history, results_path, thresholds)
        if judged is not None:
            from runner.history.section import render as render_history

            section = (section + "\n" if section else "") + render_history(judged, history)
    unwritten: Optional[RunnerError] = None
    if write:
        path, failed = report_files(doc, folder, section, plots, compared=cmp, history=judged)
        unwritten = failed if isinstance(failed, OutputError) else None
        say(f"report: {path}")
        with open(path, encoding="utf-8") as handle:
            append_step_summary(handle.read(), env)
    elif section:
        append_step_summary(section, env)
    ci_outputs(doc, cmp, junit, env, history=judged)
    errors = [e for e in (unwritten, refused, unjudged) if e is not None]  # a full disk first: the code says it (4)
    for error in errors[1:]:
        note(str(error))
    if errors:
        raise errors[0]
    return (cmp.regressions if cmp else 0) + (judged.regressions if judged else 0)


def _history(
    doc: RunDocument, target: str, results_path: str, thresholds: list[Threshold]
) -> tuple[Optional[NightVerdict], Optional[RunnerError]]:
    """The night judged against the history at `target` and added to it, its headline said; or the error that stopped it."""
    from runner.history.apply import judge_and_add
    from runner.history.section import headline

    try:
        judged = judge_and_add(target, doc, os.path.abspath(results_path), thresholds)
    except RunnerError as exc:
        return None, exc
    say(headline(judged, target))
    return judged, None
