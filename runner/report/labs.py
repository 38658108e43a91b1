"""What a run comes to in the labs' result formats (LAVA, KernelCI's KCIDB), built once for both.  Pure, no I/O.

A lab keeps results by name from night to night, so each cell run becomes a list of
*subjects* (its threads, and anything an expectation names that is no thread, such as a
queue), each with the *measures* a lab charts: the key figures (`KEY_FIGURES`) the thread
has, and every figure an expectation judges.  The threads are those a comparison with a
baseline compares (threads with callbacks, and programs' threads), and any other an
expectation names.  Each gets a status in KCIDB's words
(`LabStatus`), which lava.py maps to LAVA's:

- a measure is PASS or FAIL when expectations judge it (FAIL if any of them failed), DONE
  when none does (a measurement, not a verdict);
- a subject is FAIL when any expectation on it failed (a thread that could not keep up
  always has one: runner/run/evaluate.py `keeps_up`), PASS when some judged it, DONE otherwise;
- a cell is PASS when it passed (or ran degraded, as its exit code says), FAIL when an
  expectation failed, ERROR when it could not run or was cut short, MISS when the run ended
  before it and SKIP when it was not run (runner/report/outcomes.py decides which);
- in a cell that could not run or was cut short nothing passes: a PASS or DONE there is ERROR.

Units and scales come from one table keyed by the registry's units (`LAB_UNITS`): LAVA
records durations in microseconds, KCIDB in seconds with a metric prefix; counts stay counts.
A figure's name in a lab is its registry name (`latency.p99`), so a new figure in
runner/figures.py reaches both formats without code here.

Names are built from the exact strings (cell ids, process and thread names, which a
program may choose) by keeping `A-Za-z0-9_-` and writing any other character as `_`:
nothing a thread names itself can reach a shell, a signal line or a path as anything but
those characters.  A subject's name is `process.thread` (`minimal_schedul.gc-2`: `-N` for
a thread other than the main one, `process-N` for a process that runs several instances);
two subjects of a cell whose names meet get `-` and 8 hex digits of a hash of their
exact names, so a name stands for one subject, the same one every night.
"""

from __future__ import annotations

import enum
import hashlib
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Optional

from runner import figures as fg
from runner.figures import Number, Unit
from runner.report.outcomes import Outcome, cell_checks
from runner.results.document import CellResult, RunDocument, Status, ThreadResult, Verdict
from runner.results.merge import incomplete


class LabStatus(str, enum.Enum):
    """KCIDB's test statuses, most severe first (its schema lists them so)."""

    FAIL = "FAIL"  # an expectation was not met
    ERROR = "ERROR"  # the cell could not run or was cut short: what it would have shown is unknown
    MISS = "MISS"  # the run ended before the cell
    PASS = "PASS"  # every expectation on it met
    DONE = "DONE"  # measured, judged by no expectation
    SKIP = "SKIP"  # not run


@dataclass(frozen=True)
class LabUnit:
    """How a registry unit is written in each lab format: a unit name and how many stored units make one."""

    lava: str  # lava-test-case --units (no spaces: LAVA splits its signal lines on them)
    lava_per: int
    kcidb: Optional[str]  # KCIDB's `number.unit`; None: dimensionless
    kcidb_per: int


LAB_UNITS: dict[Unit, LabUnit] = {
    Unit.NS: LabUnit("us", 1_000, "s", 1_000_000_000),  # cyclictest's microseconds; KCIDB's seconds, shown with a metric prefix
    Unit.COUNT: LabUnit("count", 1, None, 1),
    Unit.PER_CALLBACK: LabUnit("count/callback", 1, "/callback", 1),
    Unit.PER_SECOND: LabUnit("count/s", 1, "/s", 1),
}

CYCLICTEST_FIGURES = ("latency.min", "latency.mean", "latency.max")  # cyclictest's min/avg/max (Linaro's t<N>-min|avg|max-latency)
KEY_FIGURES: tuple[fg.Figure, ...] = tuple(f for f in fg.REGISTRY if f.column or f.threshold or f.name in CYCLICTEST_FIGURES)
"""The figures every lab result carries for a thread that has them: those the terminal's thread table shows, those
compared with a baseline by default, and cyclictest's three."""


