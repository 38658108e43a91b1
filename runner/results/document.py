"""The results document (`runner.results/2`): typed records, declared once, serialised by pydantic.

A run writes `results.json` after every finished cell, atomically (temporary file,
fsync, rename), so a crash or a kill leaves the cells that finished readable.
Raw per-callback samples go beside it, one gzip'd CSV per cell (samplesfile.py).

The models below are the one declaration of the file: `RunDocument.save` writes them
(`model_dump_json`), `read.load` reads them back (`model_validate_json`, strict: `1` is not
`"1"` or `true`), and `results_schema` is their JSON Schema (`results.schema.json`).

The shape of `runner.results/2`, top down:

- the run: `schema`, `tool` {`name`, `version`}, `scenario` {`name`, `path`, `description`},
  `command`, `started_at`, `finished_at`, `status` (`running` until it ends, then the worst
  cell status), `shard`, `merged_from`, `machine`, `permissions`, `start_settings`,
  `cell_ids`, `matrix_cells`, `plan` {`repeat`, `shuffle_seed`, `settle_ns`, `cells`,
  `duration_ns`}, `cells`;
- a cell: `id`, `matrix`, `spec_hash`, `spec` (the resolved cell), `repeat`, `status`,
  `reason`, `started_at`, `duration_ns`, `machine`, `thread_table` (ps rows), `threads`,
  `expectations`, `background`, `overhead_ns`, `samples_file` (relative to the results folder),
  `callbacks` (the ROS 2 callbacks of its `command:` programs, added within /2);
- a ROS 2 callback: `program`, `pids`, `node`, `kind`, `symbol`, `name` (`node/symbol`), `topic`,
  `period_ns`, `clock`, `threads`, `figures` (a thread's, over its instances), `histograms`, `notes`,
  `slowest`; its program's `ros` says what the interposer's capture saw, in counts and words;
- a thread: `key` (derived), `process`, `instance`, `index`, `name`, `pid`, `tid`, `work`,
  `periodic`, `requested` and `applied` {`policy`, `priority`, `nice`, `cpus`}, `degraded`,
  `figures` (threadfigures.ThreadFigures: every duration an integer in ns, e.g. `latency_ns.p99`);
- a verdict: `thread`, `metric` (a figure's name from figures.REGISTRY), `limit` (as the
  scenario wrote it), `measured` (in the figure's unit: ns for durations), `passed`, `note`,
  `line` and `col` (where the expectation is written in the scenario; added within /2, so
  null in older files, which read as before).

Every duration in a /2 file is an integer number of nanoseconds, named `..._ns`; only the
report's formatting scales it.  NaN and infinity are never written (pydantic writes null)
and never read.  Unknown keys in a file are tolerated (a newer runner may add some) and
dropped; in Python, an unknown keyword is an error, so a misspelt field cannot vanish.

`runner.results/1` files (latencies in float microseconds, seconds elsewhere) still load:
`read.load` checks them against their own shape (`legacy._V1File`), converts them (`upgrade_v1`) and
reads the result as a /2 document.  A file of a newer schema is refused, saying so.

Human input goes through runner/scenario/typed.py, machine records through a compiled engine:
these records are pydantic's, validated and written by pydantic-core (one `model_post_init` each).
Why pydantic and not msgspec, measured (issue 39): docs/results.md, "The results engine".
Pydantic stays until a bench target (a load, a run's start) misses because of it.
"""

from __future__ import annotations

import enum
import os
import typing
from typing import TYPE_CHECKING, Annotated, Any, Final, Literal, Optional, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    GetPydanticSchema,
    NonNegativeInt,
    PlainSerializer,
    StrictStr,
    WithJsonSchema,
    computed_field,
)
from pydantic.json_schema import SkipJsonSchema
from pydantic_core import core_schema

from runner import __version__, units
from runner import figures as fg
from runner.errors import Problem, ScenarioError, did_you_mean
from runner.histogram import Histogram
from runner.results.files import samples_path_problem
from runner.results.machinefacts import DMA_LATENCY_NO_LIMIT_US as DMA_LATENCY_NO_LIMIT_US
from runner.results.machinefacts import DmaLatency as DmaLatency
from runner.results.machinefacts import Irq as Irq
from runner.results.machinefacts import IrqThread as IrqThread
from runner.results.machinefacts import MachineInfo as MachineInfo
from runner.results.machinefacts import PermissionsInfo as PermissionsInfo
from runner.results.machinefacts import RtThrottling as RtThrottling
from runner.results.pstable import CLS, TableRow
from runner.results.record import FILE as FILE
from runner.results.record import Record as _Record
from runner.results.threadfigures import Spread, ThreadFigures
from runner.safefs import write_atomic
from runner.scenario.model import MAX_REPEAT, MAX_RUN, MAX_SETTLE, MIN_RUN, Policy
from runner.scenario.plan import Settings

