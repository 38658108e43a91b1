"""A run as KCIDB data (KernelCI's common results database, schema v5.3), for the user to submit.  Pure, no I/O.

The document is what kcidb-io's schema v05_03 describes (kernelci/kcidb-io:
kcidb_io/schema/v05_03.py): `{"version": {"major": 5, "minor": 3}, "checkouts": [...],
"builds": [...], "tests": [...]}`, every object's `id` being `ORIGIN:...`, tests linked to a
build and builds to a checkout, no property null.  The runner tests a kernel it did not
build, so by default the document describes that kernel itself: one checkout and one build
of the running kernel (its release, version string and architecture, from the machine facts
the run recorded, on the host that ran it).  A lab that tests a build KCIDB already holds
(KernelCI's own) names it with `build_id` instead, and the document is tests alone.

Tests, per cell run (runner/report/labs.py says what each status means):

- `runner.SCENARIO.CELL`: the cell, its status, start time and length, `misc` with the exact
  cell id, matrix values and repeat, and the why of a cell that could not run;
- `runner.SCENARIO.CELL.PROCESS.THREAD`: each subject, its status from its expectations
  (`misc` holds its exact name, settings asked for and read back, and degradations);
- `runner.SCENARIO.CELL.PROCESS.THREAD.FIGURE` (`...latency.p99`): each measure, with
  `number` `{value, unit, prefix}` (durations in seconds with a metric prefix, so 21 µs is
  `{"value": 2.1e-05, "unit": "s", "prefix": "metric"}`; counts dimensionless), PASS or FAIL
  when expectations judged it (their words in `comment` and `misc`), DONE when none did.

Every test carries the cell's environment: `comment` the host, `misc` the machine facts the
run recorded (kernel, preemption model, command line, isolated CPUs, governors, RT
throttling, clocksource, ...; the lists of IRQs and their threads are left to results.json).
The report, results.json and the cell's samples are its `output_files`, at `url` (where the
user publishes the results folder) or, without one, as `file://` URLs of where they lie.

Paths hold only `A-Za-z0-9_-` between their dots (KCIDB's pattern): names are written as
labs.py writes them, the exact ones kept in `misc`.  Ids are unique and the same each time
the same results are exported, so a second submission of them replaces the first.
"""

from __future__ import annotations

import hashlib
import math
import os
import pathlib
import re
import urllib.parse
from typing import Any, Optional

from runner.figures import Number
from runner.outdir import REPORT_NAME
from runner.report.labs import LAB_UNITS, LabCell, LabStatus, Measure, Subject, lab_cells, name_part
from runner.report.outcomes import expectation_message
from runner.results.document import CellResult, MachineInfo, RunDocument

MAJOR, MINOR = 5, 3
DEFAULT_ORIGIN = "runner"
ORIGIN = re.compile(r"[a-z0-9_]+")  # KCIDB's origin pattern
ID = re.compile(r"[a-z0-9_]+:[^\0]*")  # an object id: ORIGIN:anything without NUL
_ARCHITECTURE = re.compile(r"[a-z0-9_]*")  # KCIDB's build architecture pattern
LOG_EXCERPT_LIMIT = 16_384  # characters KCIDB keeps of a log excerpt


def _clean(value: Any) -> Any:
    """`value` without nulls anywhere (KCIDB allows none) and without NUL characters in text."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_clean(v) for v in value if v is not None]
    if isinstance(value, str):
        return value.replace("\0", "\\0")
    return value


def environment_facts(machine: MachineInfo) -> dict[str, Any]:
    """The machine facts a test's `environment.misc` holds: all the run recorded but the IRQ lists (bulky, in results.json)."""
    facts: dict[str, Any] = _clean(machine.model_dump(mode="json", exclude={"irqs", "irq_threads"}))
    return facts


def _digest(*parts: str) -> str:
    return hashlib.sha256("\0".join(parts).encode("utf-8", "surrogatepass")).hexdigest()[:16]


def _files(doc: RunDocument, cell: Optional[CellResult], url: Optional[str]) -> list[dict[str, str]]:
    """The report, results.json and the cell's samples file, as KCIDB resources: `url` + their path in the results folder."""
    relative = [REPORT_NAME, "results.json"]
    if cell is not None and cell.samples_file:
        relative.append(cell.samples_file)
    out = []
    for rel in relative:
        path = os.path.join(doc.folder, rel) if doc.folder else ""
        if url:
            link = url.rstrip("/") + "/" + urllib.parse.quote(rel.replace(os.sep, "/"))
        elif path and os.path.isabs(path):
            link = pathlib.PurePosixPath(path).as_uri()
        else:
            continue
        out.append({"name": os.path.basename(rel) or rel, "url": link})
    return out


def _number(measure: Measure) -> Optional[dict[str, Any]]:
    value: Optional[Number] = measure.value
    if value is None or not math.isfinite(value):
        return None
    unit = LAB_UNITS[measure.figure.unit]
    out: dict[str, Any] = {"value": value / unit.kcidb_per if unit.kcidb_per != 1 else value, "prefix": "metric"}
    if unit.kcidb:
        out["unit"] = unit.kcidb
    return out


