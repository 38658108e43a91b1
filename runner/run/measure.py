"""Per-thread figures from the native core's records, and expectation verdicts.  Pure, no I/O.

The figures are declared in figures.py (the registry); `thread_figures` measures
them from a native slot, `check` holds one against an expectation.
"""

from __future__ import annotations

import math
from typing import Optional

from runner import figures as fg
from runner.histogram import QUANTILES, Histogram
from runner.results.document import Verdict
from runner.results.threadfigures import Faults, Involuntary, Slack, Spread, ThreadFigures, Voluntary
from runner.run.samples import CallbackStats, SlotData
from runner.scenario.model import Expectation

_QUANTILES = (QUANTILES["p50"], QUANTILES["p90"], QUANTILES["p99"], QUANTILES["p999"])


def _round(value: Optional[float]) -> Optional[float]:
    return None if value is None else round(value, 4)


def thread_figures(
    slot: SlotData, periodic: bool, releases_due: int = 0, bound: Optional[int] = None, released: bool = False
) -> ThreadFigures:
    """A thread's figures from its native slot, in integer ns; per-callback fields are None without callbacks.

    `releases_due` is how many releases the thread's period put in the cell: every one that no
    callback served is missed, the ones after the last callback too.  Latency counts every
    release answered, those a late callback skipped included (see README, "Latency").  A thread
    `released` by resumes (not `periodic`) has callbacks and their figures, but no releases due,
    overruns or slack: no period says when its next release is (its misses are the resumes its
    queue dropped, which the caller adds).
    """
    st = slot.stats
    callbacks = slot.loops if periodic or released else 0
    totals = slot.totals()
    if totals is None:  # the thread never finished: what its callbacks recorded is all there is
        totals = (st.nivcsw_sum, st.nvcsw_sum, st.minflt_sum, st.majflt_sum)
    has = callbacks > 0
    return ThreadFigures(
        callbacks=callbacks,
        missed_releases=max(slot.missed, releases_due - callbacks) if periodic else 0,
        releases=max(releases_due, callbacks + slot.missed) if periodic else 0,
        overruns=st.overruns if periodic else 0,
        # releases after a stopped thread's last callback, which no native count saw, are one run of misses too
        missed_consecutive_max=max(st.missed_consecutive_max, releases_due - callbacks - slot.missed) if periodic else None,
        involuntary=Involuntary(
            total=totals[0],
            per_callback_mean=_round(st.nivcsw_sum / callbacks) if has else None,
            per_callback_max=st.nivcsw_max if has else None,
            callbacks_with_any=st.with_nivcsw if has else None,
        ),
        voluntary=Voluntary(total=totals[1]),
        latency_ns=spread(st.latency, st.lat_mean, st.lat_m2, st.releases, st.above_bound if bound else None) if has else None,
        callback_wall_ns=spread(st.wall) if has else None,
        slack_ns=_slack(st) if has else None,
        faults=Faults(
            minor=totals[2],
            major=totals[3],
            minor_first_callback=st.minflt_first if has else None,
            minor_after_first=st.minflt_sum - st.minflt_first if has else None,
            minor_per_callback_max=st.minflt_max if has else None,
        ),
        cpus_seen=tuple(sorted(c for c in slot.cpus_seen if c >= 0)),
        complete=slot.finished,
    )


def spread(
    hist: Optional[Histogram], mean: Optional[float] = None, m2: Optional[float] = None, n: int = 0, above: Optional[int] = None
) -> Optional[Spread]:
    """Order statistics of a histogram (ns): min and max exact, percentiles to the bucket.

    The mean when `mean` of `n` values is known; the standard deviation when their sum of
    squared deviations `m2` is known too (the trace's reader keeps no squares).
    """
    if hist is None or not hist.buckets:
        return None
    p50, p90, p99, p999 = hist.quantiles(_QUANTILES)
    mean_ns = round(mean) if mean is not None and n > 0 else None
    return Spread(
        min=hist.min,
        p50=p50,
        p90=p90,
        p99=p99,
        p999=p999,
        max=hist.max,
        mean=mean_ns,
        stddev=round(math.sqrt(max(0.0, m2) / n)) if mean_ns is not None and m2 is not None else None,
        above_bound=above,
        count=hist.count,
    )


def _slack(st: CallbackStats) -> Optional[Slack]:
    hist = st.slack
    if hist is None or not hist.count:
        return None
    return Slack(min=hist.min, **dict(zip(("p1", "p50"), hist.quantiles((0.01, 0.5), low=True))), max=hist.max, mean=round(st.slack_mean))


def check(exp: Expectation, thread: str, figs: ThreadFigures, absent: str = "") -> Verdict:
    """Evaluate `exp` on one thread's figures; a missing figure fails `not measured` with a note saying why
    (`absent`, when the caller knows it better: the scheduler trace did not run).

    Limits and values are in the figure's unit (ns for durations), as the registry declares it.
    """
    name = exp.metric.value
    fig = fg.figure(name)
    value = fg.value(figs, fig)
    if value is None:
        why = absent or {
            fg.Scope.EVENTS: "no such events ran",
            fg.Scope.OUTSIDE: "/proc gave no reading of it while it ran",
        }.get(fig.scope, "no callbacks")
        return Verdict(thread=thread, metric=name, limit=exp.describe_limit(), measured=None, passed=False, note=f"not measured ({why})")
    ok = (exp.max is None or value <= exp.max) and (exp.min is None or value >= exp.min)
    return Verdict(thread=thread, metric=name, limit=exp.describe_limit(), measured=value, passed=ok, samples=samples(figs, fig))


def samples(figs: ThreadFigures, fig: fg.Figure) -> Optional[int]:
    """How many values `fig` stands on, when it is a percentile, mean or extreme of a spread (a p99 of 1 wake-up)."""
    spread_of = getattr(figs, fig.path[0], None)
    if isinstance(spread_of, Spread) and len(fig.path) == 2 and fig.path[1] != "above_bound":
        return spread_of.count
    return None
