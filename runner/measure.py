"""Per-thread figures from the native core's records, and expectation verdicts.  Pure, no I/O.

The figures are named as in results.json (`involuntary.per_callback_mean`,
`latency_us.p99`, ...), and `metric_value` is the one place that maps an
expectation's metric onto them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from .model import Expectation, Metric
from .samples import SlotData
from .stats import mean, summarize


@dataclass(frozen=True)
class Involuntary:
    total: int
    per_callback_mean: Optional[float]
    per_callback_max: Optional[int]
    callbacks_with_any: Optional[int]


@dataclass(frozen=True)
class Faults:
    minor: int
    major: int
    minor_first_callback: Optional[int]
    minor_after_first: Optional[int]
    minor_per_callback_max: Optional[int]


@dataclass(frozen=True)
class Figures:
    """What was measured for one thread."""

    callbacks: int
    missed: int
    involuntary: Involuntary
    voluntary_total: int
    latency_us: Optional[dict[str, float]]
    callback_wall_us: Optional[dict[str, float]]
    faults: Faults
    cpus_seen: tuple[int, ...]
    complete: bool  # False when the thread did not finish (killed, crashed, interrupted)


def figures(slot: SlotData, periodic: bool) -> Figures:
    """Figures of one thread from its slot; per-callback fields are None for non-periodic work."""
    smp = slot.samples
    totals = slot.totals()
    if totals is None:  # the thread never finished: what its callbacks recorded is all there is
        totals = (sum(s.nivcsw for s in smp), sum(s.nvcsw for s in smp), sum(s.minflt for s in smp), sum(s.majflt for s in smp))
    nivcsw = [s.nivcsw for s in smp]
    minflt = [s.minflt for s in smp]
    cpus = set(slot.cpus_seen)
    for s in smp:
        cpus.update((s.cpu_start, s.cpu_end))
    return Figures(
        callbacks=len(smp),
        missed=sum(s.missed for s in smp),
        involuntary=Involuntary(
            total=totals[0],
            per_callback_mean=_round(mean(nivcsw)) if periodic else None,
            per_callback_max=max(nivcsw) if periodic and nivcsw else None,
            callbacks_with_any=sum(1 for n in nivcsw if n) if periodic else None,
        ),
        voluntary_total=totals[1],
        latency_us=_us(summarize([s.latency_ns for s in smp])) if periodic else None,
        callback_wall_us=_us(summarize([s.end_ns - s.wake_ns for s in smp])) if periodic else None,
        faults=Faults(
            minor=totals[2],
            major=totals[3],
            minor_first_callback=minflt[0] if minflt else None,
            minor_after_first=sum(minflt[1:]) if minflt else None,
            minor_per_callback_max=max(minflt) if minflt else None,
        ),
        cpus_seen=tuple(sorted(c for c in cpus if c >= 0)),
        complete=slot.finished,
    )


def _round(value: Optional[float]) -> Optional[float]:
    return None if value is None else round(value, 4)


def _us(summary: Optional[dict[str, float]]) -> Optional[dict[str, float]]:
    return None if summary is None else {k: round(v / 1000.0, 3) for k, v in summary.items()}


def metric_value(fig: Figures, metric: Metric) -> Optional[float]:
    """The figure an expectation's metric names; latencies in nanoseconds (as limits are)."""
    inv, faults = fig.involuntary, fig.faults
    lat = fig.latency_us or {}
    table: dict[Metric, Optional[float]] = {
        Metric.CALLBACKS: fig.callbacks,
        Metric.INVOLUNTARY_TOTAL: inv.total,
        Metric.INVOLUNTARY_PER_CALLBACK_MEAN: inv.per_callback_mean,
        Metric.INVOLUNTARY_PER_CALLBACK_MAX: inv.per_callback_max,
        Metric.INVOLUNTARY_CALLBACKS_WITH_ANY: inv.callbacks_with_any,
        Metric.VOLUNTARY_TOTAL: fig.voluntary_total,
        Metric.FAULTS_MINOR: faults.minor,
        Metric.FAULTS_MAJOR: faults.major,
        Metric.FAULTS_MINOR_AFTER_FIRST: faults.minor_after_first,
    }
    if metric.is_latency:
        value = lat.get(metric.value.split(".", 1)[1])
        return None if value is None else value * 1000.0
    return table[metric]


@dataclass(frozen=True)
class Verdict:
    """One expectation checked against one thread."""

    thread: str
    metric: Metric
    limit: str
    measured: Optional[float]
    passed: bool
    note: str = field(default="")


def check(exp: Expectation, thread: str, fig: Figures) -> Verdict:
    """Evaluate `exp` on one thread's figures; a missing figure fails with a note saying why."""
    value = metric_value(fig, exp.metric)
    if value is None:
        return Verdict(thread, exp.metric, exp.describe_limit(), None, False, "not measured (no callbacks)")
    ok = (exp.max is None or value <= exp.max) and (exp.min is None or value >= exp.min)
    return Verdict(thread, exp.metric, exp.describe_limit(), value, ok)
