"""Exact small statistics for judging figures against their sampling error: tails, intervals, Holm.  Pure, no I/O.

What a run's figures stand on is counted, not assumed: a p99 is an order statistic of so many
callbacks, missed releases are so many of so many releases, switches so many over so many
callbacks.  Each gets an interval and each change a p-value from the distributions that
describe such counts exactly:

- quantiles: distribution-free order-statistic intervals (the number of samples below the true
  q-quantile is binomial(n, q) whatever the distribution), `quantile_ranks`;
- a proportion (missed of releases): Clopper-Pearson's exact binomial interval; two runs'
  proportions: Fisher's exact test (the hypergeometric tail);
- a count over an exposure (switches per callback): Garwood's exact Poisson interval; two runs'
  rates: the exact conditional binomial test;
- a quantile of two runs: how many of the new run's samples lie beyond the baseline's order
  statistic, whose law under "the same distribution" is beta-binomial (exact, distribution-free);
- a mean: its standard error, normal (the only approximation here: a mean of many callbacks);
- many figures at once: Holm's step-down, so a matrix of hundreds of figures does not "find" a
  regression by chance (family-wise error at most alpha).

Hand-written rather than scipy: each is a short exact sum of a unimodal probability mass
function, walked from the far side of its mean with the ratio of neighbouring terms (so a tail
of a million trials costs a few thousand multiplications, not a million), and the core install
is kept light on purpose (numpy and scipy are about 100 MB, and a run's judgement must not need
them).  Change-point detection over many nights, which is no short exact sum, is left to a
library in the `history` extra (runner/history).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Optional

CONFIDENCE = 0.95  # the level of every interval shown and the family-wise level of a comparison's verdicts
ALPHA = 1 - CONFIDENCE
_TINY = 1e-17  # a term this small against the running sum changes nothing in a double


def _tail(log_first: float, ratio: Callable[[int], float], start: int, end: int, step: int) -> float:
    """Sum of a unimodal pmf from `start` to `end` (inclusive) stepping `step` (+1 or -1).

    `log_first` is the log of the pmf at `start`; `ratio(k)` is pmf(k + step) / pmf(k).  The walk
    stops once the terms decrease and no longer change the sum.
    """
    term = math.exp(log_first) if log_first > -745 else 0.0
    total = term
    k = start
    while k != end:
        nxt = term * ratio(k)
        k += step
        total += nxt
        if nxt <= term and nxt <= total * _TINY:
            break
        term = nxt
    return min(1.0, total)


def _log_comb(n: int, k: int) -> float:
    return math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)


# ---------------------------------------------------------------- binomial


def binom_logpmf(k: int, n: int, p: float) -> float:
    if p <= 0:
        return 0.0 if k == 0 else -math.inf
    if p >= 1:
        return 0.0 if k == n else -math.inf
    return _log_comb(n, k) + k * math.log(p) + (n - k) * math.log1p(-p)


def binom_cdf(k: int, n: int, p: float) -> float:
    """P(X <= k) for X ~ binomial(n, p)."""
    if k < 0:
        return 0.0
    if k >= n:
        return 1.0
    if k >= n * p:
        return max(0.0, 1.0 - binom_sf(k + 1, n, p))
    if p <= 0:
        return 1.0
    odds = (1 - p) / p
    return _tail(binom_logpmf(k, n, p), lambda j: j / (n - j + 1) * odds, k, 0, -1)


def binom_sf(k: int, n: int, p: float) -> float:
    """P(X >= k) for X ~ binomial(n, p)."""
    if k <= 0:
        return 1.0
    if k > n:
        return 0.0
    if k <= n * p:
        return max(0.0, 1.0 - binom_cdf(k - 1, n, p))
    if p >= 1:
        return 1.0
    odds = p / (1 - p)
    return _tail(binom_logpmf(k, n, p), lambda j: (n - j) / (j + 1) * odds, k, n, 1)


# ---------------------------------------------------------------- Poisson


def poisson_logpmf(k: int, mu: float) -> float:
    if mu <= 0:
        return 0.0 if k == 0 else -math.inf
    return k * math.log(mu) - mu - math.lgamma(k + 1)


def poisson_cdf(k: int, mu: float) -> float:
    """P(X <= k) for X ~ Poisson(mu)."""
    if k < 0:
        return 0.0
    if k >= mu:
        return max(0.0, 1.0 - poisson_sf(k + 1, mu))
    return _tail(poisson_logpmf(k, mu), lambda j: j / mu, k, 0, -1)


def poisson_sf(k: int, mu: float) -> float:
    """P(X >= k) for X ~ Poisson(mu)."""
    if k <= 0:
        return 1.0
    if mu <= 0:
        return 0.0
    if k <= mu:
        return max(0.0, 1.0 - poisson_cdf(k - 1, mu))
    return _tail(poisson_logpmf(k, mu), lambda j: mu / (j + 1), k, -1, 1)


# ---------------------------------------------------------------- hypergeometric and beta-binomial


def hypergeom_sf(k: int, total: int, good: int, draws: int) -> float:
    """P(X >= k): X good items among `draws` taken without replacement from `total` holding `good` (Fisher's exact test)."""
    low, high = max(0, draws - (total - good)), min(good, draws)
    if k <= low:
        return 1.0
    if k > high:
        return 0.0

    def logpmf(j: int) -> float:
        return _log_comb(good, j) + _log_comb(total - good, draws - j) - _log_comb(total, draws)

    mean = draws * good / total
    rest = total - good - draws
    if k <= mean:
        below = _tail(logpmf(k - 1), lambda j: j * (rest + j) / ((good - j + 1) * (draws - j + 1)), k - 1, low, -1)
        return max(0.0, 1.0 - below)
    return _tail(logpmf(k), lambda j: (good - j) * (draws - j) / ((j + 1) * (rest + j + 1)), k, high, 1)


def betabinom_sf(k: int, n: int, a: float, b: float) -> float:
    """P(X >= k) for X ~ beta-binomial(n, a, b): binomial(n, P) with P ~ beta(a, b)."""
    if k <= 0:
        return 1.0
    if k > n:
        return 0.0

    def logpmf(j: int) -> float:
        return _log_comb(n, j) + math.lgamma(j + a) + math.lgamma(n - j + b) - math.lgamma(n + a + b) - _lbeta(a, b)

    mean = n * a / (a + b)
    if k <= mean:
        below = _tail(logpmf(k - 1), lambda j: j / (n - j + 1) * (n - j + b) / (j - 1 + a), k - 1, 0, -1)
        return max(0.0, 1.0 - below)
    return _tail(logpmf(k), lambda j: (n - j) / (j + 1) * (j + a) / (n - j - 1 + b), k, n, 1)


def _lbeta(a: float, b: float) -> float:
    return math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)


