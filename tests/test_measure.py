"""Figures and verdicts from recorded samples (pure)."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from runner import figures as fg
from runner import histogram as hg
from runner.results.samplesfile import SAMPLE_COLUMNS
from runner.run.measure import check, thread_figures
from runner.run.samples import LockWait, Sample, _bits, rows, slot_of
from runner.scenario.model import Expectation, Metric

PERIOD = 100_000_000


def slot(samples, finished=True):
    return slot_of(list(samples), state="done" if finished else "running", end_ru=(7, 30, 12900, 0), cpus_seen=(1,))


def sample(i, lat_us, nivcsw, minflt=0, missed=0, end_ms=40):
    due = i * PERIOD
    return Sample(
        due,
        due + lat_us * 1000,
        due + end_ms * 1_000_000,
        40_000_000,
        i,
        nivcsw,
        0,
        minflt,
        0,
        1,
        0,
        missed,
        period_ns=PERIOD,
        next_ns=due + PERIOD,
    )


def top(value):
    """The value a percentile reports for `value`: the upper end of its histogram bucket."""
    return hg.bounds(hg.index(value))[1]


def test_figures_of_a_callback_thread():
    f = thread_figures(slot([sample(0, 10, 0, 12800), sample(1, 20, 3), sample(2, 30, 4)]), periodic=True)
    assert f.callbacks == 3 and f.missed_releases == 0
    assert f.involuntary.total == 7 and f.involuntary.per_callback_mean == round(7 / 3, 4)
    assert f.involuntary.per_callback_max == 4 and f.involuntary.callbacks_with_any == 2
    assert f.latency_ns is not None
    assert f.latency_ns.model_dump() == {
        "min": 10_000,
        "p50": top(20_000),
        "p90": 30_000,  # the upper end of 30 us's bucket, clamped to the exact maximum
        "p99": 30_000,
        "p999": 30_000,
        "max": 30_000,
        "mean": 20_000,
        "stddev": 8165,
        "above_bound": None,
        "count": 3,  # what the percentiles stand on: the 3 releases answered
    }
    assert f.faults.minor_first_callback == 12800 and f.faults.minor_after_first == 0
    assert f.cpus_seen == (0, 1)


def test_an_unfinished_thread_counts_what_its_callbacks_recorded():
    # 3 voluntary switches, 4 + 1 faults
    late = Sample(PERIOD, PERIOD + 10_000, PERIOD + 40_000_000, 40_000_000, 1, 5, 3, 4, 1, 1, 0, 0, period_ns=PERIOD, next_ns=2 * PERIOD)
    f = thread_figures(slot([sample(0, 10, 2, minflt=6), late], finished=False), periodic=True)
    assert not f.complete and f.involuntary.total == 7 and f.voluntary.total == 3
    assert (f.faults.minor, f.faults.major) == (10, 1)


def test_releases_no_callback_served_are_missed_up_to_the_end_of_the_cell():
    f = thread_figures(slot([sample(0, 10, 0), sample(1, 10, 0)]), periodic=True, releases_due=10)
    assert f.callbacks == 2 and f.missed_releases == 8


def test_verdicts_carry_the_measured_value():
    f = thread_figures(slot([sample(0, 10, 0), sample(1, 500, 1)]), periodic=True)
    ok = check(Expectation.parse({"thread": "t", "metric": "latency.p50", "max": "100us"}), "t", f)
    bad = check(Expectation.parse({"thread": "t", "metric": "involuntary.per_callback_mean", "max": 0.1}), "t", f)
    assert ok.passed and ok.measured == top(10_000)
    assert not bad.passed and bad.measured == 0.5 and bad.limit == "<= 0.1"


def test_a_thread_without_callbacks_cannot_pass_a_callback_check():
    f = thread_figures(slot([]), periodic=False)
    v = check(Expectation.parse({"thread": "t", "metric": "latency.max", "max": "1ms"}), "t", f)
    assert not v.passed and "not measured" in v.note


def test_a_thread_that_cannot_keep_up_shows_its_misses_overruns_and_negative_slack():
    # callback 0 ends 130 ms after its release (30 ms into the next period): it overran;
    # callback 1 serves release 2 after skipping release 1, whose latency runs to callback 1's wake-up.
    f = thread_figures(slot([sample(0, 10, 0, end_ms=130), sample(2, 10, 0, missed=1)]), periodic=True, releases_due=3)
    assert f.callbacks == 2 and f.releases == 3 and f.missed_releases == 1 and f.overruns == 1
    assert f.slack_ns is not None and f.slack_ns.min == -30_000_000 and f.slack_ns.max == 60_000_000
    assert f.latency_ns is not None and f.latency_ns.max == PERIOD + 10_000  # the skipped release waited a whole period
    assert f.latency_ns.min == 10_000 and f.latency_ns.mean == round((10_000 * 2 + PERIOD + 10_000) / 3)


def test_the_latency_bound_counts_the_releases_above_it():
    samples = [sample(0, 10, 0), sample(1, 500, 0), sample(3, 20, 0, missed=1)]
    f = thread_figures(slot_of(samples, bound=100_000), periodic=True, bound=100_000)
    assert f.latency_ns is not None and f.latency_ns.above_bound == 2  # 500 us, and the release skipped before #3
    assert thread_figures(slot_of(samples), periodic=True).latency_ns.above_bound is None  # type: ignore[union-attr]


@given(st.lists(st.integers(min_value=0, max_value=2**64 - 1), min_size=16, max_size=16))
def test_a_cpu_mask_reads_as_the_numbers_of_its_bits(words):
    expected = tuple(w * 64 + b for w, word in enumerate(words) for b in range(64) if word >> b & 1)
    assert _bits(tuple(words)) == expected


def test_cpu_masks_at_the_ends_of_their_words():
    assert _bits((1, 0, 2**63, *(0,) * 13)) == (0, 191)
    assert _bits((0,) * 16) == ()


def test_a_row_says_per_mutex_how_long_the_activation_waited_and_who_held_it():
    taken = [
        Sample(
            0,
            10,
            9_000_000,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            lock_wait_ns=6_500_000,
            period_ns=PERIOD,
            locks=(LockWait(6_000_000, 4, 1, 1), LockWait(500_000, -1, 2, 0), LockWait(0, -1, 0, 0)),
        ),
        Sample(PERIOD, PERIOD + 10, PERIOD + 1_000_000, 0, 1, 0, 0, 0, 0, 0, 0, 0, period_ns=PERIOD, locks=(LockWait(0, -1, 0, 0),) * 3),
    ]
    written = rows("app[0]/high #3", 9, taken, ("data", "log", "never"), {4: "app[0]/low #1"})
    assert json.loads(written[0][-1]) == {
        "data": {"wait_ns": 6_000_000, "taken": 1, "contended": 1, "held_by": "app[0]/low #1"},
        "log": {"wait_ns": 500_000, "taken": 2, "contended": 0, "held_by": None},
    }
    assert written[1][-1] is None, "an activation that locked none of them"
    assert rows("app[0]/t (main)", 9, taken)[0][-1] is None, "a thread that locks no mutex has no such cell"


def test_a_stage_released_by_resumes_has_callbacks_and_latency_but_nothing_measured_against_a_period():
    # Released at 0, 10 and 30 ms by resumes; the second came while the first still ran (5 ms late).
    taken = [
        Sample(0, 50_000, 12_000_000, 0, 0, 1, 0, 0, 0, 0, 0, 0, origin_ns=1),
        Sample(10_000_000, 12_000_000, 14_000_000, 0, 1, 0, 0, 0, 0, 0, 0, 0, origin_ns=1),
        Sample(30_000_000, 30_020_000, 31_000_000, 0, 2, 0, 0, 0, 0, 0, 0, 0),
    ]
    f = thread_figures(slot_of(taken), periodic=False, released=True)
    assert f.callbacks == 3 and (f.releases, f.missed_releases, f.overruns, f.slack_ns) == (0, 0, 0, None)
    assert f.latency_ns is not None and (f.latency_ns.min, f.latency_ns.max) == (20_000, 2_000_000)
    assert f.callback_wall_ns is not None and f.callback_wall_ns.max == 11_950_000
    assert f.involuntary.callbacks_with_any == 1
    # Rows: no slack; the chain latency where the activation belongs to a chain.
    written = rows("app[0]/stage #1", 7, taken)
    at = [SAMPLE_COLUMNS.index(c) for c in ("slack_ns", "chain_ns", "period_ns")]
    assert [tuple(r[i] for i in at) for r in written] == [(None, 11_999_999, 0), (None, 13_999_999, 0), (None, None, 0)]
    assert thread_figures(slot_of(taken), periodic=False).callbacks == 0, "neither periodic nor released: no callbacks"


def test_the_most_releases_missed_in_a_row_is_the_longest_run_no_callback_served():
    """Control loops survive one lost release, not two in a row: 3 missed in all, at most 2 of them in a row."""
    samples = [sample(0, 10, 0), sample(3, 10, 0, missed=2), sample(4, 10, 0), sample(6, 10, 0, missed=1)]
    f = thread_figures(slot(samples), periodic=True, releases_due=7)
    assert (f.missed_releases, f.missed_consecutive_max) == (3, 2)
    bound = Expectation.parse({"thread": "t", "metric": "missed_releases.consecutive_max", "max": 1})
    v = check(bound, "t", f)
    assert not v.passed and v.measured == 2 and v.limit == "<= 1"
    kept_up = thread_figures(slot([sample(i, 10, 0) for i in range(4)]), periodic=True, releases_due=4)
    assert kept_up.missed_consecutive_max == 0 and check(bound, "t", kept_up).passed


def test_releases_after_a_stopped_threads_last_callback_are_one_run_of_misses():
    f = thread_figures(slot([sample(0, 10, 0), sample(2, 10, 0, missed=1)], finished=False), periodic=True, releases_due=10)
    assert (f.missed_releases, f.missed_consecutive_max) == (8, 7)  # releases 3 to 9, which no callback reached


def test_a_thread_without_a_period_has_no_misses_in_a_row_and_an_expectation_on_them_is_not_measured():
    f = thread_figures(slot([sample(0, 10, 0)]), periodic=False, released=True)
    assert f.missed_consecutive_max is None
    v = check(Expectation.parse({"thread": "t", "metric": "missed_releases.consecutive_max", "max": 1}), "t", f)
    assert not v.passed and "not measured" in v.note


def test_the_registry_declares_misses_in_a_row_an_exact_count_of_periodic_threads_compared_at_plus_0():
    fig = fg.figure("missed_releases.consecutive_max")
    assert (fig.unit, fig.kind, fig.worse, fig.threshold) == (fg.Unit.COUNT, fg.Sampling.EXACT, fg.Worse.HIGHER, fg.Threshold(absolute=0))
    assert fg.default_thresholds()[fig.name] == fg.Threshold(absolute=0)
    periodic, released = fg.ThreadKind("periodic", callbacks=True, period=True), fg.ThreadKind("released", callbacks=True)
    program, spinner = fg.ThreadKind("a command: program's", proc=True), fg.ThreadKind("spin")
    assert [fg.has(k, fig) for k in (periodic, released, program, spinner)] == [True, False, False, False]
    assert Metric("missed_releases.consecutive_max").figure is fig
    with pytest.raises(ValueError, match="is a count"):
        Expectation.parse({"thread": "t", "metric": "missed_releases.consecutive_max", "max": "1ms"})
