"""Every figure the runner measures, declared once: name, unit, words, scope, default comparison threshold.

A figure's name is the one users write in expectations (`latency.p99`), in `--threshold`
and find in results.json; its unit says how it is stored (nanoseconds as integers for
durations, plain counts otherwise) and how it is shown; its words are what the report
and the comparison call it; its scope says which kinds of thread have it (`ThreadKind`,
`has`: validation refuses an expectation no thread it names can meet, a run fails it
`not measured`).  Expectations (the scenario's `metric` enum and its schema),
comparison (figures and default thresholds), the report's verdict rows and the
terminal's columns are all derived from `REGISTRY`, so a new figure is one entry here
plus the line of the evaluation core that measures it.

A figure's sampling error (`Sampling`: how its interval is made and a change of it tested, and
how many samples it needs to be judged at all) is part of its entry too, declared for counts
and derived from the path for a spread's quantiles and means; runner/results/estimates.py
applies it and runner/stats.py holds the exact statistics.

The measured values of one thread live in `ThreadFigures` (typed, integers in ns; in
runner.results.threadfigures), which the evaluation core produces and the results
document stores.  Pure: no I/O.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional, Union

if TYPE_CHECKING:
    from runner.results.threadfigures import ThreadFigures

Number = Union[int, float]


class Unit(str, enum.Enum):
    """How a figure is stored and shown; only formatting ever scales a value."""

    NS = "ns"  # a duration: integer nanoseconds inside, us/ms/s when shown
    COUNT = "count"  # events: switches, faults, callbacks
    PER_CALLBACK = "per callback"  # a mean of counts over callbacks (a float)
    PER_SECOND = "per second"  # counts over the time they were counted in (a float)


MINUS = "\u2212"  # the one minus sign of every number the report and the comparison write
_DURATION_UNITS = (("µs", 1_000), ("ms", 1_000_000), ("s", 1_000_000_000))


@dataclass(frozen=True)
class Scale:
    """How a column (or a row) of values of one unit is written: one unit, one precision, for all of them.

    The unit goes in the header (`p99 (µs)`), the numbers stand alone and right-aligned, so a
    column never mixes `124 µs` with `3.16 ms` and a limit reads in the unit of what it limits.
    """

    unit: str = ""  # µs, ms or s for durations; "" for counts and means of counts
    per: int = 1  # stored units in one shown unit: 1,000 ns in a µs
    decimals: int = 0

    def number(self, value: Optional[Number], sign: bool = False) -> str:
        """`value` (in the stored unit) in this scale: `3,160`, `58.4`, `−11.7`; `+` too with `sign`; `–` for none."""
        if value is None or not math.isfinite(value):
            return "–"
        shown = value / self.per
        text = f"{abs(shown):,.{self.decimals}f}"
        if shown < 0 and text.strip("0.,"):  # a value that rounds to zero is 0, not −0
            return MINUS + text
        return "+" + text if sign else text

    def header(self, words: str) -> str:
        """A column's header with its unit: `Wake-up p99 (µs)`."""
        return f"{words} ({self.unit})" if self.unit else words


_LONGEST_NUMBER = 10_000_000  # a duration column steps down to a smaller unit only while its largest stays below this


def scale(unit: Unit, values: Iterable[Optional[Number]] = ()) -> Scale:
    """The one scale `values` of `unit` are written in.

    Durations in µs up to 10 ms (the unit of cyclictest and OSADL's plots), then ms up to 10 s,
    then s; with one decimal when the largest is below 100 in that unit and none above, so the
    largest keeps three significant digits (the histograms hold 0.78%) and all share its
    precision.  But no value that is not zero may read as 0 or lose its first two digits: a
    column of an OTHER cell's 142 ms beside a FIFO cell's 176 µs wrote the FIFO one as `0` ms.
    Such a column steps down a unit (142,318 and 176 µs) while its largest stays under ten
    million, then takes decimals (up to 3) for its smallest; in µs, only a value under half a
    microsecond takes them (a lock wait of 117 ns beside 7 ms).  Means of counts per callback
    with two decimals, counts whole.
    """
    if unit is Unit.COUNT:
        return Scale()
    if unit is Unit.PER_CALLBACK:
        return Scale(decimals=2)
    if unit is Unit.PER_SECOND:
        return Scale(decimals=1)
    sizes = [abs(v) for v in values if v is not None and math.isfinite(v) and v != 0]
    largest, smallest = max(sizes, default=0), min(sizes, default=0)
    at = next((i for i, (_, p) in enumerate(_DURATION_UNITS) if largest < 10_000 * p), len(_DURATION_UNITS) - 1)

    def decimals(per: int) -> int:
        return 1 if largest / per < 100 else 0

    def too_coarse(per: int, places: int) -> bool:  # the smallest would show fewer than two significant digits
        return bool(smallest) and smallest / per < 10 ** (1 - places)

    while at > 0 and too_coarse(_DURATION_UNITS[at][1], decimals(_DURATION_UNITS[at][1])):
        if largest / _DURATION_UNITS[at - 1][1] >= _LONGEST_NUMBER:
            break
        at -= 1
    name, per = _DURATION_UNITS[at]
    places = decimals(per)
    while places < 3 and too_coarse(per, places) and (at > 0 or round(smallest / per, places) == 0):
        places += 1  # in µs only what would read 0 takes decimals: whole microseconds otherwise, as cyclictest prints them
    return Scale(name, per, places)


