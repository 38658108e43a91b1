"""The log-linear histogram (pure): buckets, precision, and percentiles exact to the bucket."""

from __future__ import annotations

import math
from array import array

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from runner import histogram as hg
from runner.run import _probe


def test_the_python_layout_is_the_native_cores():
    assert (hg.BUCKETS, hg.SUB_BITS) == (_probe.HIST_BUCKETS, _probe.HIST_SUB_BITS)


def test_small_values_are_exact_and_buckets_tile_the_range_without_gaps():
    assert [hg.bounds(hg.index(v)) for v in (0, 1, 255)] == [(0, 0), (1, 1), (255, 255)]
    previous_high = -1
    for i in range(hg.BUCKETS):
        low, high = hg.bounds(i)
        assert low == previous_high + 1 and high >= low
        previous_high = high


@given(st.integers(min_value=0, max_value=(1 << hg.TOP_BITS) - 1))
def test_every_value_lies_in_its_bucket_within_the_stated_precision(value):
    low, high = hg.bounds(hg.index(value))
    assert low <= value <= high
    assert high - low <= max(0, value * hg.RELATIVE_PRECISION)


def test_values_past_the_top_share_the_last_bucket():
    assert hg.index(1 << hg.TOP_BITS) == hg.index(1 << 62) == hg.BUCKETS - 1


def _nearest_rank(values: list[int], q: float) -> int:
    ordered = sorted(values)
    return ordered[max(1, math.ceil(q * len(ordered))) - 1]


@settings(max_examples=200)
@given(
    st.lists(st.integers(min_value=-(10**9), max_value=10**10), min_size=1, max_size=300), st.sampled_from([0.01, 0.5, 0.9, 0.99, 0.999])
)
def test_a_percentile_is_the_exact_one_to_the_bucket_and_never_flatters(values, q):
    hist = hg.from_values(values)
    assert hist is not None and hist.count == len(values) and (hist.min, hist.max) == (min(values), max(values))
    exact = _nearest_rank(values, q)
    high, low = hist.quantile(q), hist.quantile(q, low=True)
    assert low <= exact <= high  # high never understates a latency, low never overstates a slack
    width = abs(exact) * hg.RELATIVE_PRECISION + 1
    assert high - exact <= width and exact - low <= width


@settings(max_examples=200)
@given(st.lists(st.integers(min_value=-(10**9), max_value=10**10), min_size=1, max_size=300), st.booleans())
def test_quantiles_in_one_walk_are_each_quantile_to_the_bucket(values, low):
    hist = hg.from_values(values)
    assert hist is not None
    qs = [0.01, 0.5, 0.9, 0.99, 0.999, 1.0]
    for q, got in zip(qs, hist.quantiles(qs, low=low)):
        exact = _nearest_rank(values, q)
        assert (got <= exact) if low else (got >= exact)
        assert abs(got - exact) <= abs(exact) * hg.RELATIVE_PRECISION + 1


def test_above_counts_values_over_a_bound():
    hist = hg.from_values([100, 200, 300, 5000])
    assert hist is not None and hist.above(250) == 2 and hist.above(10_000) == 0
    assert hg.from_values([]) is None


@settings(max_examples=300)
@given(st.dictionaries(st.integers(0, hg.BUCKETS - 1), st.integers(1, 2**63), max_size=40), st.sampled_from(["list", "array"]))
def test_nonzero_finds_every_counter_that_is_not_zero_and_only_those(filled, kind):
    counts = [0] * hg.BUCKETS
    for i, n in filled.items():
        counts[i] = n
    given_counts = counts if kind == "list" else array("Q", counts)
    assert hg.nonzero(given_counts) == sorted(filled.items())


