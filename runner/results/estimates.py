"""Each figure of a thread with its sampling error: what it stands on, its interval, and the test of a change.  Pure.

A figure is an estimate from a sample: a p99 of so many callbacks, missed releases of so many
releases.  `estimate` finds, by the figure's `Sampling` (runner/figures.py), what that sample
is in a thread's results (its stored histograms, its counts and their trials, the cell's
length) and the interval at `stats.CONFIDENCE`; `p_change` tests whether a new estimate is
worse (or better) than a baseline's by more than sampling explains, exactly:

- a quantile, min or max: how many of the new run's samples lie beyond the baseline's order
  statistic, beta-binomial under "the same distribution" (distribution-free).  Histograms are
  exact to the bucket only, so the baseline's value is taken at its bucket's far edge and a new
  sample counts only when its whole bucket lies beyond it: the test never finds a change that
  the bucket width could explain.  Intervals widen to their buckets' outer edges for the same reason;
- a mean: its standard error (the stored standard deviation, else the histogram's);
- a proportion: Clopper-Pearson's interval, Fisher's exact test;
- a rate: Garwood's interval, the exact conditional binomial test of two Poisson rates.

A figure whose interval would need more samples than the run has (a p99 of 20 callbacks) is
`few`, and says what it needs: the count, and how long a run gives it at the thread's rate.
A figure whose sample the results do not hold (no histogram: a file of an older runner, or a
program's event figures) has no interval, and `lacking` says so.  Repeats of a cell pool their
samples (histograms merge exactly, counts add); the value compared stays the repeats' median.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Optional, Protocol

from runner import stats, units
from runner.figures import Figure, Number, Sampling, Unit, Worse, value
from runner.histogram import Histogram, merge
from runner.results.document import ThreadHistograms
from runner.results.threadfigures import ThreadFigures


class Measured(Protocol):
    """What an estimate reads of a thread or a ROS 2 callback: its figures and its histograms."""

    @property
    def figures(self) -> ThreadFigures: ...

    @property
    def histograms(self) -> Optional[ThreadHistograms]: ...


@dataclass(frozen=True)
class Estimate:
    """One figure of one thread (its repeats pooled) with what it stands on and its interval, in the figure's unit."""

    figure: Figure
    value: Number
    samples: Optional[int] = None  # samples of its distribution, trials of its proportion, or events of its rate; None: not known
    low: Optional[float] = None  # its interval at `confidence`; None: it has none (see `lacking`, or an extreme)
    high: Optional[float] = None
    few: bool = False  # too few samples for its interval: not judged on them
    lacking: str = ""  # why it has no interval, in words; "" when it has one (or is an extreme, or exact)
    hist: Optional[Histogram] = None
    events: Optional[int] = None  # PROPORTION, RATE: events counted (repeats added)
    exposure: Optional[float] = None  # PROPORTION: trials; RATE: callbacks or seconds (repeats added)
    se: Optional[float] = None  # MEAN: its standard error
    confidence: float = stats.CONFIDENCE

    @property
    def testable(self) -> bool:
        """Whether a change of it can be tested against its sampling error (an extreme with a histogram can, without an interval)."""
        kind = self.figure.kind
        if self.few or kind is Sampling.EXACT:
            return False
        if kind is Sampling.QUANTILE:
            return self.hist is not None
        if kind is Sampling.MEAN:
            return self.se is not None
        return self.events is not None and self.exposure is not None

    def basis(self) -> str:
        """What it stands on, in words: `2,000 callbacks`, `7 of 20 releases`, `412 over 2.0 s`."""
        fig = self.figure
        if fig.kind is Sampling.PROPORTION and self.events is not None and self.exposure is not None:
            return f"{self.events:,} of {round(self.exposure):,} {_trials_word(fig)}"
        if fig.kind is Sampling.RATE and self.events is not None and self.exposure is not None:
            over = f"{round(self.exposure):,} callbacks" if fig.trials else units.human_duration(round(self.exposure * 1e9))
            return f"{self.events:,} over {over}"
        if self.samples is not None:
            return f"{self.samples:,} {fig.samples_word}"
        return ""


def _trials_word(fig: Figure) -> str:
    return {"releases": "releases", "callbacks": "callbacks"}.get(fig.trials or "", "trials")


def _median(values: Sequence[Number]) -> Number:
    return statistics.median(values)


def estimate(
    fig: Figure, threads: Sequence[Measured], durations_ns: Sequence[int], confidence: float = stats.CONFIDENCE
) -> Optional[Estimate]:
    """`fig` of one thread over its repeats (`durations_ns`: each repeat's cell length), or None when none measured it.

    The value is the repeats' median, as the comparison has always compared it; the sample is theirs pooled.
    """
    values = [v for t in threads if (v := value(t.figures, fig)) is not None and math.isfinite(v)]
    if not values:
        return None
    shown = _median(values)
    kind = fig.kind
    if kind is Sampling.QUANTILE or kind is Sampling.MEAN:
        return _of_distribution(fig, shown, threads, durations_ns, confidence)
    if kind is Sampling.PROPORTION:
        return _proportion(fig, shown, threads, confidence)
    if kind is Sampling.RATE:
        return _rate(fig, shown, threads, durations_ns, confidence)
    return Estimate(fig, shown, confidence=confidence)