class Scope(str, enum.Enum):
    """Which threads have the figure."""

    CALLBACKS = "callbacks"  # only threads that run callbacks (periodic, or released by resumes): per-callback figures, latency
    THREAD = "thread"  # every thread (whole-thread totals from getrusage)
    OUTSIDE = "outside"  # threads measured from outside: programs' threads (/proc), and any thread the scheduler trace followed
    EVENTS = "events"  # only threads whose program has the events the figure is about (locks, waits, chains)
    ROS = "ros"  # only ROS 2 callbacks measured inside a user's program (`callback:` expectations): per message taken


class Worse(str, enum.Enum):
    """Which way a figure moves when things get worse: most grow (latency, misses), slack shrinks."""

    HIGHER = "higher"
    LOWER = "lower"


class Sampling(str, enum.Enum):
    """What a figure's sampling error is made of, which sets its interval and the test of a change (runner/stats.py).

    Declared in the registry for counts; derived from the path for a spread's values (a quantile,
    the min or max, the mean), so no figure is judged by a method declared elsewhere.
    """

    QUANTILE = "quantile"  # an order statistic of the thread's histogram: distribution-free interval, exceedance test
    MEAN = "mean"  # a mean of many samples: its standard error
    PROPORTION = "proportion"  # events out of trials (missed of releases): exact binomial interval, Fisher's test
    RATE = "rate"  # events over an exposure (switches per callback, faults per second): exact Poisson
    EXACT = "exact"  # no sampling error to speak of (a count the period fixes, a total, an extreme count): its threshold alone


_LEVELS = {"min": 0.0, "p1": 0.01, "p50": 0.5, "p90": 0.9, "p99": 0.99, "p999": 0.999, "max": 1.0}
_HISTOGRAMS = {
    "latency_ns": "latency",
    "slack_ns": "slack",
    "callback_wall_ns": "callback_wall",
    "wakeup_ns": "wakeup",
    "message_age_ns": "message_age",
}
MEAN_MIN_SAMPLES = 30  # below this a mean's normal interval is no interval


@dataclass(frozen=True)
class Threshold:
    """A default regression threshold: worse by more than `relative` (a fraction) and/or `absolute` (in the unit)."""

    relative: Optional[float] = None
    absolute: Optional[Number] = None


