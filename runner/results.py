"""The results document (`runner.results/1`): typed records, JSON form, atomic writes.

A run writes `results.json` after every finished cell, atomically (temporary file,
fsync, rename), so a crash or a kill leaves the cells that finished readable.
Raw per-callback samples go beside it, one gzip'd CSV per cell.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import enum
import gzip
import hashlib
import io
import json
import math
import os
import re
import tempfile
import zlib
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    field_validator,
)

from . import units
from .errors import Problem, ScenarioError
from .measure import Faults, Figures, Involuntary, Verdict
from .model import Metric, Policy
from .plan import Settings
from .pstable import ThreadRow
from .samples import SlotData

SCHEMA = "runner.results/1"
SAMPLE_COLUMNS = ("thread", "tid", "seq", "scheduled_ns", "wake_ns", "end_ns", "latency_ns", "burn_wall_ns",
                  "nivcsw", "nvcsw", "minflt", "majflt", "cpu_start", "cpu_end", "missed")


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


def settings_json(settings: Settings | None) -> dict[str, Any] | None:
    if settings is None:
        return None
    return {
        "policy": settings.policy.value,
        "priority": settings.priority,
        "nice": settings.nice,
        "cpus": units.format_cpus(settings.cpus) if settings.cpus is not None else "all",
    }


def settings_from_json(data: dict[str, Any] | None) -> Settings | None:
    if data is None:
        return None
    cpus = None if data.get("cpus") in (None, "all") else units.parse_cpus(data["cpus"])
    return Settings(Policy(data["policy"]), int(data["priority"]), int(data["nice"]), cpus)


def thread_key(process: str, instance: int, index: int, name: str) -> str:
    """A thread's identity across cells and runs: `process[instance]/name (main)` or `... #index`."""
    return f"{process}[{instance}]/{name}" + (" (main)" if index == 0 else f" #{index}")


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
    applied: Settings | None
    degraded: list[str]
    figures: Figures

    @property
    def key(self) -> str:
        return thread_key(self.process, self.instance, self.index, self.name)

    def to_json(self) -> dict[str, Any]:
        f = self.figures
        return {
            "key": self.key,
            "process": self.process,
            "instance": self.instance,
            "index": self.index,
            "name": self.name,
            "pid": self.pid,
            "tid": self.tid,
            "work": self.work,
            "periodic": self.periodic,
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

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ThreadResult:
        inv, faults = d["involuntary"], d["faults"]
        figures = Figures(
            callbacks=d["callbacks"],
            missed=d["missed_releases"],
            involuntary=Involuntary(inv["total"], inv["per_callback_mean"], inv["per_callback_max"], inv["callbacks_with_any"]),
            voluntary_total=d["voluntary"]["total"],
            latency_us=d["latency_us"],
            callback_wall_us=d["callback_wall_us"],
            faults=Faults(faults["minor"], faults["major"], faults["minor_first_callback"], faults["minor_after_first"],
                          faults["minor_per_callback_max"]),
            cpus_seen=tuple(d["cpus_seen"]),
            complete=d["complete"],
        )
        requested = settings_from_json(d["requested"])
        assert requested is not None
        return cls(d["process"], d["instance"], d["index"], d["name"], d["pid"], d["tid"], d["work"], d["periodic"],
                   requested, settings_from_json(d["applied"]), list(d["degraded"]), figures)


def verdict_json(v: Verdict) -> dict[str, Any]:
    """A verdict as stored: latencies in microseconds, counts as counted."""
    measured = v.measured if v.measured is None or not v.metric.is_latency else round(v.measured / 1000.0, 3)
    return {"thread": v.thread, "metric": v.metric.value, "limit": v.limit, "measured": measured,
            "unit": "us" if v.metric.is_latency else "", "passed": v.passed, "note": v.note}


def verdict_from_json(d: dict[str, Any]) -> Verdict:
    metric = Metric(d["metric"])
    measured = d["measured"]
    if measured is not None and metric.is_latency:
        measured = measured * 1000.0
    return Verdict(d["thread"], metric, d["limit"], measured, d["passed"], d.get("note", ""))


@dataclass
class CellResult:
    """One cell of the matrix, as run."""

    id: str
    matrix: dict[str, Any]
    spec_hash: str
    status: Status
    spec: dict[str, Any] = field(default_factory=dict)  # the resolved cell as hashed, to say what differs
    reason: str = ""
    started_at: str = ""
    duration_s: float = 0.0
    machine: dict[str, Any] = field(default_factory=dict)
    thread_table: list[ThreadRow] = field(default_factory=list)
    threads: list[ThreadResult] = field(default_factory=list)
    expectations: list[Verdict] = field(default_factory=list)
    background: list[dict[str, Any]] = field(default_factory=list)
    overhead_s: dict[str, float | None] = field(default_factory=dict)
    samples_file: str | None = None  # relative to the results file's folder
    repeat: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "matrix": self.matrix,
            "spec_hash": self.spec_hash,
            "spec": self.spec,
            "repeat": self.repeat,
            "status": self.status.value,
            "reason": self.reason,
            "started_at": self.started_at,
            "duration_s": self.duration_s,
            "machine": self.machine,
            "thread_table": [row.to_json() for row in self.thread_table],
            "threads": [t.to_json() for t in self.threads],
            "expectations": [verdict_json(v) for v in self.expectations],
            "background": self.background,
            "overhead_s": self.overhead_s,
            "samples_file": self.samples_file,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> CellResult:
        return cls(
            id=d["id"], matrix=dict(d["matrix"]), spec_hash=d["spec_hash"], status=Status(d["status"]),
            spec=dict(d.get("spec") or {}), reason=d.get("reason", ""), started_at=d.get("started_at", ""),
            duration_s=d.get("duration_s", 0.0), machine=dict(d.get("machine") or {}),
            thread_table=[ThreadRow.from_json(r) for r in d.get("thread_table", [])],
            threads=[ThreadResult.from_json(t) for t in d.get("threads", [])],
            expectations=[verdict_from_json(v) for v in d.get("expectations", [])],
            background=list(d.get("background", [])), overhead_s=dict(d.get("overhead_s") or {}),
            samples_file=d.get("samples_file"), repeat=d.get("repeat", 0),
        )


@dataclass
class RunDocument:
    """A whole results file: the run's facts and its cells, in the order they finished."""

    scenario: dict[str, Any]
    command: list[str]
    started_at: str
    machine: dict[str, Any]
    permissions: dict[str, Any]
    start_settings: dict[str, Any]
    tool_version: str
    finished_at: str | None = None
    status: str = "running"
    cells: list[CellResult] = field(default_factory=list)
    cell_ids: list[str] = field(default_factory=list)  # every cell this run was asked to run, in order
    matrix_cells: list[str] = field(default_factory=list)  # every cell of the scenario, in expansion order
    plan: dict[str, Any] = field(default_factory=dict)  # repeat, shuffle_seed, settle_s, cell globs: what --resume reuses
    shard: str | None = None  # "K/N" when this run is one part of a sharded matrix
    merged_from: list[str] = field(default_factory=list)
    folder: str = ""  # where the file was read from (not stored): samples paths are relative to it
    source: str = ""  # the results file it was read from (not stored), to say where a problem is

    @property
    def name(self) -> str:
        return str(self.scenario.get("name", "scenario"))

    def to_json(self) -> dict[str, Any]:
        return {
            "schema": SCHEMA,
            "tool": {"name": "runner", "version": self.tool_version},
            "scenario": self.scenario,
            "command": self.command,
            "started_at": self.started_at,
            "finished_at": self.finished_at,
            "status": self.status,
            "shard": self.shard,
            "merged_from": self.merged_from,
            "machine": self.machine,
            "permissions": self.permissions,
            "start_settings": self.start_settings,
            "cell_ids": self.cell_ids,
            "matrix_cells": self.matrix_cells,
            "plan": self.plan,
            "cells": [c.to_json() for c in self.cells],
        }

    @classmethod
    def from_json(cls, d: dict[str, Any], folder: str = "") -> RunDocument:
        return cls(
            scenario=dict(d["scenario"]), command=list(d.get("command", [])), started_at=d.get("started_at", ""),
            machine=dict(d.get("machine") or {}), permissions=dict(d.get("permissions") or {}),
            start_settings=dict(d.get("start_settings") or {}), tool_version=d.get("tool", {}).get("version", "?"),
            finished_at=d.get("finished_at"), status=d.get("status", "running"),
            cells=[CellResult.from_json(c) for c in d.get("cells", [])],
            cell_ids=list(d.get("cell_ids") or [c["id"] for c in d.get("cells", [])]),
            matrix_cells=list(d.get("matrix_cells") or []), plan=dict(d.get("plan") or {}),
            shard=d.get("shard"), merged_from=list(d.get("merged_from") or []), folder=folder,
        )

    def save(self, path: str) -> None:
        """Write the document to `path` atomically; a figure that is not a number is stored as null."""
        write_atomic(path, json.dumps(without_nan(self.to_json()), indent=2, allow_nan=False))

    def samples_path(self, cell: CellResult) -> str | None:
        """The cell's samples file, refused (ScenarioError) unless it lies inside the results folder.

        A results file names its samples relative to its folder; one that names `/etc/passwd`,
        `../../x` or a symlink out of the folder is not followed by any reader.
        """
        if not cell.samples_file:
            return None
        path = os.path.join(self.folder, cell.samples_file)
        why = samples_path_problem(cell.samples_file, self.folder)
        if not why:
            root = os.path.realpath(self.folder)
            if os.path.commonpath([os.path.realpath(path), root]) != root:
                why = f"{cell.samples_file!r} leads out of the results folder through a symlink; expected a path inside {self.folder}"
            elif os.path.exists(path) and not os.path.isfile(path):
                why = f"{cell.samples_file!r} is not a file; expected the cell's samples.csv.gz inside {self.folder}"
        if why:
            where = self.source or os.path.join(self.folder, "results.json")
            raise ScenarioError([Problem(where, 1, 1, f"cells.{cell.id}.samples_file", why)])
        return path


SLUG_MAX = 120  # characters of the readable part; a file name stays well under NAME_MAX (255 bytes)
_UNSAFE = re.compile(r"[^A-Za-z0-9_.=,+-]")


def without_nan(data: Any) -> Any:
    """`data` with every NaN or infinite float replaced by None: NaN is never a figure, in no file."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: without_nan(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [without_nan(v) for v in data]
    return data


def slug(exact: str) -> str:
    """A file-system safe name that stands for `exact` alone: deterministic, injective, bounded.

    An id that is already a safe name (letters, digits and `_.=,+-`, not starting with a dot,
    at most SLUG_MAX characters) is its own name, so folders read as the cell ids they hold.
    Any other id keeps a readable version (unsafe characters as `_`, cut to SLUG_MAX) and adds
    `~` and a hash of the exact id: `a/b`, `a_b` and `a:b` get three folders, never one.
    Names of the first kind never contain `~`, so the two kinds cannot meet.
    """
    if exact and len(exact) <= SLUG_MAX and not exact.startswith(".") and not _UNSAFE.search(exact):
        return exact
    readable = _UNSAFE.sub("_", exact)[:SLUG_MAX].lstrip(".") or "_"
    digest = hashlib.sha256(exact.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return f"{readable}~{digest}"


def cell_dir(cell_id: str, repeat: int, repeated: bool) -> str:
    """A cell run's folder, relative to the results folder: `cells/<id>`, or `cells/<id>/repeat-<n>` with repeats."""
    base = os.path.join("cells", slug(cell_id))
    return os.path.join(base, f"repeat-{repeat + 1}") if repeated else base


def results_file(path: str) -> str:
    """The results.json that `path` names: the file itself, or the one inside a results folder."""
    return os.path.join(path, "results.json") if os.path.isdir(path) else path


def _umask() -> int:
    """The process umask, read without changing it (Linux reports it in /proc/self/status)."""
    try:
        with open("/proc/self/status", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)  # at import, before any thread of ours exists: not racy in practice
    os.umask(old)
    return old


FILE_MODE = 0o666 & ~_umask()  # what open() would give a new file: output files are ordinary files


def write_atomic(path: str, data: str | bytes) -> None:
    """Write `data` to `path` so that readers see the old or the new file, never half of one.

    The new file gets the mode any new file would get (0666 less the umask), not mkstemp's 0600.
    On failure (a full disk, a read-only or forbidden folder) the old file is untouched, no
    temporary file is left behind, and the OSError raised names `path`, for the caller to word.
    """
    folder = os.path.dirname(os.path.abspath(path))
    blob = data.encode("utf-8") if isinstance(data, str) else data
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=folder)
        with os.fdopen(fd, "wb") as handle:
            os.fchmod(handle.fileno(), FILE_MODE)
            handle.write(blob)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), path) from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    _sync_folder(folder)


