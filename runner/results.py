"""The results document (`runner.results/2`): typed records, declared once, serialised by pydantic.

A run writes `results.json` after every finished cell, atomically (temporary file,
fsync, rename), so a crash or a kill leaves the cells that finished readable.
Raw per-callback samples go beside it, one gzip'd CSV per cell.

The models below are the one declaration of the file: `RunDocument.save` writes them
(`model_dump_json`), `load` reads them back (`model_validate_json`, strict: `1` is not
`"1"` or `true`), and `results_schema` is their JSON Schema (`results.schema.json`).

The shape of `runner.results/2`, top down:

- the run: `schema`, `tool` {`name`, `version`}, `scenario` {`name`, `path`, `description`},
  `command`, `started_at`, `finished_at`, `status` (`running` until it ends, then the worst
  cell status), `shard`, `merged_from`, `machine`, `permissions`, `start_settings`,
  `cell_ids`, `matrix_cells`, `plan` {`repeat`, `shuffle_seed`, `settle_ns`, `cells`,
  `duration_ns`}, `cells`;
- a cell: `id`, `matrix`, `spec_hash`, `spec` (the resolved cell), `repeat`, `status`,
  `reason`, `started_at`, `duration_ns`, `machine`, `thread_table` (ps rows), `threads`,
  `expectations`, `background`, `overhead_ns`, `samples_file` (relative to the results folder);
- a thread: `key` (derived), `process`, `instance`, `index`, `name`, `pid`, `tid`, `work`,
  `periodic`, `requested` and `applied` {`policy`, `priority`, `nice`, `cpus`}, `degraded`,
  `figures` (figures.ThreadFigures: every duration an integer in ns, e.g. `latency_ns.p99`);
- a verdict: `thread`, `metric` (a figure's name from figures.REGISTRY), `limit` (as the
  scenario wrote it), `measured` (in the figure's unit: ns for durations), `passed`, `note`.

Every duration in a /2 file is an integer number of nanoseconds, named `..._ns`; only the
report's formatting scales it.  NaN and infinity are never written (pydantic writes null)
and never read.  Unknown keys in a file are tolerated (a newer runner may add some) and
dropped; in Python, an unknown keyword is an error, so a misspelt field cannot vanish.

`runner.results/1` files (latencies in float microseconds, seconds elsewhere) still load:
`load` checks them against their own shape (`_V1File`), converts them (`upgrade_v1`) and
reads the result as a /2 document.  A file of a newer schema is refused, saying so.
"""

from __future__ import annotations

import contextlib
import copy
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
import types
import typing
import zlib
from dataclasses import dataclass
from decimal import Decimal
from typing import Annotated, Any, Final, Literal, Optional, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    NonNegativeInt,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
    WithJsonSchema,
    computed_field,
    field_validator,
)
from pydantic.json_schema import SkipJsonSchema

from . import __version__, units
from . import figures as fg
from .errors import Problem, ScenarioError, did_you_mean
from .figures import ThreadFigures
from .model import Policy
from .plan import Settings
from .pstable import CLS, ThreadRow
from .samples import SlotData

SCHEMA: Final = "runner.results/2"
LEGACY_SCHEMA = "runner.results/1"
SCHEMA_ID = "https://github.com/rt-scenario-runner/runner/results.schema.json"
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


def thread_label(process: str, instance: int, index: int, name: str, show_instance: bool = True) -> str:
    """How a thread is named in keys, rows, verdicts and tables: `process[instance]/name (main)` or `... #index`.

    With `show_instance` False (a process that runs once) the `[instance]` is left out:
    `process/name (main)`.  The thread's key (its identity across cells and runs, and its
    name in samples files) is the label with the instance.
    """
    proc = f"{process}[{instance}]" if show_instance else process
    return f"{proc}/{name}" + (" (main)" if index == 0 else f" #{index}")


def thread_key(process: str, instance: int, index: int, name: str) -> str:
    """A thread's identity across cells and runs (and its name in samples files): its label with the instance."""
    return thread_label(process, instance, index, name)


# ---------------------------------------------------------------- the records


