"""Figures and verdicts from recorded samples (pure)."""

from __future__ import annotations

from runner.run.measure import check, thread_figures
from runner.run.samples import Sample, SlotData
from runner.run.stats import nearest_rank, summarize
from runner.scenario.model import Expectation


def slot(samples, finished=True):
    return SlotData(
        tid=1,
        state="done" if finished else "running",
        count=len(samples),
        err_sched=0,
        err_nice=0,
        err_cpus=0,
        err_other=0,
        start_ru=(0, 0, 0, 0),
        end_ru=(7, 30, 12900, 0),
        loops=len(samples),
        missed=0,
        work_start_ns=0,
        work_end_ns=0,
        cpus_seen=(1,),
        samples=tuple(samples),
    )


def sample(i, lat_us, nivcsw, minflt=0):
    due = i * 100_000_000
    return Sample(due, due + lat_us * 1000, due + 40_000_000, 40_000_000, nivcsw, 0, minflt, 0, 1, 0, 0)


def test_nearest_rank_is_an_observed_value():
    values = list(range(1, 101))
    assert nearest_rank(values, 0.5) == 50 and nearest_rank(values, 0.99) == 99 and nearest_rank(values, 0.999) == 100
    assert summarize([]) is None


def test_figures_of_a_callback_thread():
    f = thread_figures(slot([sample(0, 10, 0, 12800), sample(1, 20, 3), sample(2, 30, 4)]), periodic=True)
    assert f.callbacks == 3 and f.missed_releases == 0
    assert f.involuntary.total == 7 and f.involuntary.per_callback_mean == round(7 / 3, 4)
    assert f.involuntary.per_callback_max == 4 and f.involuntary.callbacks_with_any == 2
    assert f.latency_ns is not None
    assert f.latency_ns.model_dump() == {"min": 10_000, "p50": 20_000, "p90": 30_000, "p99": 30_000, "p999": 30_000, "max": 30_000}
    assert f.faults.minor_first_callback == 12800 and f.faults.minor_after_first == 0
    assert f.cpus_seen == (0, 1)


def test_an_unfinished_thread_counts_what_its_callbacks_recorded():
    f = thread_figures(slot([sample(0, 10, 2), sample(1, 10, 5)], finished=False), periodic=True)
    assert f.involuntary.total == 7 and not f.complete


def test_releases_no_callback_served_are_missed_up_to_the_end_of_the_cell():
    f = thread_figures(slot([sample(0, 10, 0), sample(1, 10, 0)]), periodic=True, releases_due=10)
    assert f.callbacks == 2 and f.missed_releases == 8


def test_verdicts_carry_the_measured_value():
    f = thread_figures(slot([sample(0, 10, 0), sample(1, 500, 1)]), periodic=True)
    ok = check(Expectation.model_validate({"thread": "t", "metric": "latency.p50", "max": "100us"}), "t", f)
    bad = check(Expectation.model_validate({"thread": "t", "metric": "involuntary.per_callback_mean", "max": 0.1}), "t", f)
    assert ok.passed and ok.measured == 10_000
    assert not bad.passed and bad.measured == 0.5 and bad.limit == "<= 0.1"


def test_a_thread_without_callbacks_cannot_pass_a_callback_check():
    f = thread_figures(slot([]), periodic=False)
    v = check(Expectation.model_validate({"thread": "t", "metric": "latency.max", "max": "1ms"}), "t", f)
    assert not v.passed and "not measured" in v.note