@dataclass(frozen=True)
class Measure:
    """One figure of one subject, with the expectations that judged it."""

    figure: fg.Figure
    value: Optional[Number]  # in the registry's unit (ns for durations); None: not measured
    status: LabStatus
    verdicts: tuple[Verdict, ...] = ()


@dataclass(frozen=True)
class Subject:
    """A thread of a cell, or what an expectation names that is no thread; its lab name and its measures."""

    token: str  # `process.thread`, as labs name it
    name: str  # exact: the thread's key, or the expectation's label
    thread: Optional[ThreadResult]
    status: LabStatus
    measures: tuple[Measure, ...]


@dataclass(frozen=True)
class LabCell:
    """One cell run (or a cell the run was asked for and has no result of) as the labs see it."""

    cell_id: str
    repeat: int
    status: LabStatus
    reason: str  # why it could not run, was cut short or was not run, in words; "" otherwise
    result: Optional[CellResult] = None  # None: not run
    subjects: tuple[Subject, ...] = ()


_NOT_IN_NAMES = re.compile(r"[^A-Za-z0-9_-]")


def name_part(text: str) -> str:
    """`text` with every character but `A-Za-z0-9_-` written `_` (never empty): one part of a lab name."""
    return _NOT_IN_NAMES.sub("_", text) or "_"


def short_hash(text: str) -> str:
    """8 hex digits standing for `text` exactly (surrogates included: names read from the kernel may hold any byte)."""
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:8]


def several_instances(cells: Iterable[CellResult]) -> set[str]:
    """The processes that run more than once somewhere in `cells`: their subjects' names say which instance."""
    return {t.process for c in cells for t in c.threads if t.instance > 0}


def _thread_token(t: ThreadResult, multi: set[str]) -> str:
    process = name_part(t.process) + (f"-{t.instance}" if t.process in multi else "")
    return f"{process}.{name_part(t.name)}" + ("" if t.index == 0 else f"-{t.index}")


def unique_tokens(named: Sequence[tuple[str, str]]) -> dict[str, str]:
    """Each exact name's token, from (exact name, token) pairs; tokens that meet get `-` and a hash of the exact name."""
    seen: dict[str, int] = {}
    for _, token in named:
        seen[token] = seen.get(token, 0) + 1
    return {exact: f"{token}-{short_hash(exact)}" if seen[token] > 1 else token for exact, token in named}


def _unowned(cell: CellResult) -> dict[str, list[Verdict]]:
    """The cell's verdicts by the thread they name, under the thread's key; those naming no thread under their own label."""
    owners = _owners(cell)
    out: dict[str, list[Verdict]] = {}
    for v in cell.expectations:
        owner = owners.get(v.thread)
        out.setdefault(owner.key if owner else v.thread, []).append(v)
    return out


def cell_tokens(cell: CellResult, multi: set[str]) -> dict[str, str]:
    """The lab name of each subject of a cell, by exact name: its threads (by key, `minimal_schedul.gc-2`), then
    what its expectations name that is no thread (by label)."""
    keys = {t.key for t in cell.threads}
    named = [(t.key, _thread_token(t, multi)) for t in cell.threads]
    named += [(label, name_part(label)) for label in _unowned(cell) if label not in keys]
    return unique_tokens(named)


def _judged(verdicts: Sequence[Verdict]) -> LabStatus:
    if not verdicts:
        return LabStatus.DONE
    return LabStatus.FAIL if any(not v.passed for v in verdicts) else LabStatus.PASS


def _cut_short(status: LabStatus, cell: CellResult) -> LabStatus:
    """In a cell that could not run or was cut short nothing passes: what it would have shown is unknown."""
    if cell.status in (Status.ERROR, Status.INTERRUPTED) and status in (LabStatus.PASS, LabStatus.DONE):
        return LabStatus.ERROR
    return status


