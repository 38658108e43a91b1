"""A night against its history, then into it: the I/O around the pure judge (`judge.judge`).

Called once the night's results.json is written (a run, a merge) or for each results file imported
(`runner history FILE --import`): its cells' past series are read from the store, judged, and the
night is added with the change points it reported, in one transaction.
"""

from __future__ import annotations

from collections.abc import Sequence

from runner.histogram import Histogram
from runner.history.judge import CellInput, NightVerdict, judge
from runner.history.night import CellRecord, record
from runner.history.store import Store, open_store
from runner.report.compare import Threshold
from runner.results.document import RunDocument


def judge_and_add(target: str, doc: RunDocument, results: str, thresholds: Sequence[Threshold]) -> NightVerdict:
    """Judge `doc` against the history at `target`, then add it there; the verdict of every figure judged."""
    with open_store(target) as store:
        return judged_into(store, doc, results, thresholds)


def judged_into(store: Store, doc: RunDocument, results: str, thresholds: Sequence[Threshold]) -> NightVerdict:
    night = record(doc)
    environments = {n.started_at: n.environment for n in store.nights(night.host)}
    environments[night.started_at] = night.environment
    recorded = store.change_points(night.host)
    cells = []
    for c in night.cells:
        specs = store.spec_hashes(night.host, c.cell)
        new_spec = ""
        if specs and c.spec_hash not in {s for s, _ in specs}:
            new_spec = (
                f"its resolved scenario changed (spec hash {specs[-1][0][:12]} → {c.spec_hash[:12]}): a history of its own starts "
                "tonight, the nights of the old spec are kept apart"
            )
        cells.append(
            CellInput(
                cell=c.cell,
                spec_hash=c.spec_hash,
                started_at=c.started_at,
                rows=c.figures,
                past=store.series(night.host, c.cell, c.spec_hash, c.started_at),
                recorded=[cp for cp in recorded if cp.cell == c.cell and cp.spec_hash == c.spec_hash],
                new_spec=new_spec,
                histograms={(thread, kind): hist for thread, kind, hist in c.histograms},
                past_histograms=_past_histograms(store, night.host, c),
            )
        )
    verdict = judge(cells, thresholds, environments, night.started_at)
    store.add(night, results, verdict.change_points)
    return verdict


def _past_histograms(store: Store, host: str, cell: CellRecord) -> dict[tuple[str, str], Histogram]:
    """The past nights' histograms of each thread and kind tonight has, merged (the extremes' exceedance tests use them)."""
    out = {}
    for thread, kind, _ in cell.histograms:
        merged = store.histogram(host, cell.cell, cell.spec_hash, thread, kind, before=cell.started_at)
        if merged is not None:
            out[(thread, kind)] = merged
    return out
