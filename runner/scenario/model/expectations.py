"""Expectations: a bound on a figure of the registry (`latency.p99 <= 100us`) for the threads it names.

Every figure of `runner.figures` is a metric an expectation may bound; the limit is read in
the figure's unit (durations written with theirs, `-2ms` for slack).
"""

from __future__ import annotations

import enum
import math
from typing import Annotated, Any, Optional, Union

from runner import figures, units
from runner.errors import did_you_mean
from runner.scenario.model.base import MAX_LATENCY_LIMIT, Strict
from runner.scenario.typed import Context, Field, Schema, Written, text_schema


class _MetricValue(str):
    """What every expectation metric knows: its declaration in the figure registry."""

    value: str

    @property
    def figure(self) -> figures.Figure:
        return figures.figure(self.value)

    @property
    def is_latency(self) -> bool:
        return self.figure.is_duration

    @property
    def needs_callbacks(self) -> bool:
        return self.figure.needs_callbacks


Metric = enum.Enum(  # type: ignore[misc]  # built from the registry: every figure is an expectation metric
    "Metric", {f.name.upper().replace(".", "_"): f.name for f in figures.REGISTRY}, type=_MetricValue, module=__name__
)
Metric.__doc__ = "Figures an expectation can check, named as in results.json (runner/figures.py declares them)."


def metric_figure(metric: Metric) -> figures.Figure:
    """The registry's declaration of an expectation's metric: unit, scope, words."""
    return figures.figure(metric.value)


def _limit(value: Any, context: Context = None) -> Any:
    """Latency limits are durations (kept as ns), negative for slack (`-2ms`); counts are plain numbers."""
    if isinstance(value, str):
        text = value.strip()
        negative = text[:1] in ("-", "\u2212")
        try:
            parsed = units.parse_duration(text[1:] if negative else text)
            return -parsed if negative else parsed
        except units.UnitError as exc:
            raise ValueError(str(exc)) from None
    if isinstance(value, bool):  # a bool is an int to Python: `max: true` would be a limit of 1
        raise ValueError(f"{str(value).lower()} is not a limit; expected a number, or a duration such as 2ms for latency figures")
    return value


SIGNED_DURATION_SCHEMA = text_schema(  # -2ms for slack
    units.DURATION_PATTERN.replace("^", "^\\s*[-\u2212]?", 1), f"{units.DURATION_EXPECTED}, or below zero (-2ms) for slack"
)
_LIMIT_SCHEMA = {
    "anyOf": [  # text first: an editor shows the first form's message when none fits
        SIGNED_DURATION_SCHEMA,
        {"type": "number", "minimum": -1.7976931348623157e308, "maximum": 1.7976931348623157e308},  # finite: .inf is refused
    ]
}
Limit = Annotated[float, Written(_limit, None, _LIMIT_SCHEMA)]
MatrixValue = Union[str, int, float, bool]


class Expectation(Strict):
    """A check on one measured figure of the named thread(s), or ROS 2 callback(s), in every cell or in selected cells."""

    thread: str = Field(default="", description="thread name, or process/thread (exactly one of thread and callback)")
    callback: str = Field(
        default="",
        description="a ROS 2 callback of a command: program, as a glob on its name `node/symbol`, e.g. '*timer_callback*' "
        "(exactly one of thread and callback)",
    )
    metric: Metric = Field(description="figure to check, as named in results.json")
    max: Optional[Limit] = Field(default=None, description="upper bound (a duration for latency metrics)")
    min: Optional[Limit] = Field(default=None, description="lower bound (a duration for latency metrics)")
    cells: dict[str, Union[MatrixValue, Annotated[list[MatrixValue], Schema({"minItems": 1})]]] = Field(
        default_factory=dict, description="only in cells whose matrix values match, e.g. {policy: [fifo, rr]}"
    )

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        if isinstance(value, dict):
            metric = str(value.get("metric", ""))
            if metric not in figures.BY_NAME:
                return value  # the metric reports its own problem (with a "did you mean"); its unit is unknown
            latency = figures.figure(metric).is_duration
            for bound in ("max", "min"):
                given = value.get(bound)
                if given is None:
                    continue
                if latency and not isinstance(given, str):
                    raise ValueError(f"{bound}: bare number {given!r} for {metric}; expected {units.DURATION_EXPECTED}")
                if not latency and isinstance(given, str):
                    raise ValueError(f"{bound}: {metric or 'this metric'} is a count; expected a number, got {given!r}")
        return value

    def _after(self, written: Any, context: Context) -> None:
        if bool(self.thread) == bool(self.callback):
            raise ValueError(
                "an expectation names a thread or a callback: exactly one of thread: (a thread's name) and callback: (a glob on "
                "a ROS 2 callback's name)"
            )
        if self.callback:
            fig = metric_figure(self.metric)
            if not figures.has(figures.CALLBACK, fig):
                held = [f.name for f in figures.REGISTRY if figures.has(figures.CALLBACK, f)]
                raise ValueError(
                    f"{fig.name} {figures.measured_how(fig)}, not per ROS 2 callback; "
                    f"a callback has {figures.figures_of(figures.CALLBACK)}{did_you_mean(fig.name, held)}"
                )
        if self.max is None and self.min is None:
            raise ValueError("an expectation needs max, min or both")
        for name, bound in (("min", self.min), ("max", self.max)):
            if bound is None:
                continue
            if not math.isfinite(bound):
                raise ValueError(f"{name}: {bound!r} is not a finite number")
            fig = metric_figure(self.metric)
            if bound < 0 and not fig.signed:
                raise ValueError(f"{name}: {self.describe_bound(bound)} is negative; {self.metric.value} is never below 0")
            if fig.is_duration and abs(bound) > MAX_LATENCY_LIMIT:
                raise ValueError(
                    f"{name}: {units.format_duration(int(bound))} is too large for a latency bound; "
                    f"at most {units.format_duration(MAX_LATENCY_LIMIT)}"
                )
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"min {self.describe_bound(self.min)} is above max {self.describe_bound(self.max)}; no run can meet both")

    def describe_bound(self, value: float) -> str:
        """A bound as written back: a duration for latency metrics, a number otherwise."""
        return units.format_duration(int(value)) if metric_figure(self.metric).is_duration else f"{value:g}"

    @classmethod
    def _schema(cls, schema: dict[str, Any]) -> None:
        """Exactly one of `thread` and `callback`, for editors too."""
        schema["oneOf"] = [
            {"properties": {key: True}, "required": [key]} for key in ("thread", "callback")
        ]  # defined there: ajv's strict mode

    @property
    def target(self) -> str:
        """What it names, as verdicts and listings say it: the thread, or `callback GLOB`."""
        return self.thread or f"callback {self.callback}"

    def describe_limit(self) -> str:
        parts = []
        if self.min is not None:
            parts.append(f">= {self.describe_bound(self.min)}")
        if self.max is not None:
            parts.append(f"<= {self.describe_bound(self.max)}")
        return " and ".join(parts)