def _sync_folder(folder: str) -> None:
    """Make a rename durable (best effort: some file systems cannot fsync a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_samples(path: str, slots: list[tuple[str, SlotData]]) -> None:
    """Per-callback samples of a cell as gzip'd CSV (one row per callback), written atomically."""
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(list(SAMPLE_COLUMNS))
    for key, slot in slots:
        for seq, s in enumerate(slot.samples):
            out.writerow([key, slot.tid, seq, s.scheduled_ns, s.wake_ns, s.end_ns, s.latency_ns, s.burn_wall_ns,
                          s.nivcsw, s.nvcsw, s.minflt, s.majflt, s.cpu_start, s.cpu_end, s.missed])
    write_atomic(path, gzip.compress(buf.getvalue().encode("utf-8"), compresslevel=6))


# ---------------------------------------------------------------- the stored shape
#
# `ResultsFile` is the shape of a `runner.results/1` file as pydantic models: what `load` checks
# before building the dataclasses above, so the report, comparison and merge can trust every
# type.  Only what the readers use is typed; other keys (older or newer writers) pass through.

Int = Annotated[StrictInt, Field(ge=-(2**63), le=2**63 - 1)]
Count = Annotated[StrictInt, Field(ge=0, le=2**63 - 1)]
Number = Annotated[StrictFloat, Field(ge=-1e18, le=1e18, allow_inf_nan=False)]  # takes ints too, never bools
Text = StrictStr
Cpus = Annotated[StrictStr | list[Count], Field(union_mode="left_to_right")]


