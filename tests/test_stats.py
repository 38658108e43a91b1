"""runner/stats.py and runner/results/estimates.py: exact tails against sums of exact fractions, intervals that cover
what they claim (checked by simulation, seeded), tests that hold their level on identical samples, Holm."""

from __future__ import annotations

import math
import random
from fractions import Fraction

import pytest
from reportdata import latencies, main_thread, matrix

from runner import figures as fg
from runner import stats
from runner.histogram import from_values
from runner.results.document import ThreadHistograms
from runner.results.estimates import estimate, p_change
from runner.run.measure import spread


def exact_binom_sf(k: int, n: int, p: Fraction) -> Fraction:
    return sum((math.comb(n, j) * p**j * (1 - p) ** (n - j) for j in range(max(k, 0), n + 1)), Fraction(0))


@pytest.mark.parametrize(("n", "p"), [(1, Fraction(1, 2)), (20, Fraction(1, 100)), (50, Fraction(1, 3)), (200, Fraction(99, 100))])
def test_binomial_tails_are_the_exact_sums(n, p):
    for k in range(-1, n + 2):
        want = float(exact_binom_sf(k, n, p))
        assert stats.binom_sf(k, n, float(p)) == pytest.approx(want, rel=1e-9, abs=1e-300), k
        assert stats.binom_cdf(k - 1, n, float(p)) == pytest.approx(1 - want, rel=1e-9, abs=1e-12), k


def test_poisson_tails_are_the_exact_sums():
    for mu in (0.3, 4.0, 60.0):
        for k in range(0, 120, 7):
            below = sum(math.exp(-mu) * mu**j / math.factorial(j) for j in range(k))
            assert stats.poisson_sf(k, mu) == pytest.approx(1 - below, rel=1e-9, abs=1e-14), (mu, k)


def test_fishers_test_of_missed_releases_is_the_hypergeometric_tail():
    """0 of 20 releases missed, then 7 of 20: P = C(20,7) / C(40,7), the chance all 7 misses fell in the new run."""
    assert stats.hypergeom_sf(7, 40, 7, 20) == pytest.approx(math.comb(20, 7) / math.comb(40, 7), rel=1e-12)
    assert stats.hypergeom_sf(0, 40, 7, 20) == 1.0


def test_the_beta_binomial_tail_of_exceeding_a_baseline_max():
    """k of n new samples above the max of m baseline ones: C(n, k) / C(n + m, k) when k = n (all of them)."""
    assert stats.betabinom_sf(5, 5, 1, 20) == pytest.approx(math.comb(5, 5) / math.comb(25, 5), rel=1e-12)
    assert stats.betabinom_sf(1, 20, 1, 20) == pytest.approx(20 / 40, rel=1e-12)  # the larger max of two equal runs: a coin


def test_exact_intervals_match_their_closed_forms():
    assert stats.proportion_interval(0, 20)[1] == pytest.approx(1 - 0.025 ** (1 / 20), rel=1e-6)
    assert stats.proportion_interval(20, 20)[0] == pytest.approx(0.025 ** (1 / 20), rel=1e-6)
    assert stats.poisson_interval(0)[1] == pytest.approx(-math.log(0.025), rel=1e-6)
    low, high = stats.poisson_interval(1)
    assert low == pytest.approx(-math.log(1 - 0.025), rel=1e-5) and 5.57 < high < 5.58


def test_a_p99_needs_368_samples_and_a_median_6():
    assert [stats.min_samples(q) for q in (0.5, 0.9, 0.99, 0.999, 0.01)] == [6, 36, 368, 3688, 368]
    assert stats.quantile_ranks(367, 0.99) is None and stats.quantile_ranks(368, 0.99) is not None
    assert stats.quantile_ranks(100, 0.5) == (40, 61)