@dataclass(frozen=True)
class Figure:
    """One measured figure of a thread."""

    name: str
    words: str
    unit: Unit
    scope: Scope
    path: tuple[str, ...]  # where the value lives in ThreadFigures
    threshold: Optional[Threshold] = None  # compared against a baseline by default when set
    column: Optional[str] = None  # header in the terminal's per-thread table, when shown there
    worse: Worse = Worse.HIGHER
    signed: bool = False  # may be negative (slack of a callback that overran)
    overload: bool = False  # tells whether a thread kept up: its column is shown when some thread did not
    needs_period: bool = False  # measured against a period's next release: a thread released by resumes has no such figure
    traced: bool = False  # taken from the scheduler trace: undercounted when it lost events, so not compared then
    sampling: Optional[Sampling] = None  # None: derived from the path (`kind`)
    trials: Optional[str] = None  # PROPORTION: the figure counting the trials; RATE: the exposure's (None: the cell's seconds)
    events: Optional[str] = None  # RATE given per second: the figure counting its events
    in_trace: bool = False  # the scheduler trace measures it for every thread it follows (traced ones, and migrations)
    of_callbacks: bool = False  # a figure of another scope that ROS 2 callbacks have too (their chains across processes)

    @property
    def is_duration(self) -> bool:
        return self.unit is Unit.NS

    @property
    def kind(self) -> Sampling:
        """How the figure's sampling error is judged: declared, or derived from where it lives in a spread."""
        if self.sampling is not None:
            return self.sampling
        last = self.path[-1]
        if self.unit is Unit.NS and last in _LEVELS:
            return Sampling.QUANTILE
        if self.unit is Unit.NS and last == "mean":
            return Sampling.MEAN
        return Sampling.EXACT

    @property
    def level(self) -> Optional[float]:
        """The quantile a QUANTILE figure is (0.99 for a p99, 1 for the max, 0 for the min); None for others."""
        return _LEVELS[self.path[-1]] if self.kind is Sampling.QUANTILE else None

    @property
    def histogram(self) -> Optional[str]:
        """The field of a thread's stored histograms (results' `histograms`) its samples are in; None: none stored."""
        return _HISTOGRAMS.get(self.path[0]) if self.kind in (Sampling.QUANTILE, Sampling.MEAN) else None

    @property
    def samples_word(self) -> str:
        """What one sample of the figure is, in words: `callbacks`, `wake-ups`, `events`."""
        return {"wakeup_ns": "wake-ups", "message_age_ns": "messages"}.get(
            self.path[0], "callbacks" if self.scope is Scope.CALLBACKS else "events"
        )

    def min_samples(self, confidence: float) -> int:
        """The fewest samples the figure is judged on: what its interval needs to exist (0: any number)."""
        from runner import stats

        level = self.level
        if level is not None:
            return stats.min_samples(level, confidence)
        return MEAN_MIN_SAMPLES if self.kind is Sampling.MEAN else 0

    @property
    def needs_callbacks(self) -> bool:
        return self.scope is Scope.CALLBACKS


_QUANTILE_WORDS = {
    "min": "min",
    "p50": "p50",
    "p90": "p90",
    "p99": "p99",
    "p999": "p99.9",
    "max": "max",
    "mean": "mean",
    "stddev": "std dev",
}
_LATENCY_THRESHOLD = {"p99": Threshold(relative=0.20, absolute=10_000)}
_LATENCY_COLUMN = {"p50": "lat p50", "p99": "p99", "max": "max"}

