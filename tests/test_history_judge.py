"""runner/history/judge.py on synthetic histories: pure noise, a planted step (reported once), a step in variance only,
a slow drift, too few nights, a figure new or gone, and what changed in the environment said with the change."""

from __future__ import annotations

import math
import random

from runner.history.judge import CellInput, Verdict, judge, level_starts
from runner.history.night import FigureRow
from runner.history.store import ChangePoint, Point
from runner.report.compare import DEFAULT_THRESHOLDS

THREAD = "ctl[0]/loop (main)"
FIGURE = "latency.p99"
P99 = [t for t in DEFAULT_THRESHOLDS if t.figure == FIGURE]


def stamp(night: int) -> str:
    return f"2026-{1 + night // 28:02d}-{1 + night % 28:02d}T02:17:00+00:00"


def point(night: int, value: float, half: float = 0.04) -> Point:
    """A night's p99 with an interval of ±`half` (relative), as a run of a few thousand callbacks has."""
    return Point(stamp(night), value, 5_000, value * (1 - half), value * (1 + half), None, None, None, False)


def row(p: Point) -> FigureRow:
    return FigureRow(THREAD, FIGURE, p.value, p.samples, p.low, p.high)


def nights(values: list[float], environments: dict[str, dict[str, str]] | None = None) -> list[tuple[int, Verdict, str]]:
    """Each night judged against those before it, as `--history` does night after night: (night, verdict, words)."""
    past: list[Point] = []
    recorded: list[ChangePoint] = []
    out = []
    for n, value in enumerate(values):
        p = point(n, value)
        cell = CellInput("cell", "spec", p.started_at, [row(p)], {(THREAD, FIGURE): list(past)}, recorded=list(recorded))
        verdict = judge([cell], P99, environments or {}, p.started_at)
        (f,) = verdict.figures
        out.append((n, f.verdict, f.words))
        recorded += verdict.change_points
        past.append(p)
    return out


def noise(n: int, seed: int, level: float = 60_000, sigma: float = 0.08) -> list[float]:
    draw = random.Random(seed)
    return [level * math.exp(draw.gauss(0, sigma)) for _ in range(n)]


def test_too_few_nights_is_learning_and_says_how_many_are_needed():
    got = nights(noise(6, seed=1))
    assert got[0][1] == Verdict.NEW
    assert [v for _, v, _ in got[1:5]] == [Verdict.LEARNING] * 4
    assert got[2][2] == "learning: 2 of 5 nights needed"
    assert got[5][1] == Verdict.WITHIN


def test_pure_noise_raises_about_as_many_alarms_as_its_level_allows():
    """200 nights of pure noise (five series of 40; ±8%, and ±30% for the noisiest), each judged alone (a family of one
    figure, so Holm takes nothing off): at the night's 1% level about 2 alarms, never a run of them."""
    alarms = []
    for seed in range(5):
        got = nights(noise(40, seed=seed, sigma=0.08 if seed < 3 else 0.3))
        alarms += [(seed, n) for n, v, _ in got if v == Verdict.REGRESSION]
    assert len(alarms) <= 3, alarms


def test_a_step_is_reported_once_on_its_first_night_with_what_changed_that_night():
    values = noise(20, seed=7) + [v * 4 for v in noise(15, seed=8)]
    environments = {stamp(n): {"kernel": "6.12.8" if n < 20 else "6.12.9"} for n in range(35)}
    got = nights(values, environments)
    regressions = [(n, words) for n, v, words in got if v == Verdict.REGRESSION]
    assert [n for n, _ in regressions] == [20], got[18:]
    assert "outside the " in regressions[0][1] and "changed tonight: kernel 6.12.8 → 6.12.9" in regressions[0][1]
    assert all(v in (Verdict.CONTINUING, Verdict.LEARNING, Verdict.WITHIN) for n, v, _ in got[21:]), got[21:]
    assert any(v == Verdict.CONTINUING and "continues the change of" in w for _, v, w in got[21:])
    assert got[-1][1] == Verdict.WITHIN  # the new level is the range now


def test_a_single_wild_night_is_one_alarm_and_the_nights_after_it_are_judged_against_the_old_level():
    values = noise(20, seed=9)
    values[12] *= 5
    values += noise(10, seed=10)
    got = nights(values)
    assert [n for n, v, _ in got if v == Verdict.REGRESSION] == [12]
    assert any("back at the level before the change" in w for _, _, w in got[13:18])