if TYPE_CHECKING:
    pass  # typing's from Python 3.11

SCHEMA: Final = "runner.results/2"
LEGACY_SCHEMA = "runner.results/1"
SCHEMA_ID = "https://github.com/rt-scenario-runner/runner/results.schema.json"


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


def _figure_name(value: Any) -> Any:
    value = value.value if isinstance(value, enum.Enum) else value
    if isinstance(value, str) and value not in fg.BY_NAME:
        raise ValueError(f"unknown figure {value!r}{did_you_mean(value, fg.BY_NAME)}; known: {', '.join(fg.BY_NAME)}")
    return value


FigureName = Annotated[
    StrictStr,
    BeforeValidator(_figure_name),
    WithJsonSchema(
        {"type": "string", "enum": [f.name for f in fg.REGISTRY], "description": "a figure's name, as runner/figures.py declares it"}
    ),
]
Measured = Optional[Union[int, float]]  # int for counts and durations (ns), float for means


CpuList = Annotated[
    tuple[int, ...],
    BeforeValidator(units.parse_cpu_list),
    PlainSerializer(units.format_cpus, return_type=str),
    WithJsonSchema(
        {"type": "string", "description": "CPU list as the kernel writes it (`0-1,3`); empty: not known", "examples": ["0-1,3"]}
    ),
]


class PsRow(_Record):
    """One thread as the kernel reported it (policy numbers as in sched(7)): a row of the cell's ps table.

    Built from a `pstable.ThreadRow` (or anything with its attributes); `cpus` stored as a CPU list string.
    """

    model_config = ConfigDict(frozen=True, from_attributes=True)

    pid: int
    tid: int
    comm: str
    policy: int = Field(description="sched(7) number; `cls` names it as ps does")
    rtprio: int
    nice: int
    psr: int
    prio: Optional[int] = Field(description="/proc stat field 18 (kernel prio, shifted); null where not recorded (results/1 files)")
    cpus: CpuList = ()
    voluntary: Optional[int] = None
    involuntary: Optional[int] = None

    @computed_field(description="the policy as ps names it (TS, FF, RR, B, IDL, DLN)")  # type: ignore[prop-decorator]
    @property
    def cls(self) -> str:
        return CLS.get(self.policy, "?")


def ps_rows(rows: typing.Iterable[TableRow]) -> list[PsRow]:
    """Rows read from /proc as results store them."""
    return [PsRow.model_validate(r) for r in rows]


class Verdict(_Record):
    """One expectation checked against one thread; `measured` in the figure's unit (ns for durations)."""

    thread: str = Field(description="the thread's label, as the report names it")
    metric: FigureName
    limit: str = Field(description="the limit as the scenario wrote it, e.g. `<= 2ms`")
    measured: Measured = Field(description="the figure's value in its unit (integer ns for durations); null: not measured")
    passed: bool
    note: str = ""
    samples: Optional[NonNegativeInt] = Field(
        None, description="for a percentile, mean or extreme: how many values it stands on (wake-ups, releases); null otherwise"
    )
    line: Optional[Annotated[int, Field(ge=1)]] = Field(
        None, description="where the expectation is written in the scenario file (`scenario.path`), 1-based; null: not recorded"
    )
    col: Optional[Annotated[int, Field(ge=1)]] = Field(None, description="its column, 1-based; null: not recorded")

    @property
    def figure(self) -> fg.Figure:
        return fg.figure(self.metric)

    @property
    def unmeasured(self) -> str:
        """Why there is no measured value, in words (`not measured (no callbacks)`); "" when there is one.

        Said in place of the value, never after "measured": "measured not measured" reads as nothing.
        """
        if self.measured is not None:
            return ""
        return self.note if self.note.startswith(NOT_MEASURED) else NOT_MEASURED + (f" ({self.note})" if self.note else "")


NOT_MEASURED = "not measured"
"""How a verdict without a value begins its note: `not measured (why)`."""


