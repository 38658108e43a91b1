"""What a run (and its comparison with a baseline) comes to, check by check, for CI readers.  Pure, no I/O.

JUnit XML (`junit.py`) and GitHub workflow annotations (`annotations.py`) show the same
things: each cell run, each expectation checked in it and each figure compared with the
baseline, with an outcome (passed, failed, error, skipped) and a message in the words the
report uses.  They are built here once, so the two cannot disagree with each other or with
the exit code (a failed expectation or a regression, a figure of the baseline this run lacks
included, is a failure; a cell that could not run or was cut short is an error; a cell the run
was asked for but never ran is skipped).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional

from runner.figures import scale
from runner.report.compare import CellChange, Comparison, FigureChange, Verdict
from runner.report.compareview import change_text, interval_ends, interval_text
from runner.report.findings import thread_labels
from runner.report.fmt import fmt_figure
from runner.results.document import CellResult, RunDocument, Status
from runner.results.document import Verdict as ExpectationVerdict
from runner.scenario.matrix import format_value

if TYPE_CHECKING:
    from runner.history.judge import FigureVerdict, NightVerdict


class Outcome(str, enum.Enum):
    """A check's outcome, as test reporters count them."""

    PASSED = "passed"
    FAILED = "failed"  # an expectation not met, a regression against the baseline
    ERROR = "error"  # the cell could not run, or was cut short
    SKIPPED = "skipped"  # not run, or nothing to compare with


class Kind(str, enum.Enum):
    """What a check is about."""

    RUN = "run"  # the cell's run itself
    EXPECTATION = "expectation"  # one expectation on one thread
    BASELINE = "baseline"  # one figure (or the cell's status) against the baseline
    HISTORY = "history"  # one figure against its past nights (--history)


@dataclass(frozen=True)
class Check:
    """One test case: a name that stays the same from run to run, its outcome and the words saying why."""

    name: str
    kind: Kind
    outcome: Outcome
    message: str = ""  # one line, the report's words; empty when passed
    time_ns: int = 0
    line: Optional[int] = None  # where an expectation is written in the scenario
    col: Optional[int] = None


@dataclass
class CellChecks:
    """One cell run (one test suite): its identity, matrix values and checks, and what it printed as warnings."""

    cell: str
    title: str  # `policy=fifo,priority=80`, or `... (repeat 2)` when cells ran more than once
    matrix: dict[str, str] = field(default_factory=dict)
    status: Optional[Status] = None  # None: the cell did not run
    started_at: str = ""
    hostname: Optional[str] = None
    duration_ns: int = 0
    checks: list[Check] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # warnings and degradations, in words

    def count(self, outcome: Outcome) -> int:
        return sum(c.outcome is outcome for c in self.checks)


_RUN_ERRORS = (Status.ERROR, Status.INTERRUPTED)


def expectation_message(v: ExpectationVerdict) -> str:
    """A verdict as the report's row reads: `minimal_schedul (main): latency p99 <= 2 ms, measured 3.10 ms`,
    or `...: latency max <= 1 µs: not measured (why)` without a value."""
    if v.measured is None:
        return f"{v.thread}: {v.figure.words} {v.limit}: {v.unmeasured}"
    return f"{v.thread}: {v.figure.words} {v.limit}, measured {fmt_figure(v.measured, v.figure.unit)}" + (f" ({v.note})" if v.note else "")


def expectation_name(v: ExpectationVerdict) -> str:
    """A verdict's test case name, the same in every run: `minimal_schedul (main): latency.p99 <= 2ms`."""
    return f"{v.thread}: {v.metric} {v.limit}"