def test_order_statistic_intervals_cover_the_true_quantile_as_often_as_they_claim():
    """A 95% interval of a p99 (and a p50) from a bucketed histogram covers the true quantile about 95% of the time.

    Seeded: 400 draws of 1,000 log-normal latencies each; the bucket width may only widen it (never below 95%, and not
    by much above)."""
    draw = random.Random(7)
    true = {0.99: 50_000 * math.exp(0.3 * 2.3263478740408408), 0.5: 50_000.0}
    covered = {0.99: 0, 0.5: 0}
    rounds = 400
    for _ in range(rounds):
        hist = from_values([round(50_000 * draw.lognormvariate(0, 0.3)) for _ in range(1_000)])
        assert hist is not None
        for q, want in true.items():
            ranks = stats.quantile_ranks(1_000, q)
            assert ranks is not None
            seen, low, high = 0, None, None
            for lo, hi, count in hist.buckets:
                seen += count
                if low is None and seen >= ranks[0]:
                    low = lo
                if seen >= ranks[1]:
                    high = hi
                    break
            covered[q] += low <= want <= high
    for q, hits in covered.items():
        assert 0.93 <= hits / rounds <= 0.995, (q, hits)


def test_a_proportions_exact_interval_covers_at_least_its_level():
    draw = random.Random(11)
    hits = 0
    for _ in range(400):
        k = sum(draw.random() < 0.05 for _ in range(200))
        low, high = stats.proportion_interval(k, 200)
        hits += low <= 0.05 <= high
    assert hits / 400 >= 0.94


def test_holm_adjusts_each_p_by_its_rank_and_keeps_order():
    assert stats.holm([0.01, 0.04, None, 0.03, 0.005]) == pytest.approx([0.03, 0.06, None, 0.06, 0.02])  # type: ignore[arg-type]
    assert stats.holm([]) == []


_TEMPLATE = main_thread(matrix().cells[1])


def thread_with(values: list[int]):
    """The recorded FIFO thread, with one callback per value of wake-up latency (its histogram and figures from them)."""
    hist = from_values(values)
    mean = sum(values) / len(values)
    figures = _TEMPLATE.figures.model_copy(
        update={"latency_ns": spread(hist, mean, sum((v - mean) ** 2 for v in values), len(values)), "callbacks": len(values)}
    )
    return _TEMPLATE.model_copy(update={"figures": figures, "histograms": ThreadHistograms(latency=hist)})


def test_identical_distributions_are_called_worse_about_as_often_as_the_level_allows():
    """The exceedance test of a p99 holds its level on samples of one law (exact, and conservative for the buckets)."""
    draw = random.Random(3)
    fig = fg.figure("latency.p99")
    rejected = 0
    for _ in range(200):
        base = thread_with([round(50_000 * draw.lognormvariate(0, 0.3)) for _ in range(500)])
        new = thread_with([round(50_000 * draw.lognormvariate(0, 0.3)) for _ in range(500)])
        b, n = estimate(fig, [base], [1_000_000_000]), estimate(fig, [new], [1_000_000_000])
        assert b is not None and n is not None
        p = p_change(b, n)
        assert p is not None
        rejected += p <= 0.05
    assert rejected / 200 <= 0.08


def test_a_grown_tail_is_worse_beyond_sampling_and_a_p99_of_twenty_is_not_judged():
    fig = fg.figure("latency.p99")
    base = estimate(fig, [thread_with(latencies(2_000, seed=1))], [200_000_000_000])
    grown = [v * 3 if i % 20 == 0 else v for i, v in enumerate(latencies(2_000, seed=2))]
    new = estimate(fig, [thread_with(grown)], [200_000_000_000])
    assert base is not None and new is not None and base.low is not None and new.low is not None
    assert new.low > base.high  # type: ignore[operator]
    assert (p := p_change(base, new)) is not None and p < 1e-6
    few = estimate(fig, [thread_with(latencies(20, seed=3))], [2_000_000_000])
    assert few is not None and few.few and few.lacking == "20 callbacks; p99 needs at least 368, run ≥ 37s"
    assert p_change(base, few) is None


def test_a_mean_has_its_standard_error_and_a_max_is_tested_by_exceedance():
    thread = thread_with(latencies(1_000, seed=5))
    mean = estimate(fg.figure("latency.mean"), [thread], [100_000_000_000])
    assert mean is not None and mean.se is not None and mean.low < mean.value < mean.high  # type: ignore[operator]
    top = estimate(fg.figure("latency.max"), [thread], [100_000_000_000])
    assert top is not None and top.low is None and top.testable  # an extreme has no interval, only a test
    worse = thread_with([v + 1_000_000 if i < 50 else v for i, v in enumerate(latencies(1_000, seed=6))])
    got = estimate(fg.figure("latency.max"), [worse], [100_000_000_000])
    assert got is not None and (p := p_change(top, got)) is not None and p < 1e-9