class ThreadHistograms(_Record):
    """A thread's distributions, exact to the bucket (runner/histogram.py): what its percentiles come from, what their
    intervals are made of (runner/results/estimates.py), and what merges exactly across repeats and nights."""

    latency: Optional[Histogram] = Field(None, description="wake-up latency of every release answered, in ns")
    slack: Optional[Histogram] = Field(None, description="end of each callback to its next release, in ns (negative: overran)")
    callback_wall: Optional[Histogram] = Field(None, description="wake to end of each callback, in ns")
    wakeup: Optional[Histogram] = Field(
        None, description="scheduler trace: from each sched_waking to the switch onto a CPU, in ns (added within /2: null before)"
    )
    message_age: Optional[Histogram] = Field(
        None, description="ROS 2 callbacks: each taken message's age at the start of its callback, in ns (added within /2)"
    )


def _cpus_in(value: Any) -> Any:
    """`all` is every CPU (None); any other text is a CPU list (`0-1,3`)."""
    return None if value == "all" else units.parse_cpu_list(value)


def _cpus_out(cpus: Optional[tuple[int, ...]]) -> str:
    return "all" if cpus is None else units.format_cpus(cpus)


AffinityCpus = Annotated[
    Optional[tuple[int, ...]],
    BeforeValidator(_cpus_in),
    PlainSerializer(_cpus_out, return_type=str),
    WithJsonSchema({"type": "string", "description": "CPU list as the kernel writes it (`0-1,3`), or `all`", "examples": ["all", "0-1,3"]}),
]


class _SettingsRecord(BaseModel):
    """How a file writes a thread's settings (`runner.scenario.plan.Settings`), read back: its fields, the CPUs as a list."""

    policy: Policy = Policy.OTHER
    priority: int = 0
    nice: int = 0
    cpus: AffinityCpus = None
    runtime: int = 0
    deadline: int = 0
    period: int = 0


def _settings_in(record: _SettingsRecord) -> Settings:
    return Settings(**{f: getattr(record, f) for f in _SettingsRecord.model_fields})


def _settings_out(value: Settings) -> dict[str, Any]:
    """Settings as stored: the SCHED_DEADLINE parameters only for deadline threads, so other records read as before."""
    data: dict[str, Any] = {f: getattr(value, f) for f in _SettingsRecord.model_fields}
    data["policy"] = value.policy.value
    data["cpus"] = _cpus_out(value.cpus)
    if value.policy is not Policy.DEADLINE:
        for key in ("runtime", "deadline", "period"):
            data.pop(key, None)
    return data


StoredSettings = Annotated[
    Settings,
    GetPydanticSchema(
        lambda _tp, handler: core_schema.union_schema(
            [
                core_schema.is_instance_schema(Settings),  # made by the run
                core_schema.no_info_after_validator_function(_settings_in, handler(_SettingsRecord)),  # read from a file
            ],
            mode="left_to_right",
            serialization=core_schema.plain_serializer_function_ser_schema(_settings_out, return_schema=core_schema.dict_schema()),
        )
    ),
]
"""A thread's settings in results.json: `{policy, priority, nice, cpus}`, plus `runtime, deadline, period` (ns) for deadline."""


class Holder(_Record):
    """A thread that held a mutex when another had to wait for it."""

    thread: str = Field(description="the holder, as the report names threads")
    contentions: NonNegativeInt = Field(description="acquisitions that found it holding the mutex")
    wait_ns: NonNegativeInt = Field(description="time the waiter spent on those acquisitions")


class EventResult(_Record):
    """One event of a thread's program, as the native core measured it."""

    phase: str
    index: NonNegativeInt = Field(description="the event's position in the thread's program, from 0")
    event: str = Field(description="the event in words: `lock data`, `timer 1ms`, `run 200us`")
    kind: str = Field(description="run, runtime, sleep, timer, lock, unlock, wait, signal, broadcast, barrier, suspend, resume, ...")
    resource: Optional[str] = None
    measures: str = Field(description="what its figures are: wait (lock, wait, barrier), latency (timer, suspend) or wall time")
    count: NonNegativeInt
    total_ns: int = 0
    spread_ns: Optional[Spread] = None
    contended: NonNegativeInt = Field(0, description="lock: acquisitions that had to wait")
    holders: list[Holder] = Field(default_factory=list, description="lock: who held the mutex when this thread waited")
    dropped: NonNegativeInt = Field(0, description="spawn: spawns that found every instance of the thread taken, or the kernel refused")
    lost: NonNegativeInt = Field(
        0, description="resume of a queue with pending: drop: resumes that came while no thread was suspended on it (rt-app's loss)"
    )
    cut: NonNegativeInt = Field(
        0,
        description="times the event was under way when the run ended (or was stopped): cut short, so in neither count nor figures",
    )