class _Record(BaseModel):
    """A stored record: fields typed; an unknown keyword is an error in Python, an unknown key in a file is dropped.

    A file may hold keys this runner does not know (a newer runner added them, or they are
    derived, like a thread's `key`): reading ignores them.  Code that builds a record with a
    misspelt keyword gets a TypeError instead of a silently missing field.
    """

    model_config = ConfigDict(extra="ignore", validate_assignment=True, populate_by_name=True)

    def __init__(self, **data: Any) -> None:
        unknown = sorted(set(data) - self._keywords())
        if unknown:
            raise TypeError(f"{type(self).__name__} has no field {', '.join(map(repr, unknown))}; "
                            f"fields: {', '.join(type(self).model_fields)}")
        for name, value in data.items():  # records given as dicts are built as records, so their keys are checked too
            found = _record_type(type(self).model_fields[name].annotation) if name in type(self).model_fields else None
            if found and found[0] and isinstance(value, list):
                data[name] = [found[1](**v) if isinstance(v, dict) else v for v in value]
            elif found and not found[0] and isinstance(value, dict):
                data[name] = found[1](**value)
        super().__init__(**data)

    # Validation (of a file, or of nested dicts) must not run the check above: pydantic calls a model's own
    # __init__ while validating unless it is marked as the base one, as pydantic marks BaseModel.__init__.
    __init__.__pydantic_base_init__ = True  # type: ignore[attr-defined]

    @classmethod
    def _keywords(cls) -> set[str]:
        return {alias for name, f in cls.model_fields.items() for alias in (name, f.alias) if alias}


def _record_type(annotation: Any) -> tuple[bool, type[_Record]] | None:
    """(is a list, the record class) when a field holds records (`X`, `X | None`, `list[X]`); None otherwise."""
    if isinstance(annotation, type) and issubclass(annotation, _Record):
        return False, annotation
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) is list and args and isinstance(args[0], type) and issubclass(args[0], _Record):
        return True, args[0]
    if typing.get_origin(annotation) in (Union, types.UnionType):
        return next((found for arg in args if (found := _record_type(arg))), None)
    return None


def _figure_name(value: Any) -> Any:
    value = value.value if isinstance(value, enum.Enum) else value
    if isinstance(value, str) and value not in fg.BY_NAME:
        raise ValueError(f"unknown figure {value!r}{did_you_mean(value, fg.BY_NAME)}; known: {', '.join(fg.BY_NAME)}")
    return value


FigureName = Annotated[StrictStr, BeforeValidator(_figure_name),
                       WithJsonSchema({"type": "string", "enum": [f.name for f in fg.REGISTRY],
                                       "description": "a figure's name, as runner/figures.py declares it"})]
Measured = Optional[Union[int, float]]  # int for counts and durations (ns), float for means


class Verdict(_Record):
    """One expectation checked against one thread; `measured` in the figure's unit (ns for durations)."""

    thread: str = Field(description="the thread's label, as the report names it")
    metric: FigureName
    limit: str = Field(description="the limit as the scenario wrote it, e.g. `<= 2ms`")
    measured: Measured = Field(description="the figure's value in its unit (integer ns for durations); null: not measured")
    passed: bool
    note: str = ""

    @property
    def figure(self) -> fg.Figure:
        return fg.figure(self.metric)


class ThreadResult(_Record):
    """One measured thread: identity, requested vs applied settings, figures."""

    process: str
    instance: NonNegativeInt
    index: NonNegativeInt = Field(description="0 for the main thread, then creation order")
    name: str
    pid: int
    tid: int
    work: str = Field(description="the thread's work, in words")
    periodic: bool
    requested: Settings
    applied: Optional[Settings] = Field(description="as read back from the kernel; null when the thread was gone")
    degraded: list[str] = Field(default_factory=list, description="how the applied settings fell short, in words")
    figures: ThreadFigures

    @computed_field(description="the thread's identity across cells and runs: `process[instance]/name (main)` or `... #index`")  # type: ignore[prop-decorator]
    @property
    def key(self) -> str:
        return thread_key(self.process, self.instance, self.index, self.name)

    def label(self, show_instance: bool) -> str:
        """This thread's name in rows and tables (see `thread_label`)."""
        return thread_label(self.process, self.instance, self.index, self.name, show_instance)


class Overhead(_Record):
    """What the runner itself costs a cell, in ns: None where it could not be measured."""

    start_to_first_callback: Optional[int] = None
    last_callback_to_exit: Optional[int] = None


class BackgroundKind(str, enum.Enum):
    HOG = "hog"
    COMMAND = "command"