def test_a_step_in_variance_only_is_not_a_regression_of_its_level():
    draw = random.Random(11)
    values = [60_000 * math.exp(draw.gauss(0, 0.05)) for _ in range(20)] + [60_000 * math.exp(draw.gauss(0, 0.2)) for _ in range(20)]
    regressions = [n for n, v, _ in nights(values) if v == Verdict.REGRESSION]
    assert len(regressions) <= 2, regressions  # its first wide nights may stand out; then the range is learnt anew


def test_a_slow_drift_is_caught_once_it_is_past_threshold_and_range_and_not_every_night_after():
    values = [60_000 * (1 + 0.03 * n) * math.exp(random.Random(n).gauss(0, 0.02)) for n in range(45)]
    regressions = [n for n, v, _ in nights(values) if v == Verdict.REGRESSION]
    assert 1 <= len(regressions) <= 3, regressions
    assert regressions[0] < 40


def test_a_figure_gone_tonight_is_missing_and_one_without_past_is_new():
    past = {(THREAD, FIGURE): [point(n, 60_000) for n in range(6)]}
    gone = judge([CellInput("cell", "spec", stamp(6), [], past)], P99, {}, stamp(6))
    assert [f.verdict for f in gone.figures] == [Verdict.MISSING] and gone.regressions == 1
    fresh = judge([CellInput("cell", "spec", stamp(6), [row(point(6, 60_000))], {})], P99, {}, stamp(6))
    assert [f.verdict for f in fresh.figures] == [Verdict.NEW] and fresh.regressions == 0


def test_a_cell_whose_spec_changed_says_its_history_starts_anew():
    cell = CellInput("cell", "spec2", stamp(0), [row(point(0, 60_000))], {}, new_spec="its resolved scenario changed")
    assert judge([cell], P99, {}, stamp(0)).notes == ["cell: its resolved scenario changed"]


def test_change_points_of_a_planted_step_are_found_where_it_was_planted():
    values = [math.log(v) for v in noise(15, seed=3)] + [math.log(v * 3) for v in noise(15, seed=4)]
    assert level_starts(values) == [15]
    assert level_starts([math.log(v) for v in noise(30, seed=5)]) == []


def test_a_count_that_was_zero_every_night_and_jumps_is_a_regression():
    """0 switches of 10 callbacks every night (each 0 [0, 0.37]), then 135 per callback: on a log scale offset by a
    hundredth, the nights' own intervals spanned a factor of 40 and hid the jump; offset by their half width, they do not."""
    name = "involuntary.per_callback_mean"
    past = [Point(stamp(n), 0.0, 10, 0.0, 0.3689, 0, 10.0, None, False) for n in range(5)]
    tonight = FigureRow(THREAD, name, 134.9, 1349, 127.8, 142.3, 1349, 10.0)
    thresholds = [t for t in DEFAULT_THRESHOLDS if t.figure == name]
    got = judge([CellInput("cell", "spec", stamp(5), [tonight], {(THREAD, name): past})], thresholds, {}, stamp(5))
    assert [f.verdict for f in got.figures] == [Verdict.REGRESSION], got.figures


def test_a_worst_slack_is_judged_by_how_many_samples_lie_beyond_the_past_nights_not_by_one():
    """slack.min is one callback of 20: one callback 19 ms late on an identical night moved it from 59.9 to 40.8 ms, far
    outside the nights' range of minima.  Against the 200 callbacks of the past nights pooled, one sample below their worst
    is what 20 more samples give a tenth of the time: not a regression; ten of them are."""
    from runner.histogram import from_values

    name = "slack.min"
    past = [Point(stamp(n), 59_900_000.0 + 10_000 * (n % 3), 20, None, None, None, None, None, False) for n in range(10)]
    pooled = from_values([59_900_000 + 5_000 * (i % 40) for i in range(200)])
    thresholds = [t for t in DEFAULT_THRESHOLDS if t.figure == name]

    def tonight(late: int):
        values = [40_800_000] * late + [59_950_000] * (20 - late)
        hist = from_values(values)
        assert pooled is not None and hist is not None
        row = FigureRow(THREAD, name, float(min(values)), 20)
        cell = CellInput(
            "cell", "spec", stamp(10), [row], {(THREAD, name): past},
            histograms={(THREAD, "slack"): hist}, past_histograms={(THREAD, "slack"): pooled},
        )  # fmt: skip
        (f,) = judge([cell], thresholds, {}, stamp(10)).figures
        return f.verdict

    assert tonight(1) == Verdict.WITHIN
    assert tonight(10) == Verdict.REGRESSION


def regressions_of(values: list[float]) -> list[int]:
    return [n for n, v, _ in nights(values) if v == Verdict.REGRESSION]


