"""Combine the results of shards (or of separate runs) of one scenario into one results folder.

Refuses what cannot be one run: different scenarios, cells whose resolved spec
differs between inputs, and the same cell (and repeat) twice.  Samples files are
copied, so the merged folder stands on its own.
"""

from __future__ import annotations

import os
import shutil
from datetime import datetime, timezone

from runner.errors import Problem, ScenarioError
from runner.results.document import RunDocument, Status, worst
from runner.results.files import cell_dir, results_file
from runner.results.read import load


def merge(paths: list[str], out: str) -> RunDocument:
    """Merge the results in `paths` (folders or results.json files) into `out`; return the merged document."""
    docs = [(p, load(p)) for p in paths]
    problems: list[Problem] = []
    first_path, first = docs[0]
    seen: dict[tuple[str, int], str] = {}
    specs: dict[str, tuple[str, str]] = {}
    for path, doc in docs:
        where = results_file(path)
        if doc.name != first.name:
            problems.append(
                Problem(
                    where,
                    1,
                    1,
                    "scenario.name",
                    f"is {doc.name!r}, but {results_file(first_path)} is {first.name!r}; merge shards of one scenario",
                )
            )
            continue
        for cell in doc.cells:
            key = (cell.id, cell.repeat)
            if key in seen:
                rep = f" (repeat {cell.repeat + 1})" if cell.repeat else ""
                problems.append(
                    Problem(where, 1, 1, f"cells.{cell.id}", f"cell{rep} is also in {seen[key]}; each cell may come from one input only")
                )
            seen.setdefault(key, where)
            if cell.id in specs and specs[cell.id][0] != cell.spec_hash:
                problems.append(
                    Problem(
                        where,
                        1,
                        1,
                        f"cells.{cell.id}",
                        f"ran a different scenario spec than in {specs[cell.id][1]} (spec {cell.spec_hash} vs {specs[cell.id][0]})",
                    )
                )
            specs.setdefault(cell.id, (cell.spec_hash, where))
    if problems:
        raise ScenarioError(problems)

    order = {cell_id: i for i, cell_id in enumerate(first.matrix_cells or [c.id for _, d in docs for c in d.cells])}
    cells = sorted(((doc, c) for _, doc in docs for c in doc.cells), key=lambda dc: (order.get(dc[1].id, len(order)), dc[1].repeat))
    os.makedirs(out, exist_ok=True)
    repeated = {c.id for _, c in cells if c.repeat}
    merged = RunDocument(
        scenario=first.scenario,
        command=first.command,
        started_at=min(d.started_at for _, d in docs),
        machine=first.machine,
        permissions=first.permissions,
        start_settings=first.start_settings,
        tool=first.tool,
        finished_at=max((d.finished_at or "" for _, d in docs), default="") or None,
        cell_ids=list(first.matrix_cells) or [c.id for _, c in cells],
        matrix_cells=list(first.matrix_cells),
        plan=first.plan,
        merged_from=[results_file(p) for p, _ in docs],
        folder=os.path.abspath(out),
    )
    for doc, cell in cells:
        source = doc.samples_path(cell)
        if source and os.path.exists(source):
            rel = os.path.join(cell_dir(cell.id, cell.repeat, cell.id in repeated), "samples.csv.gz")
            target = os.path.join(out, rel)
            if os.path.abspath(source) != os.path.abspath(target):
                os.makedirs(os.path.dirname(target), exist_ok=True)
                shutil.copyfile(source, target)
            cell.samples_file = rel
        merged.cells.append(cell)
    merged.status = worst([c.status for _, c in cells] + [Status(d.status) for _, d in docs if d.status == "interrupted"]).value
    merged.command = ["runner", "merge", *paths, "--out", out]
    if merged.finished_at is None:
        merged.finished_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    merged.save(os.path.join(out, "results.json"))
    return merged