class Background(_Record):
    """One background load process of a cell: a busy-loop hog or a command."""

    kind: BackgroundKind
    name: str = ""
    argv: list[str] = Field(default_factory=list)
    pid: Optional[int] = None


class RtThrottling(_Record):
    """The kernel's RT throttling (sched_rt_runtime_us / sched_rt_period_us), in ns."""

    runtime_ns: Optional[int] = Field(None, description="RT time allowed per period; null: unlimited or not known")
    period_ns: Optional[int] = None
    enabled: bool = False

    @classmethod
    def from_sysctl(cls, runtime_us: Optional[int], period_us: Optional[int]) -> RtThrottling:
        """From the two sysctls as the kernel reports them (runtime -1: no throttling)."""
        enabled = runtime_us is not None and runtime_us >= 0
        return cls(runtime_ns=runtime_us * 1000 if enabled and runtime_us is not None else None,
                   period_ns=None if period_us is None else period_us * 1000, enabled=enabled)


class MachineInfo(_Record):
    """Facts about the machine a run (or a cell) ran on: what a reader needs to trust or compare its numbers."""

    hostname: Optional[str] = None
    kernel: Optional[str] = None
    kernel_version: str = ""
    preempt_rt: bool = False
    preempt: Optional[str] = None
    arch: Optional[str] = None
    cpus_online: Optional[str] = None
    cpus_allowed: Optional[int] = None
    isolated_cpus: str = ""
    rt_throttling: Optional[RtThrottling] = None
    cpufreq_governors: list[str] = Field(default_factory=list)
    memory_total_bytes: Optional[int] = None
    python: Optional[str] = None


class PermissionsInfo(_Record):
    """What the user running it was allowed to do."""

    user: Optional[str] = None
    uid: Optional[int] = None
    cap_sys_nice: bool = False
    cap_ipc_lock: bool = False
    rlimit_rtprio: Optional[int] = None
    rlimit_memlock: Optional[int] = Field(None, description="bytes; -1 unlimited")
    missing: list[str] = Field(default_factory=list, description="rights the cells needed and lacked, in words")


class Plan(_Record):
    """The run's options that `--resume` reuses."""

    repeat: Annotated[int, Field(ge=1)] = 1
    shuffle_seed: Optional[int] = None
    settle_ns: Optional[NonNegativeInt] = Field(None, description="pause between cells; null: the default")
    cells: list[str] = Field(default_factory=list, description="the --cell globs")
    duration_ns: Optional[NonNegativeInt] = None


class ScenarioInfo(_Record):
    name: str = "scenario"
    path: Optional[str] = None
    description: str = ""


class Tool(_Record):
    name: str = "runner"
    version: str = Field(default_factory=lambda: __version__)


def _status_value(value: Any) -> Any:
    return value.value if isinstance(value, enum.Enum) else value


def _run_status(value: str) -> str:
    allowed = ["running"] + [s.value for s in Status]
    if value not in allowed:
        raise ValueError(f"expected one of {', '.join(allowed)}")
    return value


RunStatus = Annotated[StrictStr, BeforeValidator(_status_value), AfterValidator(_run_status),
                      WithJsonSchema({"type": "string", "enum": ["running"] + [s.value for s in Status]})]


class CellResult(_Record):
    """One cell of the matrix, as run."""

    id: str
    matrix: dict[str, Any] = Field(default_factory=dict, description="the cell's matrix values")
    spec_hash: str
    spec: dict[str, Any] = Field(default_factory=dict, description="the resolved cell as hashed, to say what differs")
    repeat: Annotated[int, Field(ge=0, le=1_000_000)] = 0
    status: Status
    reason: str = ""
    started_at: str = ""
    duration_ns: NonNegativeInt = 0
    machine: Optional[MachineInfo] = None
    thread_table: list[ThreadRow] = Field(default_factory=list, description="the threads as the kernel held them mid-run")
    threads: list[ThreadResult] = Field(default_factory=list)
    expectations: list[Verdict] = Field(default_factory=list)
    background: list[Background] = Field(default_factory=list)
    overhead_ns: Overhead = Field(default_factory=Overhead)
    samples_file: Optional[str] = Field(None, description="relative to the results file's folder")

    def __init__(self, **data: Any) -> None:
        """`duration_s=` (seconds) is accepted here and stored as `duration_ns`; files hold only ns."""
        if "duration_s" in data:
            data["duration_ns"] = round(data.pop("duration_s") * 1e9)
        super().__init__(**data)

    __init__.__pydantic_base_init__ = True  # type: ignore[attr-defined]  # see _Record.__init__

    @property
    def duration_s(self) -> float:
        return self.duration_ns / 1e9