class _Open(BaseModel):
    """A stored record: known keys typed, unknown keys kept (other writers' additions)."""

    model_config = ConfigDict(extra="allow")  # the Strict* types keep 1 from passing as "1" or True


class SettingsModel(_Open):
    policy: Policy
    priority: Int
    nice: Int
    cpus: Cpus | None = None

    @field_validator("cpus")
    @classmethod
    def _cpus(cls, value: Any) -> Any:
        if value not in (None, "all"):
            try:
                units.parse_cpus(value)
            except units.UnitError as exc:
                raise ValueError(str(exc)) from None
        return value


class InvoluntaryModel(_Open):
    total: Count
    per_callback_mean: Number | None
    per_callback_max: Count | None
    callbacks_with_any: Count | None


class FaultsModel(_Open):
    minor: Count
    major: Count
    minor_first_callback: Count | None
    minor_after_first: Count | None
    minor_per_callback_max: Count | None


class VoluntaryModel(_Open):
    total: Count


class ThreadModel(_Open):
    process: Text
    instance: Count
    index: Count
    name: Text
    pid: Int
    tid: Int
    work: Text
    periodic: StrictBool
    requested: SettingsModel
    applied: SettingsModel | None
    degraded: list[Text]
    complete: StrictBool
    callbacks: Count
    missed_releases: Count
    involuntary: InvoluntaryModel
    voluntary: VoluntaryModel
    latency_us: dict[str, Number | None] | None
    callback_wall_us: dict[str, Number | None] | None
    faults: FaultsModel
    cpus_seen: list[Annotated[StrictInt, Field(ge=0, lt=8192)]]


