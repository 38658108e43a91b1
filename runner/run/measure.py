"""Per-thread figures from the native core's records, and expectation verdicts.  Pure, no I/O.

The figures are declared in figures.py (the registry); `thread_figures` measures
them from a native slot, `check` holds one against an expectation.
"""

from __future__ import annotations

from typing import Optional

from runner import figures as fg
from runner.figures import ThreadFigures
from runner.results.document import Verdict
from runner.run.samples import SlotData
from runner.run.stats import mean, summarize
from runner.scenario.model import Expectation


def _round(value: Optional[float]) -> Optional[float]:
    return None if value is None else round(value, 4)


def thread_figures(slot: SlotData, periodic: bool, releases_due: int = 0) -> ThreadFigures:
    """A thread's figures from its native slot, in integer ns; per-callback fields are None without callbacks.

    `releases_due` is how many releases the thread's period put in the cell: every one that no
    callback served is missed, the ones after the last callback too.
    """
    smp = slot.samples
    totals = slot.totals()
    if totals is None:  # the thread never finished: what its callbacks recorded is all there is
        totals = (sum(s.nivcsw for s in smp), sum(s.nvcsw for s in smp), sum(s.minflt for s in smp), sum(s.majflt for s in smp))
    nivcsw = [s.nivcsw for s in smp]
    minflt = [s.minflt for s in smp]
    cpus = set(slot.cpus_seen)
    for s in smp:
        cpus.update((s.cpu_start, s.cpu_end))
    skipped = sum(s.missed for s in smp)
    return ThreadFigures(
        callbacks=len(smp),
        missed_releases=max(skipped, releases_due - len(smp)) if periodic else 0,
        involuntary=fg.Involuntary(
            total=totals[0],
            per_callback_mean=_round(mean(nivcsw)) if periodic else None,
            per_callback_max=max(nivcsw) if periodic and nivcsw else None,
            callbacks_with_any=sum(1 for n in nivcsw if n) if periodic else None,
        ),
        voluntary=fg.Voluntary(total=totals[1]),
        latency_ns=_spread([s.latency_ns for s in smp]) if periodic else None,
        callback_wall_ns=_spread([s.end_ns - s.wake_ns for s in smp]) if periodic else None,
        faults=fg.Faults(
            minor=totals[2],
            major=totals[3],
            minor_first_callback=minflt[0] if minflt else None,
            minor_after_first=sum(minflt[1:]) if minflt else None,
            minor_per_callback_max=max(minflt) if minflt else None,
        ),
        cpus_seen=tuple(sorted(c for c in cpus if c >= 0)),
        complete=slot.finished,
    )


def _spread(values: list[int]) -> Optional[fg.Spread]:
    summary = summarize(values)
    return None if summary is None else fg.Spread(**{k: int(v) for k, v in summary.items()})


def check(exp: Expectation, thread: str, figs: ThreadFigures) -> Verdict:
    """Evaluate `exp` on one thread's figures; a missing figure fails with a note saying why.

    Limits and values are in the figure's unit (ns for durations), as the registry declares it.
    """
    name = exp.metric.value
    value = fg.value(figs, fg.figure(name))
    if value is None:
        return Verdict(
            thread=thread, metric=name, limit=exp.describe_limit(), measured=None, passed=False, note="not measured (no callbacks)"
        )
    ok = (exp.max is None or value <= exp.max) and (exp.min is None or value >= exp.min)
    return Verdict(thread=thread, metric=name, limit=exp.describe_limit(), measured=value, passed=ok)
