"""The root of a scenario: its name, duration, processes, resources, background load, samples and expectations.

One cell of a scenario (matrix values already substituted) validates into a `Scenario`.
Background load (hogs, commands) and the samples setting are the scenario's own keys.
"""

from __future__ import annotations

import enum
import re
from typing import Annotated, Any, Optional

from runner import units
from runner.scenario.model.base import (
    MAX_HOGS,
    MAX_LAST_SAMPLES,
    MAX_LATENCY_LIMIT,
    MAX_RUN,
    MIN_RUN,
    CpuSet,
    Duration,
    Strict,
    _no_control,
    context_cpus,
)
from runner.scenario.model.events import Resource
from runner.scenario.model.expectations import Expectation
from runner.scenario.model.programs import AnyProcess, ProgramSpec, argv_items, argv_list
from runner.scenario.model.sched import Sched
from runner.scenario.model.threads import ProcessSpec, check_comm
from runner.scenario.typed import Context, Field, Written, text_schema

# --------------------------------------------------------------------- background


class HogKind(str, enum.Enum):
    THREAD = "thread"
    PROCESS = "process"


class Hog(Strict):
    """Busy loops that compete for the CPUs while the scenario runs."""

    count: int = Field(description="how many hogs; 'cpus' writes one per online CPU", ge=1, le=MAX_HOGS)
    kind: HogKind = Field(default=HogKind.PROCESS, description="process: one process each; thread: threads of one process")
    name: str = Field(default="hog", description="process and thread name", check=check_comm)
    sched: Optional[Sched] = Field(default=None, description="policy of the hogs (default: inherited, normally SCHED_OTHER)")
    cpus: Optional[CpuSet] = Field(default=None, description="CPUs the hogs may run on (default: all)")

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        if isinstance(value, dict) and value.get("count") == "cpus":
            return {**value, "count": len(context_cpus(context))}
        return value


class Command(Strict):
    """An external program run as background load, started before and stopped after the cell."""

    argv: list[str] = Field(
        min_items=1,
        before=argv_list("argv"),
        check=argv_items("argv"),
        description="program and arguments as a list (never a shell string)",
    )
    name: Optional[str] = Field(default=None, description="label in reports; default: the program", check=_no_control("name"))


class Background(Strict):
    """Contention that runs during each cell and is stopped after it."""

    hogs: list[Hog] = Field(default_factory=list)
    commands: list[Command] = Field(default_factory=list)


# ------------------------------------------------------------------------ samples


class SamplesMode(str, enum.Enum):
    """Which per-callback samples are written to samples.csv.gz (the figures always cover every callback)."""

    ALL = "all"
    NONE = "none"
    OUTLIERS = "outliers"  # callbacks that skipped releases, overran, or woke later than latency_bound
    LAST = "last"  # the last N callbacks of each thread


SAMPLES_EXPECTED = "all, none, outliers or 'last N'"


def _samples_text(value: Any) -> Any:
    if isinstance(value, str):
        word, _, count = value.strip().partition(" ")
        if word == "last":
            try:
                n = units.parse_whole(count, -(1 << 63), (1 << 63) - 1)  # ASCII digits, bounded; the field checks the range
                return {"mode": "last", "last": n}
            except units.UnitError:
                raise ValueError(f"samples {value!r}: expected 'last N' with a whole number N, e.g. 'last 10000'") from None
        return {"mode": word}
    if not isinstance(value, (dict, Samples)):  # null, a number: the model's own message would name its class
        raise ValueError(f"samples {'null' if value is None else repr(value)}: expected {SAMPLES_EXPECTED}")
    return value


class Samples(Strict):
    """What goes to the samples file: `all`, `none`, `outliers` or `last N`."""

    mode: SamplesMode = SamplesMode.ALL
    last: Optional[int] = Field(default=None, ge=1, le=MAX_LAST_SAMPLES, description="with mode last: how many callbacks per thread")

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _samples_text(value)

    def _after(self, written: Any, context: Context) -> None:
        if (self.mode is SamplesMode.LAST) != (self.last is not None):
            raise ValueError("write 'last N' (e.g. 'last 10000'); N goes only with last")

    def label(self) -> str:
        return f"last {self.last}" if self.mode is SamplesMode.LAST else self.mode.value