class RunDocument(_Record):
    """A whole results file: the run's facts and its cells, in the order they finished."""

    schema_: Literal["runner.results/2"] = Field(SCHEMA, alias="schema")
    tool: Tool = Field(default_factory=Tool)
    scenario: ScenarioInfo = Field(default_factory=ScenarioInfo)
    command: list[str] = Field(default_factory=list)
    started_at: str = ""
    finished_at: Optional[str] = None
    status: RunStatus = "running"
    shard: Optional[str] = Field(None, description="`K/N` when this run is one part of a sharded matrix")
    merged_from: list[str] = Field(default_factory=list)
    machine: MachineInfo = Field(default_factory=MachineInfo)
    permissions: PermissionsInfo = Field(default_factory=PermissionsInfo)
    start_settings: Settings = Field(default_factory=Settings, description="what the processes the runner starts inherit")
    cell_ids: list[str] = Field(default_factory=list, description="every cell this run was asked to run, in order")
    matrix_cells: list[str] = Field(default_factory=list, description="every cell of the scenario, in expansion order")
    plan: Plan = Field(default_factory=Plan)
    cells: list[CellResult] = Field(default_factory=list)
    folder: SkipJsonSchema[str] = Field("", exclude=True)  # where the file was read from: samples paths are relative to it
    source: SkipJsonSchema[str] = Field("", exclude=True)  # the results file it was read from, to say where a problem is

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def tool_version(self) -> str:
        return self.tool.version

    def save(self, path: str) -> None:
        """Write the document to `path` atomically; a figure that is not a number is stored as null."""
        write_atomic(path, self.model_dump_json(indent=2, by_alias=True) + "\n")

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


def results_schema() -> dict[str, Any]:
    """The JSON Schema of results.json as this version writes it (`runner schema --results`, results.schema.json)."""
    schema = RunDocument.model_json_schema(by_alias=True, mode="serialization")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = SCHEMA_ID
    schema["title"] = "runner results"
    schema["description"] = (f"A run's results.json ({SCHEMA}): every duration an integer in nanoseconds, "
                             "named *_ns; a figure that is not a number is null.")
    return schema


# ---------------------------------------------------------------- files and folders

SLUG_MAX = 120  # characters of the readable part; a file name stays well under NAME_MAX (255 bytes)
_UNSAFE = re.compile(r"[^A-Za-z0-9_.=,+-]")


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


# ---------------------------------------------------------------- runner.results/1, read and upgraded
#
# The shape of a `runner.results/1` file, as its readers checked it: only what they used is
# typed; other keys pass.  `upgrade_v1` turns a file that passed into the /2 shape.

_Int = Annotated[StrictInt, Field(ge=-(2**63), le=2**63 - 1)]
_Count = Annotated[StrictInt, Field(ge=0, le=2**63 - 1)]
_Number = Annotated[StrictFloat, Field(ge=-1e18, le=1e18, allow_inf_nan=False)]  # takes ints too, never bools
_Cpus = Annotated[StrictStr | list[_Count], Field(union_mode="left_to_right")]


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow")  # the Strict* types keep 1 from passing as "1" or True


class _V1Settings(_Open):
    policy: Policy
    priority: _Int
    nice: _Int
    cpus: _Cpus | None = None

    @field_validator("cpus")
    @classmethod
    def _cpus(cls, value: Any) -> Any:
        if value not in (None, "all"):
            try:
                units.parse_cpus(value)
            except units.UnitError as exc:
                raise ValueError(str(exc)) from None
        return value


class _V1Involuntary(_Open):
    total: _Count
    per_callback_mean: _Number | None
    per_callback_max: _Count | None
    callbacks_with_any: _Count | None


class _V1Faults(_Open):
    minor: _Count
    major: _Count
    minor_first_callback: _Count | None
    minor_after_first: _Count | None
    minor_per_callback_max: _Count | None


class _V1Voluntary(_Open):
    total: _Count