class _Builder:
    """The tests of one document: ids, build link and environment shared by all."""

    def __init__(self, doc: RunDocument, origin: str, build_id: str, url: Optional[str]):
        self.doc, self.origin, self.build_id, self.url = doc, origin, build_id, url
        self.run = _digest(doc.machine.hostname or "", doc.scenario.name, doc.started_at, doc.shard or "", *doc.merged_from)
        self.scenario = name_part(doc.scenario.name)

    def test(self, suffix: str, path: str, status: LabStatus, cell: Optional[CellResult], **fields: Any) -> dict[str, Any]:
        out: dict[str, Any] = {
            "build_id": self.build_id,
            "id": f"{self.origin}:runner-{self.run}-{suffix}",
            "origin": self.origin,
            "path": path,
            "status": status.value,
        }
        machine = (cell.machine if cell is not None else None) or self.doc.machine
        out["environment"] = {"comment": machine.hostname or "", "misc": environment_facts(machine)}
        if cell is not None and cell.started_at:
            out["start_time"] = cell.started_at
        out.update(fields)
        return _clean(out)

    def cell(self, n: int, lab: LabCell) -> list[dict[str, Any]]:
        base = f"runner.{self.scenario}.{name_part(lab.cell_id)}"
        cell = lab.result
        misc: dict[str, Any] = {"cell": lab.cell_id, "scenario": self.doc.scenario.name, "runner_version": self.doc.tool.version}
        fields: dict[str, Any] = {"misc": misc, "output_files": _files(self.doc, cell, self.url)}
        if cell is not None:
            misc.update(matrix=cell.matrix, repeat=cell.repeat, status=cell.status.value, warnings=cell.warnings or None)
            fields["duration"] = cell.duration_ns / 1e9
        if lab.reason:
            fields["comment"] = lab.reason[:1000]
            fields["log_excerpt"] = lab.reason[:LOG_EXCERPT_LIMIT]
        out = [self.test(f"c{n}", base, lab.status, cell, **fields)]
        for s, subject in enumerate(lab.subjects):
            out += self.subject(f"c{n}-t{s}", f"{base}.{subject.token}", subject, cell)
        return out

    def subject(self, suffix: str, path: str, subject: Subject, cell: Optional[CellResult]) -> list[dict[str, Any]]:
        misc: dict[str, Any] = {"name": subject.name}
        t = subject.thread
        if t is not None:
            settings = t.model_dump(mode="json", include={"requested", "applied", "degraded", "work", "pid", "tid"})
            misc.update(settings)
        out = [self.test(suffix, path, subject.status, cell, misc=misc)]
        for measure in subject.measures:
            fields: dict[str, Any] = {"misc": {"figure": measure.figure.name, "words": measure.figure.words}}
            number = _number(measure)
            if number is not None:
                fields["number"] = number
            if measure.verdicts:
                fields["misc"]["expectations"] = [{"limit": v.limit, "passed": v.passed, "note": v.note or None} for v in measure.verdicts]
                fields["comment"] = "; ".join(expectation_message(v) for v in measure.verdicts)
            out.append(self.test(f"{suffix}-{measure.figure.name}", f"{path}.{measure.figure.name}", measure.status, cell, **fields))
        return out


def kernel_objects(doc: RunDocument, origin: str) -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """The checkout and build of the kernel the run ran on (its release, version and architecture, on its host), and the build's id."""
    m = doc.machine
    kernel = " ".join(part for part in ("Linux", m.kernel, m.kernel_version) if part)
    key = _digest(m.hostname or "", m.kernel or "", m.kernel_version, m.arch or "")
    checkout = {"id": f"{origin}:checkout-{key}", "origin": origin, "comment": kernel, "misc": {"host": m.hostname, "release": m.kernel}}
    build: dict[str, Any] = {
        "checkout_id": checkout["id"],
        "id": f"{origin}:build-{key}",
        "origin": origin,
        "comment": kernel,
        "misc": {"kernel_version": m.kernel_version, "preempt": m.preempt, "preempt_rt": m.preempt_rt},
    }
    if m.arch and _ARCHITECTURE.fullmatch(m.arch):
        build["architecture"] = m.arch
    return [_clean(checkout)], [_clean(build)], build["id"]


def kcidb_document(
    doc: RunDocument, origin: str = DEFAULT_ORIGIN, build_id: Optional[str] = None, url: Optional[str] = None
) -> dict[str, Any]:
    """`doc` as a KCIDB v5.3 document: the running kernel's checkout and build (unless `build_id` names one), and the tests."""
    if not ORIGIN.fullmatch(origin):
        raise ValueError(f"KCIDB origin {origin!r}: expected lowercase letters, digits and _")
    if build_id is not None and not ID.fullmatch(build_id):
        raise ValueError(f"KCIDB build id {build_id!r}: expected ORIGIN:ID")
    out: dict[str, Any] = {"version": {"major": MAJOR, "minor": MINOR}}
    if build_id is None:
        out["checkouts"], out["builds"], build_id = kernel_objects(doc, origin)
    builder = _Builder(doc, origin, build_id, url)
    out["tests"] = [test for n, lab in enumerate(lab_cells(doc)) for test in builder.cell(n, lab)]
    return out