SamplesSetting = Annotated[
    Samples,
    Written(
        dump=Samples.label,
        schema=text_schema(
            "^(all|none|outliers|last [1-9][0-9]*)$",
            SAMPLES_EXPECTED,
            description="per-callback samples to write: all, none, outliers or last N",
            examples=["all", "outliers", "last 10000"],
        ),
    ),
]


# ----------------------------------------------------------------------- scenario


def _duration_range(value: int) -> int:
    if not MIN_RUN <= value <= MAX_RUN:
        raise ValueError(
            f"duration {units.format_duration(value)} is out of range; expected "
            f"{units.format_duration(MIN_RUN)} to {units.format_duration(MAX_RUN)}"
        )
    return value


RESOURCE_NAME_WORDS = "letters, digits and _ . - (64 at most), starting with a letter or _"


def _resource_names(value: dict[str, Resource]) -> dict[str, Resource]:
    for name in value:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}", name):
            raise ValueError(f"resource name {name!r} may use {RESOURCE_NAME_WORDS}")
    return value


def _bound_range(value: int) -> int:
    if not 0 < value <= MAX_LATENCY_LIMIT:
        raise ValueError(f"latency_bound {units.format_duration(value)} is out of range; expected above 0 and at most 1h")
    return value


SCENARIO_NAME_WORDS = "letters, digits and _ . + - only (it names a results folder)"


def _scenario_name(value: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9_.+-]+", value):
        raise ValueError(f"name {value!r} may use {SCENARIO_NAME_WORDS}")
    return value


class Scenario(Strict):
    """One fully resolved scenario (a matrix cell): what to spawn, for how long, and what to expect."""

    name: str = Field(description="scenario name; default: the file name without .yaml", check=_scenario_name)
    description: str = Field(
        default="", description="what the scenario reproduces and the effect to expect", check=_no_control("description", "\n\t")
    )
    duration: Duration = Field(default=10_000_000_000, description="run time of each cell (the CLI can override)", check=_duration_range)
    processes: list[AnyProcess] = Field(min_items=1, description="the runner's own processes (threads:) and the user's programs (command:)")
    background: Background = Field(default_factory=Background)
    matrix: Any = Field(default=None, description="axes, include and exclude as in GitHub Actions strategy.matrix")
    expect: list[Expectation] = Field(default_factory=list)
    latency_bound: Optional[Duration] = Field(
        default=None,
        description="wake-up latency above which a release counts as an outlier (figure latency.above_bound; samples: outliers)",
        check=_bound_range,
    )
    samples: SamplesSetting = Field(default_factory=Samples, description="per-callback samples to write: all, none, outliers or last N")
    resources: dict[str, Resource] = Field(
        default_factory=dict,
        description="mutexes, conditions, barriers, queues and named timers the threads' events share, by name",
        check=_resource_names,
    )

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave `latency_bound` and `samples` out while unset, so a cell's spec hash reads as before they existed."""
        if self.latency_bound is None:
            data.pop("latency_bound", None)
        if self.samples.mode is SamplesMode.ALL:
            data.pop("samples", None)
        if not self.resources:
            data.pop("resources", None)
        return data

    @property
    def workers(self) -> list[ProcessSpec]:
        """The processes that run the runner's own threads."""
        return workers(self.processes)

    @property
    def programs(self) -> list[ProgramSpec]:
        """The processes that run the user's programs."""
        return [p for p in self.processes if isinstance(p, ProgramSpec)]


def workers(processes: list[ProcessSpec | ProgramSpec]) -> list[ProcessSpec]:
    """The processes of a list that run the runner's own threads (programs left out)."""
    return [p for p in processes if isinstance(p, ProcessSpec)]