def _owners(cell: CellResult) -> dict[str, ThreadResult]:
    """The thread each verdict label names: `process[instance]/name ...` exactly, or without the instance when only one matches."""
    exact = {t.label(True): t for t in cell.threads}
    loose: dict[str, list[ThreadResult]] = {}
    for t in cell.threads:
        loose.setdefault(t.label(False), []).append(t)
    out = {label: ts[0] for label, ts in loose.items() if len(ts) == 1}
    out.update(exact)
    return out


def _subjects(cell: CellResult, multi: set[str]) -> tuple[Subject, ...]:
    verdicts = _unowned(cell)
    tokens = cell_tokens(cell, multi)
    out = [_subject(cell, tokens[t.key], t.key, t, verdicts.get(t.key, [])) for t in cell.threads if _measured(t) or t.key in verdicts]
    keys = {t.key for t in cell.threads}
    out += [_subject(cell, tokens[label], label, None, judged) for label, judged in verdicts.items() if label not in keys]
    return tuple(out)


def _subject(cell: CellResult, token: str, name: str, thread: Optional[ThreadResult], verdicts: list[Verdict]) -> Subject:
    by_metric: dict[str, list[Verdict]] = {}
    for v in verdicts:
        by_metric.setdefault(v.metric, []).append(v)
    measures = []
    for f in fg.REGISTRY:
        judged = by_metric.get(f.name, [])
        value = fg.value(thread.figures, f) if thread is not None else None
        if value is None and judged:
            value = next((v.measured for v in judged if v.measured is not None), None)
        if judged or (f in KEY_FIGURES and value is not None and thread is not None and _has(thread, f)):
            measures.append(Measure(f, value, _cut_short(_judged(judged), cell), tuple(judged)))
    return Subject(token, name, thread, _cut_short(_judged(verdicts), cell), tuple(measures))


def _measured(t: ThreadResult) -> bool:
    """Whether a thread is a subject of its own: it runs callbacks, or is a program's (measured from outside), as the
    comparison with a baseline chooses; any other thread is one only where an expectation names it."""
    return t.has_callbacks or t.program


def _has(t: ThreadResult, f: fg.Figure) -> bool:
    """Whether `f` is a figure of `t` at all: per-callback figures for threads with callbacks, period ones for periodic threads."""
    return (t.has_callbacks or not f.needs_callbacks) and (t.periodic or not f.needs_period)


_CELL_STATUS = {
    Status.PASSED: LabStatus.PASS,
    Status.DEGRADED: LabStatus.PASS,  # as its exit code says: degraded runs were allowed (--allow-degraded), and say so
    Status.FAILED: LabStatus.FAIL,
    Status.ERROR: LabStatus.ERROR,
    Status.INTERRUPTED: LabStatus.ERROR,
}


def lab_cells(doc: RunDocument) -> list[LabCell]:
    """Every cell run of `doc` in the order they ran, then the cells it was asked for and has no result of."""
    multi = several_instances(doc.cells)
    out = [
        LabCell(
            cell.id,
            cell.repeat,
            _CELL_STATUS[cell.status],
            cell.reason if cell.status in (Status.ERROR, Status.INTERRUPTED) else "",
            cell,
            _subjects(cell, multi),
        )
        for cell in doc.cells
    ]
    ran = {c.id for c in doc.cells}
    for checks in cell_checks(doc):
        if checks.cell in ran or not checks.checks:
            continue
        run = checks.checks[0]  # a cell never run has its `run` check alone: an error when the run ended before it
        out.append(LabCell(checks.cell, 0, LabStatus.MISS if run.outcome is Outcome.ERROR else LabStatus.SKIP, run.message))
    return out


def run_statuses(doc: RunDocument) -> list[Status]:
    """What decides the exit code of a lab report of `doc`, as of its run: its cells' statuses, and the run's own
    when it is incomplete (interrupted: 130; never finished: 4), as `runner compare` decides on the same file."""
    statuses = [c.status for c in doc.cells]
    if incomplete(doc):
        statuses.append(Status.INTERRUPTED if doc.status == Status.INTERRUPTED.value else Status.ERROR)
    return statuses