def figure_message(f: FigureChange, labels: dict[str, str], thread_gone: bool = False) -> str:
    """A compared figure as the comparison's row reads: thread, figure, baseline, this run, change, threshold.

    `thread_gone`: this run has no such thread at all (its figures are missing for that reason).
    """
    thread = labels.get(f.thread, f.thread)
    ends = (*interval_ends(f.base_estimate), *interval_ends(f.new_estimate))
    sc = scale(f.figure.unit, (f.base, f.new, *ends))  # the row's one unit and precision, as in the comparison table
    unit = f" {sc.unit}" if sc.unit else ""
    base = sc.number(f.base) + unit + interval_text(f.base_estimate, sc)
    new = sc.number(f.new) + unit + interval_text(f.new_estimate, sc)
    if f.verdict == Verdict.NEW:
        return f"{thread}: {f.figure.words}: no baseline (this run {new})"
    if f.verdict == Verdict.MISSING:
        why = "the thread is not in this run" if thread_gone else "not measured in this run"
        return f"{thread}: {f.figure.words}: {why} (baseline {base})"
    if f.verdict == Verdict.OFF:
        return f"{thread}: {f.figure.words} {base} → {new}: not checked (its threshold is off)"
    if f.verdict == Verdict.UNCOMPARABLE:
        return f"{thread}: {f.figure.words} {base} → {new}: not comparable (the scheduler trace lost events in this cell)"
    why = f": {f.why}" if f.why else ""
    return (
        f"{thread}: {f.figure.words} {base} → {new} ({change_text(f, sc, with_unit=True)}), threshold {f.threshold.describe()}: "
        f"{f.verdict}{why}"
    )


def _figure_check(f: FigureChange, labels: dict[str, str], thread_gone: bool = False) -> Check:
    """A figure against its baseline: failed when worse, or when the baseline has it and this run does not (never a pass)."""
    skipped = {v: Outcome.SKIPPED for v in (Verdict.NEW, Verdict.OFF, Verdict.UNCOMPARABLE, Verdict.FEW)}
    outcome = {Verdict.REGRESSION: Outcome.FAILED, Verdict.MISSING: Outcome.FAILED, **skipped}.get(f.verdict, Outcome.PASSED)
    name = f"{labels.get(f.thread, f.thread)}: {f.figure.name} against the baseline"
    return Check(name, Kind.BASELINE, outcome, figure_message(f, labels, thread_gone) if outcome is not Outcome.PASSED else "")


def _history_check(f: FigureVerdict, labels: dict[str, str]) -> Check:
    """A figure against its past nights: failed when it regressed or went missing, skipped while there is too little to judge."""
    from runner.history.judge import FAILED, Verdict

    skipped = (Verdict.LEARNING, Verdict.NEW, Verdict.FEW, Verdict.CONTINUING)
    outcome = Outcome.FAILED if f.verdict in FAILED else Outcome.SKIPPED if f.verdict in skipped else Outcome.PASSED
    name = f"{labels.get(f.thread, f.thread)}: {f.figure.name} against the history"
    message = f"{labels.get(f.thread, f.thread)}: {f.figure.words}: {f.words}" if outcome is not Outcome.PASSED else ""
    return Check(name, Kind.HISTORY, outcome, message)


def _status_check(c: CellChange) -> Check:
    if c.verdict == Verdict.ERROR:  # an error in this run, whatever the baseline was: never "within threshold"
        return Check("status against the baseline", Kind.BASELINE, Outcome.ERROR, f"the cell could not run or was cut short: {c.note}")
    if c.verdict == Verdict.REGRESSION:
        return Check("status against the baseline", Kind.BASELINE, Outcome.FAILED, f"status regressed: {c.note}")
    if c.verdict == Verdict.NEW:
        return Check("status against the baseline", Kind.BASELINE, Outcome.SKIPPED, "not in the baseline")
    return Check("status against the baseline", Kind.BASELINE, Outcome.PASSED)


def _run_check(cell: CellResult) -> Check:
    if cell.status in _RUN_ERRORS:
        why = cell.reason or ("interrupted" if cell.status is Status.INTERRUPTED else "the cell could not run")
        return Check("run", Kind.RUN, Outcome.ERROR, why, cell.duration_ns)
    return Check("run", Kind.RUN, Outcome.PASSED, "", cell.duration_ns)


def _expectation_check(v: ExpectationVerdict) -> Check:
    if v.passed:
        return Check(expectation_name(v), Kind.EXPECTATION, Outcome.PASSED, line=v.line, col=v.col)
    return Check(expectation_name(v), Kind.EXPECTATION, Outcome.FAILED, expectation_message(v), line=v.line, col=v.col)