class VerdictModel(_Open):
    thread: Text
    metric: Metric
    limit: Text
    measured: Number | None
    passed: StrictBool
    note: Text = ""


class ThreadRowModel(_Open):
    pid: Int
    tid: Int
    comm: Text
    cls: Text
    rtprio: Int
    nice: Int
    psr: Int
    cpus: Cpus | None = None


class BackgroundModel(_Open):
    kind: Text | None = None
    argv: list[Text] = []


class ThrottlingModel(_Open):
    runtime_us: Number | None = None
    period_us: Number | None = None


class MachineModel(_Open):
    rt_throttling: ThrottlingModel | None = None
    cpufreq_governors: list[Text] | None = None
    memory_total_bytes: Int | None = None


class PermissionsModel(_Open):
    rlimit_memlock: Int | None = None
    missing: list[Text] | None = None


class CellModel(_Open):
    id: Text
    matrix: dict[str, Any]
    spec_hash: Text
    status: Status
    spec: dict[str, Any] | None = None
    reason: Text = ""
    started_at: Text = ""
    duration_s: Number = 0.0
    machine: MachineModel | None = None
    thread_table: list[ThreadRowModel] = []
    threads: list[ThreadModel] = []
    expectations: list[VerdictModel] = []
    background: list[BackgroundModel] = []
    overhead_s: dict[str, Number | None] | None = None
    samples_file: Text | None = None
    repeat: Annotated[StrictInt, Field(ge=0, le=1_000_000)] = 0



