"""Combine the results of shards (or of separate runs) of one scenario into one results folder.

Refuses what cannot be one run: different scenarios, cells whose resolved spec
differs between inputs, and the same cell (and repeat) twice.  Samples files are
copied, so the merged folder stands on its own.
"""

from __future__ import annotations

import os
from datetime import datetime, timezone

from runner.errors import Problem, ScenarioError
from runner.results.document import CellResult, RunDocument, Status, worst
from runner.results.files import cell_dir, results_file
from runner.results.read import load
from runner.safefs import copy_file, make_folders


def unfinished(doc: RunDocument) -> str:
    """Why `doc`'s run did not finish what it was asked, in words; "" when it did (or was asked to stop).

    A run killed outright (SIGKILL, a crash, the machine lost) leaves its status `running`
    and the cells it had not reached out; one that stopped for an error says `error`.
    A merge asks for no runs of its own, so its status says it (`_merge_unfinished`).
    """
    if doc.status == "interrupted":
        return ""
    if doc.merged_from:
        return _merge_unfinished(doc)
    lacking, planned = doc.missing_runs(), len(doc.planned_runs())
    if doc.status == "running":
        missing = f": {lacking} of its {planned} cell runs are missing" if lacking else ""
        return f"its run never finished (results.json says running){missing}"
    if lacking:
        return f"{lacking} of the {planned} cell runs it was asked for are missing (its status: {doc.status})"
    return ""


def _missing_cells(doc: RunDocument) -> str:
    """`: N of its M cells are missing`, the cells of a merge's matrix (`cell_ids`) it holds no result of; "" when none."""
    held = {c.id for c in doc.cells}
    lacking = [c for c in doc.cell_ids if c not in held]
    return f": {len(lacking)} of its {len(doc.cell_ids)} cells are missing" if lacking else ""


def _merge_unfinished(doc: RunDocument) -> str:
    """Why a merged run is not whole, in words; "" when it is.

    A merge has no runs of its own to count (`RunDocument.planned_runs`), but `merge` makes it an
    error when one of its inputs did not finish (and a merge can be cut short itself, `running`).
    Such a status is the merge's inputs not finishing, unless a cell's own error explains it and
    every cell is there: a comparison of it would otherwise pass on the cells the finished inputs hold.
    A merge that lacks a shard but whose inputs all finished stays a pass with a warning, as before.
    """
    if doc.status not in ("error", "running"):
        return ""
    missing = _missing_cells(doc)
    if not missing and any(c.status == Status.ERROR for c in doc.cells):
        return ""  # the error is a cell's, counted as that cell's run error
    return f"the merge's inputs did not finish (results.json says {doc.status}){missing}"


def incomplete(doc: RunDocument) -> str:
    """Why `doc` is not the whole run it was asked to be, in words, whatever ended it; "" when it is.

    `unfinished`, and a run asked to stop too: its cells may compare well, but the cell runs it
    lacks were never measured, so a comparison of it is never a pass (`runner compare` exits 130,
    as the run did).  A merge asks for no runs of its own (`RunDocument.planned_runs`): the cells of
    its matrix it holds no result of are counted instead.
    """
    if doc.status != "interrupted":
        return unfinished(doc)
    if doc.merged_from:
        return f"its run was interrupted (results.json says interrupted){_missing_cells(doc)}"
    lacking, planned = doc.missing_runs(), len(doc.planned_runs())
    missing = f": {lacking} of its {planned} cell runs are missing" if lacking else ""
    return f"its run was interrupted (results.json says interrupted){missing}"


def merge(paths: list[str], out: str) -> tuple[RunDocument, list[str]]:
    """Merge the results in `paths` (folders or results.json files) into `out`; the merged document, and its errors.

    An input whose run did not finish (`unfinished`) makes the merged run an error: the
    errors say which, in words.
    """
    docs = [(p, load(p)) for p in paths]
    problems = conflicts(docs)
    if problems:
        raise ScenarioError(problems)
    first = docs[0][1]
    order = {cell_id: i for i, cell_id in enumerate(first.matrix_cells or [c.id for _, d in docs for c in d.cells])}
    cells = sorted(((doc, c) for _, doc in docs for c in doc.cells), key=lambda dc: (order.get(dc[1].id, len(order)), dc[1].repeat))
    make_folders(out)
    repeated = {c.id for _, c in cells if c.repeat}
    merged = RunDocument(
        scenario=first.scenario,
        command=["runner", "merge", *paths, "--out", out],
        started_at=min(d.started_at for _, d in docs),
        machine=first.machine,
        permissions=first.permissions,
        start_settings=first.start_settings,
        tool=first.tool,
        finished_at=max((d.finished_at or "" for _, d in docs), default="") or datetime.now(timezone.utc).isoformat(timespec="seconds"),
        cell_ids=list(first.matrix_cells) or [c.id for _, c in cells],
        matrix_cells=list(first.matrix_cells),
        plan=first.plan,
        merged_from=[results_file(p) for p, _ in docs],
        folder=os.path.abspath(out),
    )
    for doc, cell in cells:
        cell.samples_file = _copy_samples(doc, cell, out, cell.id in repeated)
        merged.cells.append(cell)
    errors = [f"{results_file(p)}: {why}; the merged run is an error" for p, d in docs if (why := unfinished(d))]
    merged.status = worst(
        [c.status for _, c in cells]
        + [Status(d.status) for _, d in docs if d.status in ("interrupted", "error")]  # an input merged from an unfinished run stays so
        + [Status.ERROR] * bool(errors)
    ).value
    merged.save(os.path.join(out, "results.json"))
    return merged, errors