class PhaseResult(_Record):
    """One phase of a thread's program: how often it ran, what it cost, and its settings as the kernel reported them."""

    name: str
    passes: NonNegativeInt = Field(description="passes over the phase's events")
    entered: NonNegativeInt = 0
    time_ns: NonNegativeInt = 0
    involuntary: NonNegativeInt = 0
    voluntary: NonNegativeInt = 0
    minor_faults: NonNegativeInt = 0
    major_faults: NonNegativeInt = 0
    cpus_seen: list[int] = Field(default_factory=list)
    applied: Optional[StoredSettings] = Field(None, description="read back by the thread itself (sched_getattr, affinity) on entering")
    requested: Optional[StoredSettings] = Field(None, description="what the phase applies on entry; null when it applies nothing")
    degraded: list[str] = Field(default_factory=list)


class SettingsSnapshot(_Record):
    """A program thread's name and settings at one instant, read from the kernel."""

    at_ns: int = Field(description="since the cell's start gate (negative: before it)")
    comm: str
    settings: StoredSettings
    why: str = Field(description="appeared, rule (a thread rule was applied) or changed (it changed, by itself or by another)")


class HistoryGap(_Record):
    """The changes of a program thread's settings its `history` left out: it keeps its first and its latest snapshots.

    A thread that changes its priority at every callback would otherwise make results.json
    grow with every change for as long as the program ran.
    """

    count: NonNegativeInt = Field(description="changes of its settings that were seen and not kept")
    from_ns: int = Field(description="the first of them, since the cell's start gate")
    to_ns: int = Field(description="the last of them, since the cell's start gate")
    kept_first: NonNegativeInt = Field(description="the snapshots kept from its start (it appeared, its rule, its first changes)")
    kept_last: NonNegativeInt = Field(description="the most recent snapshots kept (its rule's is kept wherever it falls)")


class FoldedRule(_Record):
    """A thread rule as applied to a program's folded threads."""

    rule: str = Field(description="the rule's pattern")
    applied: NonNegativeInt = Field(description="folded threads it was applied to")
    not_as_asked: NonNegativeInt = Field(
        description="of them, those where the kernel refused part of it or read back other settings (for each rule, one such "
        "thread is kept in threads, where its degradation is said)"
    )


class FoldedThreads(_Record):
    """A program's threads that exited once it had `cap` thread records: counted together here, not kept one by one in `threads`.

    A program that starts a thread per request would otherwise add a thread to the
    results (and to the runner's memory) for every request.  Threads still alive are
    never folded: they are in `threads`, measured to the end.
    """

    cap: NonNegativeInt = Field(description="the thread records a program keeps before the threads that exit are folded")
    count: NonNegativeInt = Field(description="threads that came and went and were not kept one by one")
    measured: NonNegativeInt = Field(
        description="of them, those whose counters were read in the measured window; the sums below are theirs, each up to its "
        "last reading (every 50 ms), as a kept thread's are"
    )
    voluntary: NonNegativeInt = 0
    involuntary: NonNegativeInt = 0
    minor_faults: NonNegativeInt = 0
    major_faults: NonNegativeInt = 0
    cpu_time_ns: NonNegativeInt = 0
    migrations: Optional[NonNegativeInt] = Field(None, description="null: the kernel did not give them for every one (CONFIG_SCHED_DEBUG)")
    first_seen_ns: int = Field(description="the first of them appeared, since the cell's start gate")
    last_gone_ns: int = Field(description="the last of them was found gone, since the cell's start gate")
    rules: list[FoldedRule] = Field(default_factory=list, description="the thread rules applied to them")


class Preemptor(_Record):
    """A task that took the CPU from a thread while it was runnable, from the scheduler's trace."""

    comm: str
    tid: int
    pid: Optional[int] = Field(None, description="its process, when it was still there to ask; null: unknown")
    cls: str = Field(description="its class as ps writes it: TS, FF, RR, DLN, or RT where FIFO and RR cannot be told apart")
    rtprio: Optional[int] = Field(None, description="its RT priority (FF, RR, RT)")
    count: NonNegativeInt