@settings(max_examples=300)
@given(st.dictionaries(st.integers(0, hg.BUCKETS - 1), st.integers(1, 2**64 - 1), max_size=40), st.booleans(), st.integers(0, 3))
def test_the_native_core_reads_a_histogram_in_place_as_python_builds_it(filled, negated, pad):
    counts = [0] * hg.BUCKETS
    for i, n in filled.items():
        counts[i] = n
    buffer = bytes(8 * pad) + array("Q", counts).tobytes()
    expected = hg.from_rows([], 0, 0, hg.nonzero(counts)) if negated else hg.from_rows(hg.nonzero(counts), 0, 0)
    assert _probe.buckets(buffer, 8 * pad, negated) == (expected.buckets if expected else [])


@settings(max_examples=300)
@given(st.lists(st.integers(-(2**41), 2**41), min_size=1, max_size=40), st.booleans())
def test_reading_only_the_buckets_of_the_minimum_to_the_maximum_misses_no_row(values, negated):
    """What a finished thread's histogram holds lies in the buckets of its exact minimum and maximum."""
    counts = [0] * hg.BUCKETS
    for v in values:
        counts[hg.index(v)] += 1
    buffer = array("Q", counts).tobytes()
    low, high = max(0, min(values)), max(0, max(values))
    assert _probe.buckets(buffer, 0, negated, hg.index(low), hg.index(high)) == _probe.buckets(buffer, 0, negated)
    assert _probe.buckets(buffer, 0, negated, 5, 4) == [], "an empty span reads nothing"
    for first, last in ((-1, 3), (0, hg.BUCKETS), (6, 4)):
        with pytest.raises(ValueError, match="not within"):
            _probe.buckets(buffer, 0, negated, first, last)


def test_the_native_core_refuses_a_histogram_beyond_its_buffer():
    buffer = bytes(hg.BUCKETS * 8)
    assert _probe.buckets(buffer, 0) == []
    for offset in (-8, 1, 8):
        with pytest.raises(ValueError, match="does not fit"):
            _probe.buckets(buffer, offset)


def test_nonzero_sees_the_first_and_the_last_counter():
    counts = [0] * hg.BUCKETS
    counts[0] = counts[-1] = 1
    assert hg.nonzero(counts) == [(0, 1), (hg.BUCKETS - 1, 1)]
    assert hg.nonzero([0] * hg.BUCKETS) == []
    counts[0], counts[-1] = 0, 256  # a count whose low byte is zero
    assert hg.nonzero(counts) == [(hg.BUCKETS - 1, 256)]


@given(
    st.lists(st.tuples(st.integers(-(10**7), 10**7), st.integers(0, 10**6), st.integers(0, 300)), min_size=1, max_size=6),
    st.integers(0, 2 * 10**7),
)
@settings(max_examples=150, deadline=None)
def test_latencies_counted_as_runs_are_those_counted_one_by_one(callbacks: list[tuple[int, int, int]], bound: int) -> None:
    # a callback after m missed releases has m + 1 latencies a period apart: past samples.EXPANDED they are counted as runs
    from runner.run import samples as sm

    made = [
        sm.Sample(
            scheduled_ns=10**9,
            wake_ns=10**9 + lat,
            end_ns=10**9 + lat + 10,
            burn_wall_ns=10,
            seq=i,
            nivcsw=0,
            nvcsw=0,
            minflt=0,
            majflt=0,
            cpu_start=0,
            cpu_end=0,
            missed=missed,
            origin_ns=0,
            period_ns=period,
            next_ns=0,
        )
        for i, (lat, period, missed) in enumerate(callbacks)
    ]
    one_by_one = sm._latencies(made, bound)
    expanded, sm.EXPANDED = sm.EXPANDED, 0
    try:
        runs = sm._latencies(made, bound)
    finally:
        sm.EXPANDED = expanded
    assert runs[0] == one_by_one[0] and runs[1] == one_by_one[1] and runs[4] == one_by_one[4]
    assert runs[2] == pytest.approx(one_by_one[2], rel=1e-9, abs=1e-3) and runs[3] == pytest.approx(one_by_one[3], rel=1e-6, abs=1)