class ToolModel(_Open):
    version: Text = "?"


class ScenarioInfoModel(_Open):
    name: Text = "scenario"


class ResultsFile(_Open):
    """A whole `runner.results/1` file."""

    schema_: Literal["runner.results/1"] = Field(alias="schema")
    tool: ToolModel = ToolModel()
    scenario: ScenarioInfoModel
    command: list[Text] = []
    started_at: Text = ""
    finished_at: Text | None = None
    status: Text = "running"
    machine: MachineModel | None = None
    permissions: PermissionsModel | None = None
    start_settings: dict[str, Any] | None = None
    cells: list[CellModel] = []
    cell_ids: list[Text] | None = None
    matrix_cells: list[Text] | None = None
    plan: dict[str, Any] | None = None
    shard: Text | None = None
    merged_from: list[Text] | None = None


def samples_path_problem(relative: str | None, folder: str) -> str:
    """Why a stored samples path may not be followed ("" when it may): it must stay in `folder`.

    Pure (no file access): absolute paths and `..` that climbs out are refused here; a symlink
    that leads out is caught when the file is about to be opened (`RunDocument.samples_path`).
    """
    if not relative:
        return ""
    expected = f"expected a path inside {folder or os.curdir}"
    if "\x00" in relative:
        return f"contains a NUL character; {expected}"
    if os.path.isabs(relative):
        return f"{relative!r} is an absolute path; {expected}"
    if os.path.normpath(relative).split(os.sep)[0] == os.pardir:
        return f"{relative!r} leaves the results folder; {expected}"
    return ""


MAX_DEPTH = 64  # JSON nesting a results file never needs; deeper is refused before anything recurses into it
MAX_PROBLEMS = 20


def load(path: str) -> RunDocument:
    """Read a results document, refusing anything that is not a well-formed `runner.results/1` file.

    `path` may name the results file or the folder holding it.  Every refusal is a ScenarioError
    of `file:line:col: key.path: message` lines: not JSON, NaN or Infinity (never a figure), numbers
    out of range, the wrong shape or types (checked against `ResultsFile`), samples paths that
    leave the results folder.  What loads can be trusted by the report, comparison and merge.
    """
    path = results_file(path)
    try:
        with open(path, "rb") as handle:
            raw = handle.read()
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read results: {exc.strerror}")]) from None
    data = parse_json(path, raw)
    schema = data.get("schema") if isinstance(data, dict) else None
    if schema != SCHEMA:
        raise ScenarioError([Problem(path, 1, 1, "schema", f"expected a {SCHEMA} results file, got {show_value(schema)}")])
    problems = shape_problems(path, data)
    folder = os.path.dirname(os.path.abspath(path))
    if not problems:
        problems = [Problem(path, 1, 1, f"cells.{c['id']}.samples_file", why) for c in data.get("cells", [])
                    if (why := samples_path_problem(c.get("samples_file"), folder))]
    if problems:
        raise ScenarioError(problems)
    doc = RunDocument.from_json(data, folder)
    doc.source = path
    return doc


def parse_json(path: str, raw: bytes) -> Any:
    """Strict JSON: UTF-8, no NaN/Infinity, numbers a float can hold, nesting at most MAX_DEPTH."""
    def where(exc: json.JSONDecodeError) -> Problem:
        return Problem(path, exc.lineno, exc.colno, "", f"not valid JSON: {exc.msg}")

    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ScenarioError([Problem(path, line, 1, "", "not UTF-8 text; expected a runner results.json")]) from None
    try:
        data = json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except json.JSONDecodeError as exc:
        raise ScenarioError([where(exc)]) from None
    except _NotANumber as exc:
        raise ScenarioError([Problem(path, 1, 1, "", str(exc))]) from None
    except (ValueError, RecursionError) as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"not a usable number or structure: {exc}")]) from None
    if _depth(data) > MAX_DEPTH:
        raise ScenarioError([Problem(path, 1, 1, "", f"nested more than {MAX_DEPTH} levels deep; not a results file")])
    return data


class _NotANumber(ValueError):
    """A JSON number runner never writes: NaN, Infinity, or one beyond what a float holds."""