REGISTRY: tuple[Figure, ...] = (
    Figure("callbacks", "callbacks run", Unit.COUNT, Scope.CALLBACKS, ("callbacks",), column="callbacks", worse=Worse.LOWER),
    Figure("releases", "releases due in the cell", Unit.COUNT, Scope.CALLBACKS, ("releases",), worse=Worse.LOWER),
    Figure(
        "missed_releases",
        "releases missed (no callback ran for them)",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("missed_releases",),
        Threshold(absolute=0),
        column="missed",
        overload=True,
        sampling=Sampling.PROPORTION,
        trials="releases",
    ),
    Figure(
        "missed_releases.consecutive_max",
        "most releases missed in a row (no callback served one between them)",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("missed_consecutive_max",),
        Threshold(absolute=0),
        column="in a row",
        overload=True,
        needs_period=True,
        sampling=Sampling.EXACT,
    ),
    Figure(
        "overruns",
        "callbacks that ran past their next release",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("overruns",),
        Threshold(absolute=0),
        column="overruns",
        overload=True,
        needs_period=True,
        sampling=Sampling.PROPORTION,
        trials="callbacks",
    ),
    Figure(
        "slack.min",
        "slack, worst (end of a callback to its next release)",
        Unit.NS,
        Scope.CALLBACKS,
        ("slack_ns", "min"),
        Threshold(relative=0.20, absolute=10_000),
        column="slack min",
        worse=Worse.LOWER,
        signed=True,
        overload=True,
        needs_period=True,
    ),
    *(
        Figure(f"slack.{q}", f"slack {q}", Unit.NS, Scope.CALLBACKS, ("slack_ns", q), worse=Worse.LOWER, signed=True, needs_period=True)
        for q in ("p1", "p50", "max", "mean")
    ),
    Figure(
        "involuntary.total",
        "involuntary context switches (whole thread)",
        Unit.COUNT,
        Scope.THREAD,
        ("involuntary", "total"),
        sampling=Sampling.RATE,
    ),
    Figure(
        "involuntary.per_callback_mean",
        "involuntary switches per callback",
        Unit.PER_CALLBACK,
        Scope.CALLBACKS,
        ("involuntary", "per_callback_mean"),
        Threshold(absolute=0.5),
        column="invol/cb",
        sampling=Sampling.RATE,
        trials="callbacks",
    ),
    Figure(
        "involuntary.per_callback_max",
        "involuntary switches in one callback (max)",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("involuntary", "per_callback_max"),
        column="invol max",
    ),
    Figure(
        "involuntary.callbacks_with_any",
        "callbacks with an involuntary switch",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("involuntary", "callbacks_with_any"),
        sampling=Sampling.PROPORTION,
        trials="callbacks",
    ),
    Figure(
        "voluntary.total",
        "voluntary context switches (whole thread)",
        Unit.COUNT,
        Scope.THREAD,
        ("voluntary", "total"),
        sampling=Sampling.RATE,
    ),
    Figure(
        "involuntary.per_second",
        "involuntary context switches per second",
        Unit.PER_SECOND,
        Scope.OUTSIDE,
        ("involuntary", "per_second"),
        Threshold(relative=0.50, absolute=10),
        sampling=Sampling.RATE,
        events="involuntary.total",
    ),
    Figure(
        "voluntary.per_second",
        "voluntary context switches per second",
        Unit.PER_SECOND,
        Scope.OUTSIDE,
        ("voluntary", "per_second"),
        sampling=Sampling.RATE,
        events="voluntary.total",
    ),
    Figure("cpu_time", "CPU time", Unit.NS, Scope.OUTSIDE, ("cpu_time_ns",)),
    Figure("migrations", "migrations between CPUs", Unit.COUNT, Scope.OUTSIDE, ("migrations",), sampling=Sampling.RATE, in_trace=True),
    Figure(
        "preemptions",
        "preemptions (switched out while runnable, scheduler trace)",
        Unit.COUNT,
        Scope.OUTSIDE,
        ("preemptions",),
        traced=True,
        sampling=Sampling.RATE,
        in_trace=True,
    ),
    *(
        Figure(
            f"wakeup.{q}",
            f"waking-to-running latency (scheduler trace) {words}",
            Unit.NS,
            Scope.OUTSIDE,
            ("wakeup_ns", q),
            _LATENCY_THRESHOLD.get(q),
            traced=True,
            in_trace=True,
        )
        for q, words in _QUANTILE_WORDS.items()
        if q not in ("stddev",)
    ),
    *(
        Figure(
            f"latency.{q}",
            f"wake-up latency {words}",
            Unit.NS,
            Scope.CALLBACKS,
            ("latency_ns", q),
            _LATENCY_THRESHOLD.get(q),
            _LATENCY_COLUMN.get(q),
        )
        for q, words in _QUANTILE_WORDS.items()
    ),
    Figure(
        "latency.above_bound",
        "releases with a wake-up latency above latency_bound",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("latency_ns", "above_bound"),
        Threshold(absolute=0),
        sampling=Sampling.PROPORTION,
        trials="callbacks",
    ),
    Figure(
        "faults.minor",
        "minor page faults (whole thread)",
        Unit.COUNT,
        Scope.THREAD,
        ("faults", "minor"),
        column="minor faults",
        sampling=Sampling.RATE,
    ),
    Figure(
        "faults.major",
        "major page faults (whole thread)",
        Unit.COUNT,
        Scope.THREAD,
        ("faults", "major"),
        Threshold(absolute=0),
        sampling=Sampling.RATE,
    ),
    Figure(
        "faults.minor_after_first",
        "minor page faults after the first callback",
        Unit.COUNT,
        Scope.CALLBACKS,
        ("faults", "minor_after_first"),
        Threshold(relative=0.20, absolute=0),
        sampling=Sampling.RATE,
        trials="callbacks",
    ),
)

_EVENT_FIGURES = (
    ("lock_wait", "lock_wait_ns", "time to acquire a mutex"),
    ("cond_wait", "cond_wait_ns", "time blocked waiting on a condition"),
    ("barrier_wait", "barrier_wait_ns", "time waiting at a barrier"),
    ("resume_latency", "resume_latency_ns", "wake-up latency after a resume"),
    ("chain", "chain_ns", "chain latency (first release to the end of this thread's part)"),
)
REGISTRY = REGISTRY + tuple(
    Figure(
        f"{name}.{q}",
        f"{words} {_QUANTILE_WORDS[q]}",
        Unit.NS,
        Scope.EVENTS,
        (field, q),
        Threshold(relative=0.20, absolute=10_000) if q == "p99" and name in ("lock_wait", "chain") else None,
        of_callbacks=name == "chain",
    )
    for name, field, words in _EVENT_FIGURES
    for q in ("p50", "p90", "p99", "max", "mean")
)
REGISTRY = REGISTRY + tuple(
    Figure(
        f"message_age.{q}",
        f"message age (its source timestamp to the start of the callback that took it) {_QUANTILE_WORDS[q]}",
        Unit.NS,
        Scope.ROS,
        ("message_age_ns", q),
        Threshold(relative=0.20, absolute=10_000) if q == "p99" else None,
    )
    for q in ("p50", "p90", "p99", "max", "mean")
)