def test_a_figure_without_its_samples_stored_has_no_interval_and_says_why():
    """A wake-up spread of the scheduler trace in a file from before its histogram was stored: sample count unknown."""
    thread = main_thread(matrix().cells[0])
    hist = from_values([10_000, 12_000])
    old = spread(hist).model_copy(update={"count": None})  # type: ignore[union-attr]  # kept no count, as files before it
    figures = thread.figures.model_copy(update={"wakeup_ns": old})
    thread = thread.model_copy(update={"figures": figures, "histograms": ThreadHistograms()})
    got = estimate(fg.figure("wakeup.p99"), [thread], [1_000_000_000])
    assert got is not None and got.low is None and not got.testable and "no histogram" in got.lacking


def test_the_traces_wake_up_histogram_is_stored_so_its_quantiles_have_intervals():
    """The trace's wake-up spread was stored without its histogram: a wakeup.p99 could not be judged on its samples."""
    from runner.histogram import index
    from runner.run.traced import with_trace
    from runner.run.tracing import TracedThread

    values = latencies(1_000, seed=9)
    rows: dict[int, int] = {}
    for v in values:
        rows[index(v)] = rows.get(index(v), 0) + 1
    traced = TracedThread(
        tid=1, comm="t", wakeups=len(values), latency=tuple(sorted(rows.items())), latency_min=min(values), latency_max=max(values),
        preemptions=0, voluntary=0, preemptors=(), other_preemptors=0, migrations=0, cpus=(0,), run_ns=0, worst=(),
        latency_sum=sum(values),
    )  # fmt: skip
    thread = with_trace(main_thread(matrix().cells[1]), traced, {})
    assert thread.histograms is not None and thread.histograms.wakeup is not None
    assert thread.histograms.wakeup.count == len(values)
    got = estimate(fg.figure("wakeup.p99"), [thread], [10_000_000_000])
    assert got is not None and got.samples == 1_000 and got.low is not None and got.low <= got.value <= got.high  # type: ignore[operator]


def test_a_spread_that_says_how_many_values_it_holds_is_judged_on_that_count_without_a_histogram():
    """A program's lock waits keep no histogram, but their spread keeps its count: a p99 of 20 is not judged."""
    thread = main_thread(matrix().cells[0])
    hist = from_values(latencies(20, seed=4))
    spread20 = spread(hist, None, None, 20).model_copy(update={"count": 20})  # type: ignore[union-attr]
    thread = thread.model_copy(update={"figures": thread.figures.model_copy(update={"lock_wait_ns": spread20})})
    got = estimate(fg.figure("lock_wait.p99"), [thread], [2_000_000_000])
    assert got is not None and got.few and got.lacking.startswith("20 events; p99 needs at least 368")


def test_students_t_tail_keeps_its_precision_far_out():
    """The closed sums gave 1 - (1 - tail): 1.1e-16 for 7e-73 (df 30, t 50), 0 for 1.4e-274 (df 1000, t 50).  Far out, the
    tail is summed itself.  Closed forms for df 1 and 2; for others, scipy's (boost's incomplete beta) values."""
    for t in (0.5, 3.0, 40.0, 1e3, 1e8):
        assert stats.t_sf(t, 1) == pytest.approx(math.atan(1 / t) / math.pi, rel=1e-12, abs=0)
        root = math.sqrt(2 + t * t)
        assert stats.t_sf(t, 2) == pytest.approx(1 / (root * (root + t)), rel=1e-12, abs=0)
    known = {(30, 50.0): 9.357708829611355e-31, (1000, 10.0): 8.335351479300069e-23, (1000, 50.0): 1.379336206162586e-274}
    known |= {(5, 10.0): 8.547378787148181e-05, (7, 2.5): 0.020496109292876444, (1000, 5.0): 3.3836281823243174e-07}
    for (df, t), want in known.items():
        assert stats.t_sf(t, df) == pytest.approx(want, rel=1e-9, abs=0), (df, t)
        assert stats.t_sf(-t, df) == pytest.approx(1 - want, rel=1e-12)