class PreemptedRun(_Record):
    """One of a thread's most preempted runs, from the scheduler's trace: a run lasts from the
    switch-in that ended a wake-up to the next voluntary switch-out, so for a thread with
    callbacks it is one callback, and this says why that callback took long."""

    at_ns: int = Field(description="its start, from the start of the measured window (add trace.window_start_ns for CLOCK_MONOTONIC)")
    wall_ns: NonNegativeInt = Field(description="from its start to its end")
    preempted_ns: NonNegativeInt = Field(description="time it was runnable but off its CPU")
    preemptions: NonNegativeInt
    by: Preemptor = Field(description="the task that held the CPU from it longest; count: its preemptions of this run")
    by_ns: NonNegativeInt = Field(description="how long that task held the CPU from it")


class ThreadResult(_Record):
    """One measured thread: identity, requested vs applied settings, figures."""

    process: str
    instance: NonNegativeInt
    index: NonNegativeInt = Field(description="0 for the main thread, then creation order")
    name: str
    pid: int
    tid: int
    work: str = Field(description="the thread's work, in words")
    periodic: bool = Field(description="runs callbacks released on a period (periodic work, or a program with a timer)")
    released: bool = Field(
        False, description="programs: its callbacks are released by resumes (a later stage of a chain): no slack or missed releases"
    )
    requested: StoredSettings
    applied: Optional[StoredSettings] = Field(description="as read back from the kernel; null when the thread was gone")
    degraded: list[str] = Field(default_factory=list, description="how the applied settings fell short, in words")
    figures: ThreadFigures
    histograms: Optional[ThreadHistograms] = None
    samples_written: NonNegativeInt = Field(0, description="per-callback rows written to the samples file")
    samples_lost: NonNegativeInt = Field(0, description="rows the runner could not write in time (the figures still count them)")
    events: list[EventResult] = Field(default_factory=list, description="programs (kind: phases): per event")
    phases: list[PhaseResult] = Field(default_factory=list, description="programs (kind: phases): per phase")
    spawned: bool = Field(False, description="created mid-run by a spawn event of another thread (rt-app's fork)")
    began_ns: Optional[int] = Field(
        None,
        description="when it began its work, since the cell's common start, as the thread read its clock (start: in_order, a spawn "
        "or a late release make it later); null: it never began, or is measured from outside",
    )
    program: bool = Field(False, description="a thread of a user's program (command:), measured from outside")
    rule: Optional[str] = Field(None, description="programs: the pattern of the thread rule applied to it")
    rule_after_ns: Optional[int] = Field(None, description="programs: from its matching name appearing to the rule applied")
    history: list[SettingsSnapshot] = Field(default_factory=list, description="programs: its settings when it appeared and changed")
    history_not_kept: Optional[HistoryGap] = Field(
        None, description="programs: the changes `history` left out, beyond its first and latest snapshots; null: it holds them all"
    )
    preempted_by: list[Preemptor] = Field(
        default_factory=list, description="who took the CPU while it was runnable, most often first (scheduler trace)"
    )
    late_wakeups: NonNegativeInt = Field(
        0, description="wake-ups above its trace p99 among its 64 worst, whose delayer is named in late_wakeups_by"
    )
    late_wakeups_by: list[Preemptor] = Field(
        default_factory=list, description="who held the CPU while those late wake-ups waited for it (idle: the wake-up path itself)"
    )
    preempted_runs: list[PreemptedRun] = Field(
        default_factory=list, description="its 16 most preempted runs (callbacks, for a thread with callbacks), most preempted first"
    )

    @property
    def has_callbacks(self) -> bool:
        """It runs callbacks: periodic, or released by resumes."""
        return self.periodic or self.released

    def callback_settings(self) -> list[Settings]:
        """The settings the kernel reported for the thread while it ran its callbacks, each once, in order.

        A program (`kind: phases`) changes its settings phase by phase, and each phase reads them back
        on entry: its callbacks ran under those of its phases with a timer or a suspend (every phase it
        entered when none has), not under `applied`, read as it started.  Other threads: `applied`.
        """
        entered = [p for p in self.phases if p.entered and p.applied is not None]
        releasing = {e.phase for e in self.events if e.kind in ("timer", "suspend")}
        phases = [p for p in entered if p.name in releasing] or entered
        out: list[Settings] = []
        for p in phases:
            if p.applied is not None and p.applied not in out:
                out.append(p.applied)
        return out or ([self.applied] if self.applied is not None else [])

    @computed_field(description="the thread's identity across cells and runs: `process[instance]/name (main)` or `... #index`")  # type: ignore[prop-decorator]
    @property
    def key(self) -> str:
        return thread_key(self.process, self.instance, self.index, self.name)

    def label(self, show_instance: bool) -> str:
        """This thread's name in rows and tables (see `thread_label`)."""
        return thread_label(self.process, self.instance, self.index, self.name, show_instance)