BY_NAME: dict[str, Figure] = {f.name: f for f in REGISTRY}


def figure(name: str) -> Figure:
    """The figure called `name`; KeyError for an unknown one (callers say "did you mean" with `BY_NAME`)."""
    return BY_NAME[name]


@dataclass(frozen=True)
class ThreadKind:
    """A kind of thread as far as its figures go: which figures of the registry it can have at all (`has`).

    The scopes say it once for every figure: per-callback figures need callbacks (those measured
    against a period, a period too), event figures a program (`kind: phases`), figures from /proc
    a thread measured from outside (a `command:` program's, a watched process's); the scheduler
    trace adds its figures to any thread it follows, and every thread has the whole-thread totals.
    """

    words: str  # what it is, for messages: `a thread of a command: program (measured from /proc)`
    callbacks: bool = False  # runs callbacks: released by a period, or by resumes
    period: bool = False  # its callbacks are released by a period
    events: bool = False  # runs kind: phases work, whose events have figures
    proc: bool = False  # measured from outside, from /proc: a program's thread (command:, runner watch)
    ros: bool = False  # a ROS 2 callback measured inside its program: per-callback figures, message ages, chains; no thread totals


CALLBACK = ThreadKind("a ROS 2 callback (measured inside its program)", callbacks=True, period=True, ros=True)
"""What a `callback:` expectation names: a timer callback has every per-callback figure, one that takes messages their ages."""


def has(kind: ThreadKind, fig: Figure) -> bool:
    """Whether a thread of `kind` can have `fig` (a traced one, when the scheduler trace runs and follows it)."""
    if kind.ros:
        return fig.scope in (Scope.CALLBACKS, Scope.ROS) or fig.of_callbacks
    if fig.scope is Scope.ROS:
        return False
    if fig.scope is Scope.CALLBACKS:
        return kind.callbacks and (kind.period or not fig.needs_period)
    if fig.scope is Scope.EVENTS:
        return kind.events
    if fig.scope is Scope.OUTSIDE:
        return kind.proc or fig.in_trace
    return True


def measured_how(fig: Figure) -> str:
    """How `fig` is measured, as the reason a thread without it cannot have it: `is measured per callback`."""
    if fig.scope is Scope.CALLBACKS:
        return "is measured against a period's next release" if fig.needs_period else "is measured per callback"
    if fig.scope is Scope.EVENTS:
        return "is measured on a program's events (kind: phases)"
    if fig.scope is Scope.ROS:
        return "is measured per message a ROS 2 callback took (callback: expectations)"
    if fig.scope is Scope.OUTSIDE and not fig.in_trace:
        return "is read from /proc for threads measured from outside (command: programs, runner watch)"
    return "is measured for every thread"


def figures_of(kind: ThreadKind) -> str:
    """The figures a thread of `kind` has, as users write them: `callbacks, latency.*, ...`; a group it has whole as `group.*`."""
    groups: dict[str, list[Figure]] = {}  # by the name's first part, in the registry's order
    for f in REGISTRY:
        groups.setdefault(f.name.partition(".")[0], []).append(f)
    out: list[str] = []
    for group, members in groups.items():
        held = [f.name for f in members if has(kind, f)]
        whole = len(held) == len(members) and "." in members[0].name
        out += [f"{group}.*"] if whole else held
    return ", ".join(out)


def value(figures: ThreadFigures, fig: Figure) -> Optional[Number]:
    """The value of `fig` in one thread's figures, None where the thread has none (no callbacks)."""
    node: object = figures
    for part in fig.path:
        node = getattr(node, part, None)
        if node is None:
            return None
    assert isinstance(node, (int, float)) and not isinstance(node, bool), (fig.name, node)
    return node


def kept_up(figures: ThreadFigures) -> bool:
    """Whether a periodic thread served every release within its period: no release missed, no callback overran."""
    return not figures.missed_releases and not figures.overruns


def default_thresholds() -> dict[str, Threshold]:
    """The figures compared against a baseline unless told otherwise, with their thresholds."""
    return {f.name: f.threshold for f in REGISTRY if f.threshold is not None}