def _histogram(fig: Figure, threads: Sequence[Measured]) -> Optional[Histogram]:
    """The repeats' histograms of `fig` merged; None unless every repeat stored one."""
    name = fig.histogram
    if name is None:
        return None
    found = [getattr(t.histograms, name, None) if t.histograms is not None else None for t in threads]
    if any(h is None for h in found):
        return None
    return merge(found)


def _sample_count(fig: Figure, threads: Sequence[Measured], hist: Optional[Histogram]) -> Optional[int]:
    """How many samples the distribution holds: its histogram's count, else its spread's (`count`), else a callback figure's
    callbacks; None: not known."""
    if hist is not None:
        return hist.count
    counts = [getattr(getattr(t.figures, fig.path[0], None), "count", None) for t in threads]  # a spread says how many
    if counts and all(c is not None for c in counts):
        return sum(c for c in counts if c is not None)
    if fig.histogram in ("latency", "slack", "callback_wall"):
        return sum(t.figures.callbacks for t in threads)
    return None


def _of_distribution(fig: Figure, shown: Number, threads: Sequence[Measured], durations_ns: Sequence[int], confidence: float) -> Estimate:
    hist = _histogram(fig, threads)
    n = _sample_count(fig, threads, hist)
    if n is None:
        return Estimate(fig, shown, lacking="its samples are not in the results (no histogram of them stored)", confidence=confidence)
    need = fig.min_samples(confidence)
    if n < need:
        return Estimate(fig, shown, n, few=True, lacking=_too_few(fig, n, need, sum(durations_ns)), hist=hist, confidence=confidence)
    if fig.kind is Sampling.MEAN:
        return _mean(fig, shown, threads, hist, n, confidence)
    level = fig.level
    assert level is not None
    if hist is None:
        return Estimate(fig, shown, n, lacking="its samples are not in the results (no histogram of them stored)", confidence=confidence)
    if level <= 0 or level >= 1:  # an extreme has no interval; a change of it is still tested by exceedance
        return Estimate(fig, shown, n, hist=hist, confidence=confidence)
    ranks = stats.quantile_ranks(n, level, confidence)
    assert ranks is not None  # n >= min_samples
    low, _ = rank_bounds(hist, ranks[0])
    _, high = rank_bounds(hist, ranks[1])
    return Estimate(fig, shown, n, low, high, hist=hist, confidence=confidence)


def _too_few(fig: Figure, n: int, need: int, duration_ns: int) -> str:
    """`20 callbacks; p99 needs at least 368, run ≥ 37s`: what a figure with too few samples lacks."""
    text = f"{n:,} {fig.samples_word}; {fig.name.rsplit('.', 1)[-1]} needs at least {need:,}"
    if n and duration_ns:
        text += f", run ≥ {units.format_duration(math.ceil(need * duration_ns / n / 1e9) * 1_000_000_000)}"
    return text


def _mean(fig: Figure, shown: Number, threads: Sequence[Measured], hist: Optional[Histogram], n: int, confidence: float) -> Estimate:
    """A mean with its standard error: the stored standard deviation (one run), else the pooled histogram's spread."""
    spread = getattr(threads[0].figures, fig.path[0], None) if len(threads) == 1 else None
    sd: Optional[float] = getattr(spread, "stddev", None)
    if sd is None and hist is not None:
        sd = histogram_sd(hist)
    if sd is None:
        return Estimate(fig, shown, n, lacking="its spread is not in the results (no histogram or standard deviation stored)")
    se = sd / math.sqrt(n)
    z = stats.normal_quantile(1 - (1 - confidence) / 2)
    return Estimate(fig, shown, n, shown - z * se, shown + z * se, hist=hist, se=se, confidence=confidence)


def histogram_sd(hist: Histogram) -> float:
    """The standard deviation of a histogram's values, each at its bucket's middle (within 0.4% of a value)."""
    n = hist.count
    mean = sum((lo + hi) / 2 * c for lo, hi, c in hist.buckets) / n
    return math.sqrt(sum(c * ((lo + hi) / 2 - mean) ** 2 for lo, hi, c in hist.buckets) / n)


def _figure_sum(threads: Sequence[Measured], name: str) -> Optional[float]:
    from runner.figures import figure

    found = [value(t.figures, figure(name)) for t in threads]
    if any(v is None for v in found):
        return None
    return float(sum(v for v in found if v is not None))


def _proportion(fig: Figure, shown: Number, threads: Sequence[Measured], confidence: float) -> Estimate:
    assert fig.trials is not None
    events = _figure_sum(threads, fig.name)
    trials = _figure_sum(threads, fig.trials)
    if events is None or trials is None or trials <= 0 or events > trials:
        return Estimate(fig, shown, lacking=f"no {fig.trials} to count it against", confidence=confidence)
    k, n = round(events), round(trials)
    low, high = stats.proportion_interval(k, n, confidence)
    per_run = n / len(threads)  # shown as a count of one run's trials, as the value is
    return Estimate(fig, shown, n, low * per_run, high * per_run, events=k, exposure=n, confidence=confidence)