def test_a_wild_night_the_nights_came_back_from_does_not_restart_the_history_nor_widen_its_range():
    """One night ×5, reported, then four nights back at the old level: it was a wild night, not a level.  The history
    restarted at it, its range [20 µs, 168 µs] held a lasting +60% step from night 25 on, never reported."""
    values = noise(25, seed=9)
    values[12] *= 5
    values += [v * 1.6 for v in noise(10, seed=10)]
    assert regressions_of(values) == [12, 25]


def test_a_wild_night_while_learning_does_not_hide_a_later_step():
    """Night 2 ×5 (learning, so never judged) stayed in every range after it: the nights' standard deviation, taken as the
    spread whenever larger than their MAD, made a range too wide for a lasting +60% step from night 20."""
    values = noise(20, seed=9)
    values[2] *= 5
    values += [v * 1.6 for v in noise(10, seed=10)]
    assert regressions_of(values) == [20]


def test_a_further_step_while_a_change_is_continued_is_reported_too():
    """+60% from night 20 (reported), then ×2.5 more from night 22: the nights after a change were 'continuing' it
    whatever they were, so the second, larger step was never reported."""
    values = noise(20, seed=9) + [v * 1.6 for v in noise(2, seed=10)] + [v * 4 for v in noise(13, seed=11)]
    assert regressions_of(values) == [20, 22]


def test_a_night_judged_twice_a_shard_then_the_merge_is_a_regression_both_times():
    """The merge of the shards judges a cell the shard already judged and reported: its change point is tonight's own."""
    past = [point(n, v) for n, v in enumerate(noise(10, seed=1))]
    tonight = point(10, 60_000 * 3)
    cell = CellInput("cell", "spec", tonight.started_at, [row(tonight)], {(THREAD, FIGURE): past})
    first = judge([cell], P99, {}, "2026-01-11T02:16:00+00:00")
    again = judge([CellInput(**{**cell.__dict__, "recorded": first.change_points})], P99, {}, "2026-01-11T02:16:00+00:00")
    assert [f.verdict for f in first.figures] == [f.verdict for f in again.figures] == [Verdict.REGRESSION]


def test_the_nights_after_a_reported_change_list_it_among_the_regressions_and_changes_not_only_in_every_figure():
    """Night N+1 of a lasting regression passes (it was reported on night N): the section's table of regressions and
    changes still shows it continued, not only the folded table of every figure."""
    from runner.history.section import render

    values = noise(20, seed=7) + [v * 4 for v in noise(2, seed=8)]
    past = [point(n, v) for n, v in enumerate(values[:-1])]
    reported = judge(
        [CellInput("cell", "spec", past[-1].started_at, [row(past[-1])], {(THREAD, FIGURE): past[:-1]})], P99, {}, past[-1].started_at
    )
    tonight = point(21, values[-1])
    cell = CellInput("cell", "spec", tonight.started_at, [row(tonight)], {(THREAD, FIGURE): past}, recorded=reported.change_points)
    verdict = judge([cell], P99, {}, tonight.started_at)
    assert [f.verdict for f in verdict.figures] == [Verdict.CONTINUING]
    text = str(render(verdict, "history.sqlite"))
    changes = text.split("### Regressions and changes", 1)[1].split("<details>", 1)[0] if "### Regressions and changes" in text else ""
    assert "continuing a change" in changes, text


def test_a_fivefold_p99_on_the_sixth_night_is_a_regression_among_twenty_calm_figures():
    """Five calm nights (p99 62 to 64 µs), then one thread's p99 ×5 while 20 others stay calm.  The range's tails had the
    MAD's degrees of freedom, round(0.37 × 4) = 1 (Cauchy's): p = 0.005 for a jump of 70 spreads, 0.1 after Holm over 21
    figures, so no jump at all was a regression before a history had a dozen nights, nor on the five after each change."""
    draw = random.Random(5)
    past: dict[tuple[str, str], list[Point]] = {}
    rows = []
    for t in range(21):
        thread = f"t{t}"
        past[(thread, FIGURE)] = [point(n, 63_000 * math.exp(draw.gauss(0, 0.01)), half=0.025) for n in range(5)]
        tonight = point(5, 63_000 * (5 if t == 0 else math.exp(draw.gauss(0, 0.01))), half=0.025)
        rows.append(FigureRow(thread, FIGURE, tonight.value, tonight.samples, tonight.low, tonight.high))
    verdict = judge([CellInput("cell", "spec", stamp(5), rows, past)], P99, {}, stamp(5))
    assert [(f.thread, f.verdict) for f in verdict.figures if f.verdict != Verdict.WITHIN] == [("t0", Verdict.REGRESSION)]
