"""A results document as the rows a history keeps of it: per cell, each thread's figures with their sampling, and
its histograms, merged over the cell's repeats.  Pure.

A night is one run (or one merge of shards): its host, when it started, its environment facts
(`environment.facts`) and its cells.  A cell is keyed by its id and its spec hash: a cell whose
resolved scenario changed starts a history of its own.  Every figure of the registry a thread has
is kept (the trend report shows those without a threshold too), with the estimate and interval
of runner/results/estimates.py, so a night is judged on its own sampling as a comparison is.
Only cells that ran to the end (passed, degraded, failed) are kept: a cell that could not run or
was cut short measured nothing a later night should be held to.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from runner import figures as fg
from runner.histogram import Histogram, merge
from runner.history.environment import facts
from runner.report.compare import cell_estimate, compared_keys, subjects
from runner.results.document import CellResult, RunDocument, Status
from runner.results.estimates import Estimate

HISTOGRAM_KINDS = ("latency", "slack", "callback_wall", "wakeup", "message_age")
KEPT = (Status.PASSED, Status.DEGRADED, Status.FAILED)


@dataclass(frozen=True)
class FigureRow:
    """One figure of one thread of one cell on one night, with what it stands on."""

    thread: str
    figure: str
    value: float
    samples: int | None = None
    low: float | None = None
    high: float | None = None
    events: int | None = None
    exposure: float | None = None
    se: float | None = None
    few: bool = False

    @classmethod
    def of(cls, thread: str, est: Estimate) -> FigureRow:
        return cls(thread, est.figure.name, float(est.value), est.samples, est.low, est.high, est.events, est.exposure, est.se, est.few)


@dataclass(frozen=True)
class CellRecord:
    """One cell of a night (its repeats together)."""

    cell: str
    spec_hash: str
    started_at: str
    status: str
    duration_ns: int
    repeats: int
    figures: list[FigureRow] = field(default_factory=list)
    histograms: list[tuple[str, str, Histogram]] = field(default_factory=list)  # (thread, kind, histogram)


@dataclass(frozen=True)
class NightRecord:
    host: str
    started_at: str
    finished_at: str
    scenario: str
    scenario_hash: str
    runner_version: str
    shard: str
    environment: dict[str, str]
    cells: list[CellRecord]


def record(doc: RunDocument) -> NightRecord:
    """The rows a history keeps of `doc`."""
    groups: dict[str, list[CellResult]] = {}
    for cell in doc.cells:
        groups.setdefault(cell.id, []).append(cell)
    cells = [_cell(cell_id, runs, doc.started_at) for cell_id, runs in groups.items() if all(c.status in KEPT for c in runs)]
    return NightRecord(
        host=doc.machine.hostname or "?",
        started_at=doc.started_at,
        finished_at=doc.finished_at or "",
        scenario=doc.scenario.name,
        scenario_hash=doc.plan.scenario_hash or "",
        runner_version=doc.tool.version,
        shard=doc.shard or "",
        environment=facts(doc),
        cells=cells,
    )


def _cell(cell_id: str, runs: list[CellResult], run_started: str) -> CellRecord:
    first = min(runs, key=lambda c: c.repeat)
    rows: list[FigureRow] = []
    hists: list[tuple[str, str, Histogram]] = []
    for key in compared_keys(runs):
        for fig in fg.REGISTRY:
            est = cell_estimate(runs, key, fig)
            if est is not None:
                rows.append(FigureRow.of(key, est))
        threads = [t for c in runs for t in subjects(c) if t.key == key and t.histograms is not None]
        for kind in HISTOGRAM_KINDS:
            merged = merge(getattr(t.histograms, kind) for t in threads)
            if merged is not None:
                hists.append((key, kind, merged))
    statuses = [c.status for c in runs]
    worst = min(statuses, key=list(Status).index)
    return CellRecord(
        cell=cell_id,
        spec_hash=first.spec_hash,
        started_at=first.started_at or run_started,
        status=worst.value,
        duration_ns=first.duration_ns,
        repeats=len(runs),
        figures=rows,
        histograms=hists,
    )