def _refuse_constant(name: str) -> Any:
    raise _NotANumber(f"{name} is not a number; a figure is a number or null")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NotANumber(f"{text} is out of range for a number")
    return value


def _depth(data: Any) -> int:
    """How deeply `data` nests (iteratively: a hostile file must not exhaust the stack)."""
    deepest, stack = 0, [(data, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, level)
            if level <= MAX_DEPTH:
                stack.extend((v, level + 1) for v in (item.values() if isinstance(item, dict) else item))
    return deepest


def shape_problems(path: str, data: Any) -> list[Problem]:
    """Where `data` differs from the `runner.results/1` shape (`ResultsFile`), as problems in `path`."""
    from pydantic import ValidationError

    try:
        ResultsFile.model_validate(data)
    except ValidationError as exc:
        problems = sorted({Problem(path, 1, 1, _key_path(err["loc"]), _message(err)) for err in exc.errors()})
        if len(problems) > MAX_PROBLEMS:
            last, more = problems[MAX_PROBLEMS - 1], len(problems) - MAX_PROBLEMS
            problems[MAX_PROBLEMS - 1] = dataclasses.replace(last, message=f"{last.message} (and {more} more problems)")
            del problems[MAX_PROBLEMS:]
        return problems
    return []


_TYPE_TAG = re.compile(r"(str|int|float|bool|list|dict)(\[.*\])?|function-.*|constrained-.*")


def _key_path(loc: tuple[Any, ...]) -> str:
    """pydantic's error location as a key path (`cells[0].threads[1].callbacks`), without its union tags."""
    out = ""
    for part in loc:
        if isinstance(part, str) and _TYPE_TAG.fullmatch(part):
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _message(err: Any) -> str:
    msg = str(err.get("msg", "invalid"))
    msg = msg[0].lower() + msg[1:] if msg else "invalid"
    msg = msg.removeprefix("value error, ")
    return msg if err.get("type") == "missing" else f"{msg}; got {show_value(err.get('input'))}"


def show_value(value: Any) -> str:
    """A value as a message quotes it: repr, or `dict of 3`, cut to 60 characters."""
    text = repr(value) if not isinstance(value, (dict, list)) else f"{type(value).__name__} of {len(value)}"
    return text if len(text) <= 60 else text[:57] + "..."


@dataclass(frozen=True)
class SampleRow:
    """One callback of one thread, as stored in samples.csv.gz (times in ns)."""

    seq: int
    latency_ns: int
    nivcsw: int
    minflt: int
    cpu: int


def read_samples(path: str) -> dict[str, list[SampleRow]]:
    """Per-callback samples of a cell by thread key; empty when the file does not exist.

    A file that is there but unusable (not gzip, cut short, rows that are not numbers) is a
    ScenarioError naming the file and the line, not a traceback and not a silently empty plot.
    """
    out: dict[str, list[SampleRow]] = {}
    line = 1
    try:
        with gzip.open(path, "rt", encoding="utf-8", newline="") as handle:
            reader = csv.DictReader(handle)
            for record in reader:
                line = reader.line_num
                key, row = _sample_row(record)
                out.setdefault(key, []).append(row)
    except FileNotFoundError:
        return out
    except (OSError, EOFError, zlib.error) as exc:
        raise ScenarioError([Problem(path, line, 1, "", f"cannot read samples: {exc}; expected a gzip'd CSV "
                                     "as runner writes it")]) from None
    except (ValueError, csv.Error) as exc:
        raise ScenarioError([Problem(path, line, 1, "", f"not a samples row: {exc}")]) from None
    return out


_INT64 = 2**63


def _sample_row(record: dict[Any, Any]) -> tuple[str, SampleRow]:
    """One CSV record as (thread key, SampleRow); ValueError saying which column is wrong."""
    def number(column: str) -> int:
        text = record.get(column)
        if text is None:
            raise ValueError(f"column {column} is missing; expected {', '.join(SAMPLE_COLUMNS)}")
        try:
            value = int(text)
        except ValueError:
            raise ValueError(f"{column} is {show_value(text)}; expected an integer") from None
        if not -_INT64 <= value < _INT64:
            raise ValueError(f"{column} is out of range; expected a 64-bit integer")
        return value

    key = record.get("thread")
    if key is None:
        raise ValueError("column thread is missing")
    return key, SampleRow(number("seq"), number("latency_ns"), number("nivcsw"), number("minflt"), number("cpu_end"))