def normal_sf(z: float) -> float:
    """P(Z >= z) for a standard normal Z."""
    return 0.5 * math.erfc(z / math.sqrt(2))


def t_sf(t: float, df: int) -> float:
    """P(T >= t) for Student's T with `df` (whole) degrees of freedom: the closed sums of Abramowitz and Stegun 26.7.3-4.

    They give P(|T| < t); far out (a tail below 1e-3) the tail is summed itself, the rest of the same series (its terms
    shrink by cos² θ = df / (df + t²) each), since 1 minus a sum near 1 keeps no digit of a tail below 1e-16.
    """
    if df < 1:
        raise ValueError(f"t_sf: df {df}: expected at least 1")
    theta = math.atan(abs(t) / math.sqrt(df))
    c2, sin, cos = math.cos(theta) ** 2, math.sin(theta), math.cos(theta)
    if df % 2:  # odd
        total, term = 1.0, 1.0
        for k in range(1, (df - 1) // 2):
            term *= c2 * (2 * k) / (2 * k + 1)
            total += term
        inside = 2 / math.pi * (theta + (sin * cos * total if df > 1 else 0.0))
    else:
        total, term = 1.0, 1.0
        for k in range(1, df // 2):
            term *= c2 * (2 * k - 1) / (2 * k)
            total += term
        inside = sin * total
    tail = max(0.0, (1 - inside) / 2)
    if tail < 1e-3:  # 1 minus a sum near 1: the tail summed itself keeps its digits
        tail = _t_far(abs(t), df) / 2
    return tail if t >= 0 else 1 - tail


def _t_far(t: float, df: int) -> float:
    """P(|T| >= t): the terms of 26.7.3-4's series past the last one they keep, summed.

    With x = cos² θ = df / (df + t²): even df, sin θ · Σ_{k >= df/2} c_k x^k with c_k = Γ(k + 1/2) / (√π Γ(k + 1));
    odd df, (2/π) sin θ cos θ · Σ_{k >= (df-1)/2} d_k x^k with d_k = √π Γ(k + 1) / (2 Γ(k + 3/2)) (the whole series
    sum to 1 / sin θ and (π/2 - θ) / (sin θ cos θ)).
    """
    x = df / (df + t * t)
    sin, cos = t / math.sqrt(df + t * t), math.sqrt(x)
    even = df % 2 == 0
    k = df // 2 if even else (df - 1) // 2
    if even:
        log_first = math.lgamma(k + 0.5) - 0.5 * math.log(math.pi) - math.lgamma(k + 1) + k * math.log(x)
        front = sin
    else:
        log_first = 0.5 * math.log(math.pi) + math.lgamma(k + 1) - math.log(2) - math.lgamma(k + 1.5) + k * math.log(x)
        front = 2 / math.pi * sin * cos
    term = total = math.exp(log_first) if log_first > -745 else 0.0
    while term > total * _TINY:
        term *= x * ((2 * k + 1) / (2 * k + 2) if even else (2 * k + 2) / (2 * k + 3))
        total += term
        k += 1
    return min(1.0, front * total)


def normal_quantile(p: float) -> float:
    """z with P(Z <= z) = p (the standard library's inverse, exact to double precision)."""
    from statistics import NormalDist  # here: statistics imports fractions and random, which a run's start need not pay for

    return NormalDist().inv_cdf(p)


# ---------------------------------------------------------------- intervals


def _solve(f: Callable[[float], float], target: float, low: float, high: float, rising: bool) -> float:
    """x in [low, high] with f(x) = target for a monotone f (bisection to a relative 1e-7)."""
    for _ in range(200):
        mid = (low + high) / 2
        if high - low <= 1e-7 * max(abs(mid), 1e-300):
            break
        if (f(mid) < target) == rising:
            low = mid
        else:
            high = mid
    return (low + high) / 2


def proportion_interval(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Clopper-Pearson's exact interval of a proportion, `k` of `n` (never narrower than its level asks)."""
    if n <= 0:
        return 0.0, 1.0
    half = (1 - confidence) / 2
    low = 0.0 if k <= 0 else _solve(lambda p: binom_sf(k, n, p), half, 0.0, k / n, True)
    high = 1.0 if k >= n else _solve(lambda p: binom_cdf(k, n, p), half, k / n, 1.0, False)
    return low, high


def poisson_interval(k: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Garwood's exact interval of a Poisson mean, from one count `k`."""
    half = (1 - confidence) / 2
    top = k + 12 * math.sqrt(k + 1) + 12
    low = 0.0 if k <= 0 else _solve(lambda mu: poisson_sf(k, mu), half, 0.0, float(k), True)
    high = _solve(lambda mu: poisson_cdf(k, mu), half, float(k), top, False)
    return low, high


def min_samples(q: float, confidence: float = CONFIDENCE) -> int:
    """The fewest samples for which the q-quantile has a two-sided distribution-free interval at `confidence`.

    Its ends are order statistics: the top one exists only when the chance that every sample falls
    below the quantile, q^n, is below half the error allowed (368 samples for a p99: 0.99^367 is
    0.02501; 3,688 for a p99.9, 6 for a median).  An extreme (q 0 or 1) never has one.
    """
    if q <= 0 or q >= 1:
        return 0
    half = (1 - confidence) / 2
    return math.ceil(math.log(half) / math.log(max(q, 1 - q)))


def quantile_ranks(n: int, q: float, confidence: float = CONFIDENCE) -> Optional[tuple[int, int]]:
    """Ranks (1-based) of the order statistics bounding the q-quantile of `n` samples at `confidence`; None when too few.

    The count B of samples below the true quantile is binomial(n, q) for any continuous law, so
    [X(l), X(u)] covers it with probability P(l <= B < u): l is the largest rank with P(B < l) at
    most half the error, u the smallest with P(B >= u) at most half.
    """
    if n < min_samples(q, confidence) or not 0 < q < 1:
        return None
    half = (1 - confidence) / 2

    def largest(pred: Callable[[int], bool], low: int, high: int) -> int:
        while low < high:  # the largest x in [low, high] with pred(x), pred monotone falling
            mid = (low + high + 1) // 2
            if pred(mid):
                low = mid
            else:
                high = mid - 1
        return low

    centre = max(1, min(n, round(n * q)))
    lower = largest(lambda r: binom_cdf(r - 1, n, q) <= half, 1, centre)
    upper = n + 1 - largest(lambda s: binom_sf(n + 1 - s, n, q) <= half, 1, n + 1 - centre)
    return lower, upper


# ---------------------------------------------------------------- several figures at once


def holm(pvalues: Sequence[Optional[float]], alpha: float = ALPHA) -> list[Optional[float]]:
    """Holm's step-down adjusted p-values (None stays None): reject where the adjusted value is at most `alpha`.

    The family is every p-value given: with m of them the smallest must be below alpha/m, the next
    below alpha/(m-1), and so on, which keeps the chance of any false rejection at most alpha
    whatever the dependence between them.
    """
    ordered = sorted((p, i) for i, p in enumerate(pvalues) if p is not None)
    m = len(ordered)
    out: list[Optional[float]] = [None] * len(pvalues)
    running = 0.0
    for rank, (p, i) in enumerate(ordered):
        running = max(running, min(1.0, (m - rank) * p))
        out[i] = running
    return out


def median_and_mad(values: Sequence[float]) -> tuple[float, float]:
    """The median and the median absolute deviation from it (robust centre and spread)."""
    ordered = sorted(values)
    centre = _median(ordered)
    return centre, _median(sorted(abs(v - centre) for v in ordered))


def _median(ordered: Sequence[float]) -> float:
    n = len(ordered)
    if not n:
        raise ValueError("no values")
    mid = n // 2
    return float(ordered[mid]) if n % 2 else (ordered[mid - 1] + ordered[mid]) / 2