class _V1Thread(_Open):
    process: StrictStr
    instance: _Count
    index: _Count
    name: StrictStr
    pid: _Int
    tid: _Int
    work: StrictStr
    periodic: StrictBool
    requested: _V1Settings
    applied: _V1Settings | None
    degraded: list[StrictStr]
    complete: StrictBool
    callbacks: _Count
    missed_releases: _Count
    involuntary: _V1Involuntary
    voluntary: _V1Voluntary
    latency_us: dict[str, _Number | None] | None
    callback_wall_us: dict[str, _Number | None] | None
    faults: _V1Faults
    cpus_seen: list[Annotated[StrictInt, Field(ge=0, lt=8192)]]


class _V1Verdict(_Open):
    thread: StrictStr
    metric: FigureName
    limit: StrictStr
    measured: _Number | None
    passed: StrictBool
    note: StrictStr = ""


class _V1ThreadRow(_Open):
    pid: _Int
    tid: _Int
    comm: StrictStr
    cls: StrictStr
    rtprio: _Int
    nice: _Int
    psr: _Int
    cpus: _Cpus | None = None


class _V1Background(_Open):
    kind: StrictStr | None = None
    argv: list[StrictStr] = []


class _V1Throttling(_Open):
    runtime_us: _Number | None = None
    period_us: _Number | None = None


class _V1Machine(_Open):
    rt_throttling: _V1Throttling | None = None
    cpufreq_governors: list[StrictStr] | None = None
    memory_total_bytes: _Int | None = None


class _V1Permissions(_Open):
    rlimit_memlock: _Int | None = None
    missing: list[StrictStr] | None = None


class _V1Cell(_Open):
    id: StrictStr
    matrix: dict[str, Any]
    spec_hash: StrictStr
    status: Status
    spec: dict[str, Any] | None = None
    reason: StrictStr = ""
    started_at: StrictStr = ""
    duration_s: _Number = 0.0
    machine: _V1Machine | None = None
    thread_table: list[_V1ThreadRow] = []
    threads: list[_V1Thread] = []
    expectations: list[_V1Verdict] = []
    background: list[_V1Background] = []
    overhead_s: dict[str, _Number | None] | None = None
    samples_file: StrictStr | None = None
    repeat: Annotated[StrictInt, Field(ge=0, le=1_000_000)] = 0


class _V1Tool(_Open):
    version: StrictStr = "?"


class _V1Scenario(_Open):
    name: StrictStr = "scenario"


class _V1File(_Open):
    """A whole `runner.results/1` file."""

    schema_: Literal["runner.results/1"] = Field(alias="schema")
    tool: _V1Tool = _V1Tool()
    scenario: _V1Scenario
    command: list[StrictStr] = []
    started_at: StrictStr = ""
    finished_at: StrictStr | None = None
    status: StrictStr = "running"
    machine: _V1Machine | None = None
    permissions: _V1Permissions | None = None
    start_settings: dict[str, Any] | None = None
    cells: list[_V1Cell] = []
    cell_ids: list[StrictStr] | None = None
    matrix_cells: list[StrictStr] | None = None
    plan: dict[str, Any] | None = None
    shard: StrictStr | None = None
    merged_from: list[StrictStr] | None = None