def conflicts(docs: list[tuple[str, RunDocument]]) -> list[Problem]:
    """Why these documents cannot be one run, every reason at once: another scenario, a cell twice, a changed spec."""
    problems: list[Problem] = []
    first_path, first = docs[0]
    seen: dict[tuple[str, int], str] = {}
    specs: dict[str, tuple[str, str]] = {}
    for path, doc in docs:
        where = results_file(path)
        if doc.name != first.name:
            why = f"is {doc.name!r}, but {results_file(first_path)} is {first.name!r}; merge shards of one scenario"
            problems.append(Problem(where, 1, 1, "scenario.name", why))
            continue
        problems += [
            Problem(where, 1, 1, f"plan.{key}", f"{why} than {results_file(first_path)}; merge shards of one run")
            for key, why in _plan_differences(first, doc)
        ]
        for cell in doc.cells:
            key = (cell.id, cell.repeat)
            if key in seen:
                rep = f" (repeat {cell.repeat + 1})" if cell.repeat else ""
                why = f"cell{rep} is also in {seen[key]}; each cell may come from one input only"
                problems.append(Problem(where, 1, 1, f"cells.{cell.id}", why))
            seen.setdefault(key, where)
            if cell.id in specs and specs[cell.id][0] != cell.spec_hash:
                why = f"ran a different scenario spec than in {specs[cell.id][1]} (spec {cell.spec_hash} vs {specs[cell.id][0]})"
                problems.append(Problem(where, 1, 1, f"cells.{cell.id}", why))
            specs.setdefault(cell.id, (cell.spec_hash, where))
    return problems


def _plan_differences(first: RunDocument, doc: RunDocument) -> list[tuple[str, str]]:
    """How `doc`'s run differs from `first`'s in what decides its cells: length, scenario, expectations, repeats, tracing.

    A hash that one of them does not record (an older runner's file) is not held against it.
    """
    a, b = first.plan, doc.plan
    out = []
    if a.duration_ns != b.duration_ns:
        out.append(("duration_ns", "ran its cells for another --duration"))
    if a.scenario_hash and b.scenario_hash and a.scenario_hash != b.scenario_hash:
        out.append(("scenario_hash", "ran another version of the scenario file"))
    if a.expect_hash and b.expect_hash and a.expect_hash != b.expect_hash:
        out.append(("expect_hash", "judged its cells by other expectations"))
    if a.repeat != b.repeat:
        out.append(("repeat", "ran each cell another number of times (--repeat)"))
    if a.trace is not None and b.trace is not None:  # recorded by both (dma_latency_us since the same runner)
        if a.trace != b.trace:
            out.append(("trace", "traced the scheduler where the other did not (--no-trace)"))
        if a.dma_latency_us != b.dma_latency_us:
            out.append(("dma_latency_us", "held /dev/cpu_dma_latency otherwise (--dma-latency)"))
    return out


def _copy_samples(doc: RunDocument, cell: CellResult, out: str, repeated: bool) -> str | None:
    """Copy a cell's samples file into the merged folder (only from inside its own results folder); its new path."""
    source = doc.samples_path(cell)
    if not source or not os.path.exists(source):
        return cell.samples_file
    rel = os.path.join(cell_dir(cell.id, cell.repeat, repeated), "samples.csv.gz")
    target = os.path.join(out, rel)
    if os.path.abspath(source) != os.path.abspath(target):
        make_folders(out, os.path.dirname(rel))  # never into a link inside the merged folder
        copy_file(source, target)  # an error names the file: the source, or the target (a full disk names none itself)
    return rel