class TraceInfo(_Record):
    """The scheduler trace of a cell: whether it ran, what it read, what it lost, what it cost."""

    enabled: bool
    reason: str = Field("", description="why there was no trace, in words")
    events: NonNegativeInt = 0
    lost: NonNegativeInt = Field(0, description="events the kernel dropped or overwrote: the figures are undercounted")
    untracked: NonNegativeInt = Field(0, description="events of threads beyond the reader's bounded table")
    unseen_switch_ins: NonNegativeInt = Field(0, description="switches onto a CPU the kernel did not trace (their wake-ups go unmeasured)")
    reader_cpu_ns: NonNegativeInt = Field(0, description="CPU time the native reader spent")
    duration_ns: NonNegativeInt = 0
    window_start_ns: Optional[int] = Field(
        None, description="CLOCK_MONOTONIC of the measured window's start, the clock of samples.csv.gz's times"
    )
    notes: list[str] = Field(default_factory=list)


class CallbackThread(_Record):
    """A thread a ROS 2 callback ran on, as the interposer saw it."""

    tid: int
    comm: str
    count: NonNegativeInt = Field(description="instances of the callback it ran")


class CallbackInstance(_Record):
    """One instance of a ROS 2 callback (among the slowest): when, where and what it suffered, to join with the trace."""

    at_ns: int = Field(description="its start, from the cell's start gate (the origin of a thread's preempted_runs)")
    wall_ns: NonNegativeInt = Field(description="from its start to its end")
    tid: int
    involuntary: NonNegativeInt = Field(description="involuntary switches of its thread during it (getrusage)")
    latency_ns: Optional[int] = Field(None, description="from its release to its start (timer callbacks with a release grid)")


class CallbackResult(_Record):
    """A ROS 2 callback of a user's program, measured instance by instance from inside the program (issue 38).

    Its figures are a thread's (`ThreadFigures`) over its instances: for a timer callback the
    release grid from the timer's period and first release (latency is from a release to the
    start of the callback that served it; missed releases are those rcl skipped), for a callback
    that took messages their age at its start; chain figures when messages of a timer callback reached it.
    """

    program: str
    pids: list[int] = Field(default_factory=list, description="the processes of the program it ran in")
    node: str = Field("", description="its node, `namespace/name` (no leading slash); '' when unknown")
    kind: str = Field(description="timer, subscription, service, or callback (the interposer saw no registration)")
    symbol: str = Field("", description="as rclcpp gave it (tracetools::get_symbol), lightly prettified; '' when it gave none")
    name: str = Field(description="`node/symbol`, or `node/kind detail`; numbered (` #2`) when two of a program share one")
    topic: str = Field("", description="the topic or service it takes from; '' for a timer")
    period_ns: Optional[int] = Field(None, description="a timer's period")
    clock: str = Field("", description="a timer's clock: steady, system, ros, or unknown")
    threads: list[CallbackThread] = Field(default_factory=list)
    figures: ThreadFigures
    histograms: Optional[ThreadHistograms] = None
    notes: list[str] = Field(default_factory=list, description="what limits its figures, in words")
    slowest: list[CallbackInstance] = Field(default_factory=list, description="its slowest instances, slowest first")

    @property
    def label(self) -> str:
        """How verdicts and tables name it: `program: node/symbol`."""
        return callback_label(self.program, self.name)

    @property
    def key(self) -> str:
        """Its identity across cells, runs and nights, beside the threads' keys (comparison, history): its label."""
        return self.label


def callback_label(program: str, name: str) -> str:
    """A ROS 2 callback's label in verdicts, keys and tables: `program: node/symbol`."""
    return f"{program}: {name}"


class RosCaptureInfo(_Record):
    """What the interposer's capture of one program said (issue 38), in words and counts."""

    seen: bool = Field(description="some ROS 2 callback of it was seen")
    processes: NonNegativeInt = Field(0, description="its processes that reached a hook")
    callbacks: NonNegativeInt = Field(0, description="distinct callbacks seen")
    instances: NonNegativeInt = Field(0, description="callback instances recorded")
    lost: NonNegativeInt = Field(0, description="records lost: overwritten in a full ring, or not written")
    publishes: NonNegativeInt = Field(0, description="messages it published")
    publishes_unmatched: NonNegativeInt = Field(
        0, description="of those, messages no callback of the cell took (dropped, or nobody listened)"
    )
    notes: list[str] = Field(default_factory=list, description="what the capture says, in words: why no callbacks, what was lost")


