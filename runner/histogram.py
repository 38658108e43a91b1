"""Log-linear histograms of durations, as the native core keeps them: bounded memory for runs of any length.

The native core (run/interp.c) counts every latency, slack and callback time into
fixed buckets laid out as HdrHistogram does: values below 256 ns are their own
bucket, and every power of two above is split into 128 buckets, so a bucket is
never wider than 1/128 (0.78%) of the values in it.  Values from 2^40 ns (about
18 minutes) up share the last bucket.  A histogram is 4352 counters whatever the
run's length, and its percentiles are exact to the bucket: the nearest-rank value
lies in the bucket whose upper bound is reported (HdrHistogram's "highest
equivalent value"), clamped to the exact minimum and maximum kept beside it.

Signed values (slack, which is negative when a callback overran) are two
histograms in the native core, one of the value and one of its negation; here
both become one list of signed bucket ranges.  Pure: no I/O.
"""

from __future__ import annotations

import bisect
import itertools
import math
import operator
from collections.abc import Iterable, Sequence
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field

SUB_BITS = 7
SUB = 1 << SUB_BITS
TOP_BITS = 40
BUCKETS = (TOP_BITS - SUB_BITS + 1) * SUB
RELATIVE_PRECISION = 1 / SUB  # the widest bucket, relative to the values in it
QUANTILES = {"p50": 0.50, "p90": 0.90, "p99": 0.99, "p999": 0.999}  # the percentiles every duration figure reports


def index(value: int) -> int:
    """The bucket of a non-negative value in ns (negative values count as 0, as in the native core)."""
    if value >= 1 << TOP_BITS:
        return BUCKETS - 1
    return hdr_index(value)


def hdr_index(value: int) -> int:
    """`index` without the native core's last bucket: the counts index of HdrHistogram with 2 significant digits
    and a lowest discernible value of 1, whose layout the native core's buckets are (runner/report/hdrlog.py)."""
    if value < 2 * SUB:
        return max(0, value)
    shift = value.bit_length() - 1 - SUB_BITS
    return (shift + 1) * SUB + (value >> shift) - SUB


def bounds(i: int) -> tuple[int, int]:
    """The values bucket `i` holds, both ends included (the last bucket also holds everything above)."""
    if i < 2 * SUB:
        return i, i
    shift = i // SUB - 1
    low = (i % SUB + SUB) << shift
    return low, low + (1 << shift) - 1


_COUNT = operator.itemgetter(2)