def _rate(fig: Figure, shown: Number, threads: Sequence[Measured], durations_ns: Sequence[int], confidence: float) -> Estimate:
    """Events over an exposure: a count over callbacks or seconds, a mean per callback, or a rate per second."""
    events = 0.0
    exposure = 0.0
    for t, duration in zip(threads, durations_ns):
        got = _run_rate(fig, t, duration)
        if got is None:
            return Estimate(fig, shown, lacking="no exposure to count it over (callbacks or the cell's length)", confidence=confidence)
        events += got[0]
        exposure += got[1]
    if exposure <= 0:
        return Estimate(fig, shown, lacking="no exposure to count it over (callbacks or the cell's length)", confidence=confidence)
    k = round(events)
    low, high = stats.poisson_interval(k, confidence)
    per_run = exposure / len(threads)
    scale = per_run if fig.unit is Unit.COUNT else 1.0  # a count is shown as one run's; a rate as a rate
    return Estimate(fig, shown, k, low / exposure * scale, high / exposure * scale, events=k, exposure=exposure, confidence=confidence)


def _run_rate(fig: Figure, t: Measured, duration_ns: int) -> Optional[tuple[float, float]]:
    """(events, exposure) of one run of a RATE figure; None when either is not known."""
    from runner.figures import figure

    shown = value(t.figures, fig)
    if shown is None:
        return None
    if fig.unit is Unit.PER_SECOND:
        counted = value(t.figures, figure(fig.events)) if fig.events else None
        if counted is None:
            return None
        seconds = counted / shown if shown else duration_ns / 1e9
        return float(counted), seconds
    trials = value(t.figures, figure(fig.trials)) if fig.trials else duration_ns / 1e9
    if trials is None or trials <= 0:
        return None
    if fig.unit is Unit.PER_CALLBACK:
        return shown * trials, float(trials)
    return float(shown), float(trials)


def rank_bounds(hist: Histogram, rank: int) -> tuple[int, int]:
    """Where the `rank`-th smallest value (1-based) of a histogram lies: its bucket, clamped to the exact min and max."""
    seen = 0
    for lo, hi, count in hist.buckets:
        seen += count
        if seen >= rank:
            return max(lo, hist.min), min(hi, hist.max)
    return hist.max, hist.max


def _nearest_rank(level: float, n: int) -> int:
    return min(n, max(1, math.ceil(level * n)))


def _beyond(hist: Histogram, bound: int, above: bool) -> int:
    """Samples surely above (`above`) or below `bound`: those whose whole bucket is (the exact min and max count too)."""
    if above:
        return sum(c for lo, _hi, c in hist.buckets if max(lo, hist.min) > bound)
    return sum(c for _lo, hi, c in hist.buckets if min(hi, hist.max) < bound)


def p_change(base: Estimate, new: Estimate, worse: bool = True) -> Optional[float]:
    """One-sided p-value of `new` being worse (or, `worse` False, better) than `base` by more than sampling explains.

    None when either cannot be tested (too few samples, no sample stored, an exact figure).
    """
    if not (base.testable and new.testable):
        return None
    fig = new.figure
    higher = (fig.worse is Worse.HIGHER) == worse  # the direction tested: values growing
    kind = fig.kind
    if kind is Sampling.QUANTILE:
        assert base.hist is not None and new.hist is not None and fig.level is not None
        m, n = base.hist.count, new.hist.count
        r = _nearest_rank(fig.level, m)
        low, high = rank_bounds(base.hist, r)
        if higher:
            return stats.betabinom_sf(_beyond(new.hist, high, True), n, m - r + 1, r)
        return stats.betabinom_sf(_beyond(new.hist, low, False), n, r, m - r + 1)
    if kind is Sampling.MEAN:
        assert base.se is not None and new.se is not None
        spread = math.hypot(base.se, new.se)
        delta = float(new.value) - float(base.value)
        if spread == 0:
            return 0.0 if (delta > 0 if higher else delta < 0) else 1.0
        return stats.normal_sf((delta if higher else -delta) / spread)
    assert base.events is not None and new.events is not None and base.exposure is not None and new.exposure is not None
    if kind is Sampling.PROPORTION:
        total, good, draws = round(base.exposure + new.exposure), base.events + new.events, round(new.exposure)
        if higher:
            return stats.hypergeom_sf(new.events, total, good, draws)
        return 1.0 - stats.hypergeom_sf(new.events + 1, total, good, draws)
    share = new.exposure / (base.exposure + new.exposure)  # RATE: given both runs' events, the new run's share is binomial
    both = base.events + new.events
    if higher:
        return stats.binom_sf(new.events, both, share)
    return stats.binom_cdf(new.events, both, share)
