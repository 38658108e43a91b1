"""The results document (`runner.results/1`): typed records, JSON form, atomic writes.

A run writes `results.json` after every finished cell, atomically (temporary file,
fsync, rename), so a crash or a kill leaves the cells that finished readable.
Raw per-callback samples go beside it, one gzip'd CSV per cell.
"""

from __future__ import annotations

import csv
import enum
import gzip
import io
import json
import os
import re
import tempfile
from dataclasses import dataclass, field
from typing import Any, Optional

from . import units
from .errors import Problem, ScenarioError
from .measure import Figures, Verdict
from .plan import Settings
from .pstable import ThreadRow
from .samples import SlotData

SCHEMA = "runner.results/1"


class Status(str, enum.Enum):
    """Outcome of a cell, most severe first."""

    ERROR = "error"
    INTERRUPTED = "interrupted"
    FAILED = "failed"
    DEGRADED = "degraded"
    PASSED = "passed"


def worst(statuses: list[Status]) -> Status:
    order = list(Status)
    return min(statuses, key=order.index) if statuses else Status.PASSED


def settings_json(settings: Optional[Settings]) -> Optional[dict[str, Any]]:
    if settings is None:
        return None
    return {
        "policy": settings.policy.value,
        "priority": settings.priority,
        "nice": settings.nice,
        "cpus": units.format_cpus(settings.cpus) if settings.cpus is not None else "all",
    }


@dataclass
class ThreadResult:
    """One measured thread: identity, requested vs applied settings, figures."""

    process: str
    instance: int
    index: int
    name: str
    pid: int
    tid: int
    work: str
    periodic: bool
    requested: Settings
    applied: Optional[Settings]
    degraded: list[str]
    figures: Figures

    def to_json(self) -> dict[str, Any]:
        f = self.figures
        return {
            "process": self.process,
            "instance": self.instance,
            "index": self.index,
            "name": self.name,
            "pid": self.pid,
            "tid": self.tid,
            "work": self.work,
            "requested": settings_json(self.requested),
            "applied": settings_json(self.applied),
            "degraded": self.degraded,
            "complete": f.complete,
            "callbacks": f.callbacks,
            "missed_releases": f.missed,
            "involuntary": {
                "total": f.involuntary.total,
                "per_callback_mean": f.involuntary.per_callback_mean,
                "per_callback_max": f.involuntary.per_callback_max,
                "callbacks_with_any": f.involuntary.callbacks_with_any,
            },
            "voluntary": {"total": f.voluntary_total},
            "latency_us": f.latency_us,
            "callback_wall_us": f.callback_wall_us,
            "faults": {
                "minor": f.faults.minor,
                "major": f.faults.major,
                "minor_first_callback": f.faults.minor_first_callback,
                "minor_after_first": f.faults.minor_after_first,
                "minor_per_callback_max": f.faults.minor_per_callback_max,
            },
            "cpus_seen": list(f.cpus_seen),
        }


@dataclass
class CellResult:
    """One cell of the matrix, as run."""

    id: str
    matrix: dict[str, Any]
    spec_hash: str
    status: Status
    reason: str = ""
    started_at: str = ""
    duration_s: float = 0.0
    machine: dict[str, Any] = field(default_factory=dict)
    thread_table: list[ThreadRow] = field(default_factory=list)
    threads: list[ThreadResult] = field(default_factory=list)
    expectations: list[Verdict] = field(default_factory=list)
    background: list[dict[str, Any]] = field(default_factory=list)
    overhead_s: dict[str, Optional[float]] = field(default_factory=dict)
    samples_file: Optional[str] = None

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "matrix": self.matrix,
            "spec_hash": self.spec_hash,
            "status": self.status.value,
            "reason": self.reason,
            "started_at": self.started_at,
            "duration_s": self.duration_s,
            "machine": self.machine,
            "thread_table": [row.to_json() for row in self.thread_table],
            "threads": [t.to_json() for t in self.threads],
            "expectations": [
                {"thread": v.thread, "metric": v.metric.value, "limit": v.limit,
                 "measured": v.measured if v.measured is None or not v.metric.is_latency else round(v.measured / 1000.0, 3),
                 "unit": "us" if v.metric.is_latency else "", "passed": v.passed, "note": v.note}
                for v in self.expectations
            ],
            "background": self.background,
            "overhead_s": self.overhead_s,
            "samples_file": self.samples_file,
        }


def slug(cell_id: str) -> str:
    """A file-system safe folder name for a cell id."""
    return re.sub(r"[^A-Za-z0-9_.=,+-]", "_", cell_id)[:120] or "default"


def write_atomic(path: str, text: str) -> None:
    """Write `text` to `path` so that readers see the old or the new file, never half of one."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".results-", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_samples(path: str, slots: list[tuple[str, SlotData]]) -> None:
    """Per-callback samples of a cell as gzip'd CSV (one row per callback), written atomically."""
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(["thread", "tid", "seq", "scheduled_ns", "wake_ns", "end_ns", "latency_ns", "burn_wall_ns",
                  "nivcsw", "nvcsw", "minflt", "majflt", "cpu_start", "cpu_end", "missed"])
    for key, slot in slots:
        for seq, s in enumerate(slot.samples):
            out.writerow([key, slot.tid, seq, s.scheduled_ns, s.wake_ns, s.end_ns, s.latency_ns, s.burn_wall_ns,
                          s.nivcsw, s.nvcsw, s.minflt, s.majflt, s.cpu_start, s.cpu_end, s.missed])
    tmp = path + ".tmp"
    with gzip.open(tmp, "wt", encoding="utf-8", compresslevel=6) as handle:
        handle.write(buf.getvalue())
    os.replace(tmp, path)


def load(path: str) -> dict[str, Any]:
    """Read a results document, refusing files that are not `runner.results/1`."""
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read results: {exc.strerror}")]) from None
    except json.JSONDecodeError as exc:
        raise ScenarioError([Problem(path, exc.lineno, exc.colno, "", f"not valid JSON: {exc.msg}")]) from None
    schema = data.get("schema") if isinstance(data, dict) else None
    if schema != SCHEMA:
        raise ScenarioError([Problem(path, 1, 1, "schema", f"expected a {SCHEMA} results file, got {schema!r}")])
    return data