class Histogram(BaseModel):
    """Counts by bucket, as stored in results.json: `[low_ns, high_ns, count]` rows, ascending, non-empty buckets only.

    `min` and `max` are exact; the rows are exact to the bucket.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    buckets: list[tuple[int, int, int]] = Field(description="[low, high, count]: `count` values in low..high ns, ascending")
    min: int
    max: int

    @property
    def count(self) -> int:
        return sum(map(_COUNT, self.buckets))

    def quantile(self, q: float, low: bool = False) -> int:
        """The nearest-rank q-quantile, to the bucket, within [min, max].

        The upper bound of its bucket, so a latency is never understated; with `low`, the
        lower bound, for figures where low is bad (slack), so those are never flattered either.
        """
        return self.quantiles((q,), low)[0]

    def quantiles(self, qs: Sequence[float], low: bool = False) -> list[int]:
        """`quantile` of each of `qs`, from one pass of running counts (a bisection per quantile)."""
        buckets = self.buckets
        seen = list(itertools.accumulate(map(_COUNT, buckets)))  # values up to each bucket (C loops: large cells have thousands)
        total = seen[-1] if seen else 0
        if not total:
            raise ValueError("an empty histogram has no quantiles")
        last, side, least, most = len(seen) - 1, 0 if low else 1, self.min, self.max  # side: the bucket's low or high bound
        out: list[int] = []
        for q in qs:
            bound = buckets[min(bisect.bisect_left(seen, max(1, math.ceil(q * total))), last)][side]
            out.append(least if bound < least else most if bound > most else bound)
        return out

    def above(self, bound: int) -> int:
        """Values above `bound`, counting a bucket that straddles it as above (an upper estimate)."""
        return sum(n for _low, high, n in self.buckets if high > bound)


def nonzero(counts: Sequence[int]) -> list[tuple[int, int]]:
    """(index, count) of the counters that are not zero, ascending (the runner reads the native core's in place instead)."""
    return [(i, int(n)) for i, n in enumerate(counts) if n]


def from_counts(counts: Sequence[int], low: int, high: int, negative: Optional[Sequence[int]] = None) -> Optional[Histogram]:
    """A histogram from native counters (`negative` counts the negation of values below 0); None when empty."""
    return from_rows(nonzero(counts), low, high, nonzero(negative) if negative is not None else None)


def from_rows(
    rows: Sequence[tuple[int, int]], low: int, high: int, negative: Optional[Sequence[tuple[int, int]]] = None
) -> Optional[Histogram]:
    """A histogram from the (index, count) of its counters that are not zero, ascending (`nonzero`); None when empty."""
    out: list[tuple[int, int, int]] = []
    for i, n in reversed(negative or ()):
        lo, hi = bounds(i)
        out.append((-hi, -lo, n))
    for i, n in rows:
        lo, hi = bounds(i)
        out.append((lo, hi, n))
    return of_buckets(out, low, high)


def of_buckets(buckets: list[tuple[int, int, int]], low: int, high: int) -> Optional[Histogram]:
    """A histogram from its `[low, high, count]` rows, ascending, as the native core reads them in place; None when empty."""
    if not buckets:
        return None
    return Histogram.model_construct(buckets=buckets, min=low, max=high)  # built from bucket numbers: nothing to validate


def merge(histograms: Iterable[Optional[Histogram]]) -> Optional[Histogram]:
    """One histogram of all values of these (same bucket layout): exact to the bucket, min and max exact; None when empty."""
    rows: dict[tuple[int, int], int] = {}
    present = [h for h in histograms if h is not None and h.buckets]
    for h in present:
        for lo, hi, n in h.buckets:
            rows[(lo, hi)] = rows.get((lo, hi), 0) + n
    if not present:
        return None
    buckets = [(lo, hi, n) for (lo, hi), n in sorted(rows.items())]
    return Histogram(buckets=buckets, min=min(h.min for h in present), max=max(h.max for h in present))


class Counter:
    """Values counted one at a time into the native core's buckets: the memory of a histogram, however many values come."""

    def __init__(self) -> None:
        self.pos = [0] * BUCKETS
        self.neg = [0] * BUCKETS
        self.low: Optional[int] = None
        self.high: Optional[int] = None

    def add(self, value: int) -> None:
        if value >= 0:
            self.pos[index(value)] += 1
        else:
            self.neg[index(-value)] += 1
        if self.low is None or self.high is None:
            self.low = self.high = value
        elif value < self.low:
            self.low = value
        elif value > self.high:
            self.high = value

    def add_run(self, first: int, step: int, n: int) -> None:
        """The `n` values first, first + step, ... (step >= 0) counted as `add` counts each, a bucket at a time: a
        timer millions of releases behind is as many latencies, counted in at most a pass over the buckets."""
        if n <= 0:
            return
        k = 0
        while k < n:
            v = first + k * step
            if v < 0:
                i = index(-v)
                last = n - 1 if step <= 0 else min(n - 1, (-bounds(i)[0] - first) // step)  # up to -low of -v's bucket
                self.neg[i] += last - k + 1
            else:
                i = index(v)
                last = n - 1 if step <= 0 or i == BUCKETS - 1 else min(n - 1, (bounds(i)[1] - first) // step)
                self.pos[i] += last - k + 1
            k = last + 1
        lo, hi = first, first + (n - 1) * max(step, 0)
        self.low = lo if self.low is None else min(self.low, lo)
        self.high = hi if self.high is None else max(self.high, hi)

    def histogram(self) -> Optional[Histogram]:
        """What was counted, as the native core would have reported it; None when nothing was."""
        if self.low is None or self.high is None:
            return None
        return from_counts(self.pos, self.low, self.high, self.neg if any(self.neg) else None)


def from_values(values: Iterable[int]) -> Optional[Histogram]:
    """The histogram the native core would have built from these values (signed allowed); None when empty."""
    counter = Counter()
    for v in values:
        counter.add(v)
    return counter.histogram()