def _notes(cell: CellResult) -> list[str]:
    degraded = [f"degraded {t.process}/{t.name}: {why}" for t in cell.threads for why in t.degraded]
    return degraded + [f"warning: {text}" for text in cell.warnings]


def cell_checks(
    doc: RunDocument, comparison: Optional[Comparison] = None, run: bool = True, history: Optional[NightVerdict] = None
) -> list[CellChecks]:
    """Every cell run of `doc` with its checks; `comparison` adds each figure against the baseline, `history` each figure
    against its past nights.

    `run` False leaves out the runs and expectations (`runner compare`: only the comparison).
    Cells `doc` was asked for but has no result of are skipped (errors when the run did not finish,
    and in a comparison alone of an incomplete run); so are cells only the baseline has.
    """
    repeated = any(c.repeat for c in doc.cells)
    labels = thread_labels(doc.cells + (comparison.base.cells if comparison else []))
    changes = {c.cell: c for c in comparison.cells} if comparison else {}
    figures: dict[str, list[FigureChange]] = {}
    for f in comparison.figures if comparison else []:
        figures.setdefault(f.cell, []).append(f)
    out: list[CellChecks] = []
    first_repeat: dict[str, int] = {}  # the checks against the baseline go with a cell's first repeat, whatever order they ran in
    for cell in doc.cells:
        first_repeat[cell.id] = min(cell.repeat, first_repeat.get(cell.id, cell.repeat))
    for cell in doc.cells:
        item = CellChecks(
            cell=cell.id,
            title=cell.id + (f" (repeat {cell.repeat + 1})" if repeated else ""),
            matrix={str(k): format_value(v) for k, v in cell.matrix.items()},
            status=cell.status,
            started_at=cell.started_at,
            hostname=(cell.machine or doc.machine).hostname,
            duration_ns=cell.duration_ns,
        )
        if run:
            item.checks.append(_run_check(cell))
            item.checks.extend(_expectation_check(v) for v in cell.expectations)
            item.notes = _notes(cell)
        if cell.id in changes and cell.repeat == first_repeat[cell.id]:  # repeats are compared once, by their median
            item.checks.append(_status_check(changes[cell.id]))
            gone = set(comparison.threads_gone) if comparison else set()
            item.checks.extend(_figure_check(f, labels, (f.cell, f.thread) in gone) for f in figures.get(cell.id, []))
        if history is not None and cell.repeat == first_repeat[cell.id]:
            item.checks.extend(_history_check(f, labels) for f in history.figures if f.cell == cell.id)
        if item.checks:
            out.append(item)
    ran = {c.id for c in doc.cells}
    lost = doc.status in ("running", Status.ERROR.value)  # killed, crashed, or stopped by an error: what it had not reached is lost
    # a comparison alone of an incomplete run (one asked to stop too): what it lacks was never compared, an error, never a pass
    lacking = not run and comparison is not None and bool(comparison.incomplete)
    for cell_id in _unique(doc.cell_ids) if run or lacking else []:
        if cell_id not in ran:
            out.append(_lost(cell_id, doc.status) if lost or lacking else _skipped(cell_id, "not run"))
    unrun = {item.cell: item for item in out if item.cell not in ran}
    for c in comparison.cells if comparison else []:
        if c.verdict == Verdict.MISSING:  # one test suite per cell: beside its not-run check when it has one
            check = Check("against the baseline", Kind.BASELINE, Outcome.SKIPPED, "in the baseline, not in this run")
            if c.cell in unrun:
                unrun[c.cell].checks.append(check)
            else:
                out.append(CellChecks(cell=c.cell, title=c.cell, checks=[check]))
    return out


def _lost(cell_id: str, status: str) -> CellChecks:
    why = f"not run: the run ended before it (its status: {status})"
    return CellChecks(cell=cell_id, title=cell_id, checks=[Check("run", Kind.RUN, Outcome.ERROR, why)])


def _skipped(cell_id: str, why: str) -> CellChecks:
    return CellChecks(cell=cell_id, title=cell_id, checks=[Check("run", Kind.RUN, Outcome.SKIPPED, why)])


def _unique(ids: Sequence[str]) -> list[str]:
    return list(dict.fromkeys(ids))