NOT_STARTED = "did not start: the cell stopped before its start"
"""A program's `failure` when it never exec'd because its cell stopped first (followed by ` because ...`, when known)."""


class ProgramResult(_Record):
    """A user's program (command:) in one cell: how it started and ended, and where its output went."""

    name: str
    argv: list[str]
    path: str = Field("", description="the program as found in PATH")
    pid: Optional[int] = None
    started: bool = Field(description="it was exec'd")
    failure: str = Field("", description="why it could not start")
    requested: StoredSettings = Field(description="the process's settings, applied before exec")
    degraded: list[str] = Field(default_factory=list, description="process-level settings the kernel refused")
    exit_code: Optional[int] = Field(None, description="its exit status; null: a signal ended it, or it never ran")
    exit_signal: Optional[str] = Field(None, description="the signal that ended it, e.g. SIGSEGV")
    stopped: str = Field("", description="how the runner ended it: SIGTERM, SIGKILL (it ignored SIGTERM for the grace period), or ''")
    ran_ns: Optional[int] = Field(None, description="from its exec to its exit")
    stdout: str = Field("", description="file of its standard output, in the cell's folder")
    stderr: str = ""
    output_limit: Optional[int] = Field(
        None, description="bytes each of stdout and stderr kept at most (output_limit); null: not captured (runner watch) or not recorded"
    )
    stdout_bytes: Optional[NonNegativeInt] = Field(
        None, description="bytes it (and what it started) wrote to its standard output, kept or not; null: not counted"
    )
    stdout_dropped: Optional[NonNegativeInt] = Field(
        None, description="of those, bytes not in the file: beyond output_limit, or after the file could not be written"
    )
    stderr_bytes: Optional[NonNegativeInt] = None
    stderr_dropped: Optional[NonNegativeInt] = None
    tail: list[str] = Field(default_factory=list, description="the last lines of its output")
    threads_seen_by: str = Field(
        "",
        description="how its new and renamed threads were found: 'events' (the kernel's process events as they happen; rule_after_ns "
        "counts from the kernel's instant of the creation or renaming) or 'listing' (/proc every 2 ms; rule_after_ns counts from "
        "the listing that saw the name); '' in files written before it was recorded",
    )
    threads_seen_note: str = Field("", description="why not (or not always) by events, in words")
    memory_max: Optional[int] = Field(None, description="its memory limit (bytes) as its memory cgroup held it; null: none")
    memory_peak: Optional[int] = Field(None, description="the most memory (bytes) its cgroup was charged with, itself and all it started")
    oom_kills: Optional[int] = Field(None, description="its tasks (itself or what it started) the OOM killer ended at memory_max")
    threads_folded: Optional[FoldedThreads] = Field(
        None, description="its threads that exited beyond its cap of thread records, counted together; null: every thread is in threads"
    )
    ros: Optional[RosCaptureInfo] = Field(None, description="its ROS 2 callbacks as the interposer saw them; null: callbacks: off, or none")


class Overhead(_Record):
    """What the runner itself costs a cell, in ns: None where it could not be measured."""

    start_to_first_callback: Optional[int] = Field(None, description="from the runner starting on the cell to its first callback")
    last_callback_to_exit: Optional[int] = Field(None, description="from the last callback's end to the cell's processes exiting")
    end_to_saved: Optional[int] = Field(
        None, description="from the end of the measured window to the results file's write (that write's own time excluded)"
    )
    save: Optional[int] = Field(
        None,
        description="that write's own time (results.json or its journal line); stored by the next rewrite of results.json (the run's"
        " last at least), so null in a journal line and when none came",
    )


class BackgroundKind(str, enum.Enum):
    HOG = "hog"
    COMMAND = "command"


class Background(_Record):
    """One background load process of a cell: a busy-loop hog or a command."""

    kind: BackgroundKind
    name: str = Field("", description="a hog's process name; a command's name: (its program when it has none; empty in older files)")
    argv: list[str] = Field(default_factory=list)
    pid: Optional[int] = None
    log: Optional[str] = Field(None, description="a command's output file in the cell's folder, stdout and stderr together")
    output_bytes: Optional[int] = Field(None, description="bytes a command wrote to its output, kept or not; null for hogs and older files")
    output_dropped: Optional[int] = Field(
        None, description="of them, bytes not kept: beyond the first 64 MiB, or after a write to the log failed"
    )