def _scaled(value: Any, factor: int) -> Any:
    """A number of microseconds (factor 1000) or seconds (factor 10**9) as integer ns; anything else as it is.

    Exact for what runner/1 wrote (decimal fractions of a few digits): 58.366 us is 58366 ns.
    A value that is not a number is left for the /2 check to name.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return value
    return int((Decimal(repr(value)) * factor).to_integral_value())


def _spread_ns(spread: Any) -> Any:
    """A /1 `latency_us`-style spread in ns; one with a figure that was not a number (stored null) is no spread."""
    if not isinstance(spread, dict):
        return spread
    if any(v is None for v in spread.values()):
        return None
    return {q: _scaled(v, 1000) for q, v in spread.items()}


def _nulls_out(data: dict[str, Any]) -> dict[str, Any]:
    """`data` without its null values: /1 wrote null for "none", /2 leaves those keys to their defaults."""
    return {k: v for k, v in data.items() if v is not None}


def _machine_v1(machine: Any) -> Any:
    if not isinstance(machine, dict):
        return machine
    out = _nulls_out(machine)
    throttle = out.get("rt_throttling")
    if isinstance(throttle, dict):
        out["rt_throttling"] = {
            "runtime_ns": _scaled(throttle["runtime_us"], 1000) if _positive(throttle.get("runtime_us")) else None,
            "period_ns": _scaled(throttle.get("period_us"), 1000),
            "enabled": throttle.get("enabled", _positive(throttle.get("runtime_us"))),
        }
    return out


def _positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0


def _thread_v1(t: dict[str, Any]) -> dict[str, Any]:
    inv, faults = t["involuntary"], t["faults"]
    figures = {
        "callbacks": t["callbacks"],
        "missed_releases": t["missed_releases"],
        "involuntary": {k: inv[k] for k in ("total", "per_callback_mean", "per_callback_max", "callbacks_with_any")},
        "voluntary": {"total": t["voluntary"]["total"]},
        "latency_ns": _spread_ns(t["latency_us"]),
        "callback_wall_ns": _spread_ns(t["callback_wall_us"]),
        "faults": {k: faults[k] for k in ("minor", "major", "minor_first_callback", "minor_after_first",
                                          "minor_per_callback_max")},
        "cpus_seen": t["cpus_seen"],
        "complete": t["complete"],
    }
    same = ("process", "instance", "index", "name", "pid", "tid", "work", "periodic", "requested", "applied", "degraded")
    return {**{k: t[k] for k in same}, "figures": figures}


_POLICY_OF_CLS = {name: number for number, name in CLS.items()}


def _row_v1(row: dict[str, Any]) -> dict[str, Any]:
    return {"pid": row["pid"], "tid": row["tid"], "comm": row["comm"], "policy": _POLICY_OF_CLS.get(row["cls"], -1),
            "rtprio": row["rtprio"], "nice": row["nice"], "psr": row["psr"], "prio": None, "cpus": row.get("cpus") or ""}


def _verdict_v1(v: dict[str, Any]) -> dict[str, Any]:
    duration = fg.figure(v["metric"]).is_duration
    return {"thread": v["thread"], "metric": v["metric"], "limit": v["limit"],
            "measured": _scaled(v["measured"], 1000) if duration else v["measured"], "passed": v["passed"],
            "note": v.get("note", "")}


def _cell_v1(c: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {k: c[k] for k in ("id", "matrix", "spec_hash", "status") if k in c}
    out.update(_nulls_out({k: c.get(k) for k in ("spec", "repeat", "reason", "started_at", "samples_file")}))
    out["duration_ns"] = _scaled(c.get("duration_s", 0), 10**9)
    if c.get("machine") is not None:
        out["machine"] = _machine_v1(c["machine"])
    out["thread_table"] = [_row_v1(r) for r in c.get("thread_table", [])]
    out["threads"] = [_thread_v1(t) for t in c.get("threads", [])]
    out["expectations"] = [_verdict_v1(v) for v in c.get("expectations", [])]
    out["background"] = [_nulls_out(b) for b in c.get("background", [])]
    out["overhead_ns"] = {k: _scaled(v, 10**9) for k, v in (c.get("overhead_s") or {}).items()}
    return out


def upgrade_v1(data: dict[str, Any]) -> dict[str, Any]:
    """A `runner.results/1` document (one that `_V1File` accepts) in the `runner.results/2` shape.  Pure.

    Latencies and callback times (float us) become integer ns under `figures`; verdicts on
    durations are measured in ns; the cell's duration, the overhead and the settle pause
    (seconds) become ns; RT throttling (us) becomes ns; ps rows name their policy by number.
    Keys /2 does not know are left for `load` to drop, as it drops a newer runner's.
    """
    data = copy.deepcopy(data)
    cells = data.get("cells", [])
    out = _nulls_out({k: data.get(k) for k in ("tool", "scenario", "command", "started_at", "finished_at", "status",
                                               "shard", "merged_from", "permissions", "start_settings",
                                               "matrix_cells")})
    out["schema"] = SCHEMA
    out["tool"] = {"name": "runner", "version": (data.get("tool") or {}).get("version", "?")}
    if data.get("machine") is not None:
        out["machine"] = _machine_v1(data["machine"])
    if isinstance(out.get("permissions"), dict):
        out["permissions"] = _nulls_out(out["permissions"])
    out["cell_ids"] = data.get("cell_ids") or [c["id"] for c in cells]
    plan = dict(data.get("plan") or {})
    if "settle_s" in plan:
        plan["settle_ns"] = _scaled(plan.pop("settle_s"), 10**9)
    out["plan"] = plan
    out["cells"] = [_cell_v1(c) for c in cells]
    return out


# ---------------------------------------------------------------- reading a results file

MAX_DEPTH = 64  # JSON nesting a results file never needs; deeper is refused before anything recurses into it
MAX_PROBLEMS = 20
_INT64 = 2**63
_SCHEMA_NAME = re.compile(r"runner\.results/([0-9]{1,6})")


def load(path: str) -> RunDocument:
    """Read a results document, refusing anything that is not a well-formed results file.

    `path` may name the results file or the folder holding it.  A `runner.results/1` file is
    checked against its own shape and upgraded; a /2 file is read strictly.  Every refusal is a
    ScenarioError of `file:line:col: key.path: message` lines: not JSON, NaN or Infinity (never
    a figure), numbers out of range, the wrong shape or types, a newer schema, samples paths
    that leave the results folder.  What loads can be trusted by the report, comparison and merge.
    """
    path = results_file(path)
    try:
        with open(path, "rb") as handle:
            raw = handle.read()
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read results: {exc.strerror}")]) from None
    data = parse_json(path, raw)
    if _schema_version(path, data) == 1:
        try:
            _V1File.model_validate(data)
        except ValidationError as exc:
            raise ScenarioError(validation_problems(path, exc)) from None
        data = upgrade_v1(data)
    problems = range_problems(path, data)
    if problems:
        raise ScenarioError(problems)
    try:
        doc = RunDocument.model_validate_json(json.dumps(data), strict=True)
    except ValidationError as exc:
        raise ScenarioError(validation_problems(path, exc)) from None
    doc.folder, doc.source = os.path.dirname(os.path.abspath(path)), path
    problems = [Problem(path, 1, 1, f"cells.{c.id}.samples_file", why) for c in doc.cells
                if (why := samples_path_problem(c.samples_file, doc.folder))]
    if problems:
        raise ScenarioError(problems)
    return doc


def _schema_version(path: str, data: Any) -> int:
    """1 or 2, from the file's `schema`; a newer one, or none, is refused saying what this runner reads."""
    schema = data.get("schema") if isinstance(data, dict) else None
    match = _SCHEMA_NAME.fullmatch(schema) if isinstance(schema, str) else None
    if match and int(match.group(1)) in (1, 2):
        return int(match.group(1))
    if match and int(match.group(1)) > 2:
        why = (f"{schema} is a newer results format than this runner ({__version__}) reads ({LEGACY_SCHEMA} and "
               f"{SCHEMA}); read it with a newer runner")
    else:
        why = f"expected a {SCHEMA} (or {LEGACY_SCHEMA}) results file, got {show_value(schema)}"
    raise ScenarioError([Problem(path, 1, 1, "schema", why)])


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


def range_problems(path: str, data: Any) -> list[Problem]:
    """Integers a 64-bit field cannot hold, wherever they are: runner never writes one, and no reader should meet one."""
    out: list[Problem] = []
    stack: list[tuple[Any, tuple[Any, ...]]] = [(data, ())]
    while stack and len(out) < MAX_PROBLEMS:
        item, loc = stack.pop()
        if isinstance(item, dict):
            stack.extend((v, loc + (k,)) for k, v in item.items())
        elif isinstance(item, list):
            stack.extend((v, loc + (i,)) for i, v in enumerate(item))
        elif isinstance(item, int) and not isinstance(item, bool) and not -_INT64 <= item < _INT64:
            out.append(Problem(path, 1, 1, _key_path(loc), f"{show_value(item)} is out of range; expected a 64-bit integer"))
    return sorted(out)


def validation_problems(path: str, exc: ValidationError) -> list[Problem]:
    """pydantic's errors as problems in `path` (key path, message, the value found); at most MAX_PROBLEMS."""
    problems = sorted({Problem(path, 1, 1, _key_path(err["loc"]), _message(err)) for err in exc.errors()})
    if len(problems) > MAX_PROBLEMS:
        last, more = problems[MAX_PROBLEMS - 1], len(problems) - MAX_PROBLEMS
        problems[MAX_PROBLEMS - 1] = dataclasses.replace(last, message=f"{last.message} (and {more} more problems)")
        del problems[MAX_PROBLEMS:]
    return problems


_TYPE_TAG = re.compile(r"(str|int|float|bool|list|dict|tuple)(\[.*\])?|function-.*|constrained-.*|json-or-python.*")


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


# ---------------------------------------------------------------- samples

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