class Plan(_Record):
    """The run's options that `--resume` reuses."""

    repeat: Annotated[int, Field(ge=1, le=MAX_REPEAT)] = 1
    shuffle_seed: Optional[int] = None
    settle_ns: Optional[Annotated[int, Field(ge=0, le=MAX_SETTLE)]] = Field(None, description="pause between cells; null: the default")
    cells: list[str] = Field(default_factory=list, description="the --cell globs")
    duration_ns: Optional[Annotated[int, Field(ge=MIN_RUN, le=MAX_RUN)]] = Field(None, description="--duration; null: the scenario's")
    trace: Optional[bool] = Field(None, description="scheduler traced (false: --no-trace); null: not recorded, nor dma_latency_us")
    dma_latency_us: Optional[NonNegativeInt] = Field(None, description="/dev/cpu_dma_latency asked for (--dma-latency); null: left alone")
    expect_hash: Optional[str] = Field(None, description="the expectations, hashed: --resume refuses a change; null: not recorded")
    scenario_hash: Optional[str] = Field(None, description="the scenario as written, hashed: merge refuses shards of another version")


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


RunStatus = Annotated[
    StrictStr,
    BeforeValidator(_status_value),
    AfterValidator(_run_status),
    WithJsonSchema({"type": "string", "enum": ["running"] + [s.value for s in Status]}),
]


class CellResult(_Record):
    """One cell of the matrix, as run."""

    id: str
    matrix: dict[str, Any] = Field(default_factory=dict, description="the cell's matrix values")
    spec_hash: str
    spec: dict[str, Any] = Field(default_factory=dict, description="the resolved cell as hashed, to say what differs")
    repeat: Annotated[int, Field(ge=0, le=MAX_REPEAT)] = 0
    status: Status
    reason: str = ""
    unwritten: bool = Field(False, description="the disk refused the cell's files (full, read-only): --resume runs it again")
    warnings: list[str] = Field(default_factory=list, description="what the figures show went wrong without failing an expectation")
    started_at: str = ""
    duration_ns: NonNegativeInt = 0
    machine: Optional[MachineInfo] = None
    thread_table: list[PsRow] = Field(default_factory=list, description="the threads as the kernel held them mid-run")
    programs: list[ProgramResult] = Field(default_factory=list, description="the user's programs (command:)")
    trace: Optional[TraceInfo] = Field(None, description="the scheduler trace; null: a run from before tracing existed")
    threads: list[ThreadResult] = Field(default_factory=list)
    callbacks: list[CallbackResult] = Field(default_factory=list, description="the ROS 2 callbacks of its programs (added within /2)")
    expectations: list[Verdict] = Field(default_factory=list)
    background: list[Background] = Field(default_factory=list)
    overhead_ns: Overhead = Field(default_factory=Overhead)
    samples_file: Optional[str] = Field(None, description="relative to the results file's folder")

    @property
    def duration_s(self) -> float:
        return self.duration_ns / 1e9


INDENT_BELOW = 1 << 20
"""results.json is written indented while its compact form is smaller than this (characters)."""


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
    start_settings: StoredSettings = Field(default_factory=Settings, description="what the processes the runner starts inherit")
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

    def save(self, path: str) -> int:
        """Write the document to `path` atomically; a figure that is not a number is stored as null.

        Indented while its compact form is under INDENT_BELOW, to be read by eye; a larger one is one line
        (`jq .` shows it indented): indenting a 1,024-thread cell makes it 2.9 times as large
        (7.1 MB against 2.5 MB) and its serialisation and write twice as slow.
        Returns the size written, in bytes.
        """
        text = self.model_dump_json(by_alias=True)
        if len(text) < INDENT_BELOW:
            text = self.model_dump_json(indent=2, by_alias=True)
        blob = (text + "\n").encode("utf-8")
        write_atomic(path, blob)
        return len(blob)

    def planned_runs(self) -> set[tuple[str, int]]:
        """The cell runs (id, repeat) it was asked for, none for a merge: its inputs may cover part of the matrix it names."""
        return set() if self.merged_from else {(c, r) for c in self.cell_ids for r in range(self.plan.repeat)}

    def missing_runs(self) -> int:
        """How many of `planned_runs` it does not hold."""
        return len(self.planned_runs() - {(c.id, c.repeat) for c in self.cells})

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
    schema["description"] = (
        f"A run's results.json ({SCHEMA}): every duration an integer in nanoseconds, named *_ns; a figure that is not a number is null."
    )
    return schema
