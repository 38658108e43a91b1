"""A night judged against its figures' own past nights on the same host and cell spec.  Pure: no I/O.

One baseline night cannot say what is normal for a host; its past nights can.  For each figure with
a threshold (the comparison's, `--threshold` included), its series of nights is read since the last
change of level, and the new night is a regression only when all three hold:

- it is beyond the figure's threshold from the nights' median (the user's practical limit);
- it is outside what the nights vary by: their median and MAD (robust: one wild night does not widen
  the range for good), taken on a log scale for durations and counts, whose night-to-night changes are
  multiplicative, and never narrower than the nights' own sampling error;
- that holds for the new night's own interval too (its nearer end is used, not its value), and its
  p-value survives Holm's adjustment over every figure judged that night (5% family-wise).

Change points: the series is cut where its level changed (`ruptures`' PELT with a robust L1 cost and
a penalty of 3 robust standard deviations per log(nights), from the `history` extra: change-point
detection is no short exact sum, and a well-kept library does it better than a hand-written one).
A step is reported once, on its first night, as a regression (or an improvement) with what changed
in the environment that night; the nights after it are `continuing` that change, not failed again,
until enough of them make the new level the range itself.  A single wild night followed by nights
back at the old level is judged against the old nights.  Without ruptures the range is learnt from
every night since the last reported change, and the judgement says so.

Too few nights since the series began (or since its last change) is `learning`; a figure with no
past is `new`; a figure the past nights had and this night lacks is `missing` (a failure, as in a
comparison); a cell whose spec changed starts a history of its own (its spec hash), said as such.
"""

from __future__ import annotations

import enum
import functools
import itertools
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Optional

from runner import figures as fg
from runner import stats
from runner.histogram import Histogram
from runner.history.environment import changes
from runner.history.night import FigureRow
from runner.history.store import ChangePoint, Point
from runner.report.compare import Threshold

MIN_NIGHTS = 5  # nights of a level before it is a range to judge against
REFERENCE_NIGHTS = 30  # the most nights a range is learnt from (the first of a level, or the latest)
KNOWN_DF = 1_000  # a spread known from the nights' sampling, not estimated from few of them: normal tails
ALPHA = 0.01  # a night's family-wise level: a nightly gate at 5% would still cry wolf every three weeks
WILD = 8.0  # a night this many robust standard deviations from the median is a wild one, left out of the standard deviation
PENALTY = 3.0  # change-point penalty, in robust standard deviations per log(nights)
_OFFSET = {fg.Unit.NS: 1_000.0, fg.Unit.COUNT: 1.0, fg.Unit.PER_CALLBACK: 0.01, fg.Unit.PER_SECOND: 1.0}  # log(value + offset)


class Verdict(str, enum.Enum):
    REGRESSION = "regression"
    BETTER = "better"
    WITHIN = "within history"
    CONTINUING = "continuing a change"
    LEARNING = "learning"
    NEW = "new"
    MISSING = "missing"
    FEW = "not judged"


FAILED = (Verdict.REGRESSION, Verdict.MISSING)


@dataclass(frozen=True)
class FigureVerdict:
    """One figure of one thread of one cell on this night, against its past nights."""

    cell: str
    thread: str
    figure: fg.Figure
    verdict: Verdict
    words: str
    value: Optional[float] = None
    low: Optional[float] = None
    high: Optional[float] = None
    centre: Optional[float] = None  # the past nights' median
    range_low: Optional[float] = None  # what they vary within (95%), in the figure's unit
    range_high: Optional[float] = None
    nights: int = 0  # past nights of the level judged against
    p: Optional[float] = None  # Holm-adjusted
    note: str = ""  # said after the verdict's words (a night back at the level before a change)
    since: str = ""  # the first night of the level judged against, or of the change continued


@dataclass
class NightVerdict:
    """Everything a night's history says: each figure's verdict, change points to record, notes for the whole night."""

    figures: list[FigureVerdict] = field(default_factory=list)
    change_points: list[ChangePoint] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    started_at: str = ""

    @property
    def regressions(self) -> int:
        return sum(f.verdict in FAILED for f in self.figures)


@dataclass(frozen=True)
class CellInput:
    """What the judge needs of one cell of the night: its rows, its past series, its history's change points."""

    cell: str
    spec_hash: str
    started_at: str
    rows: Sequence[FigureRow]
    past: Mapping[tuple[str, str], Sequence[Point]]
    recorded: Sequence[ChangePoint] = ()
    new_spec: str = ""  # words when the cell's spec changed: its history starts tonight
    histograms: Mapping[tuple[str, str], Histogram] = field(default_factory=dict)  # (thread, kind): tonight's
    past_histograms: Mapping[tuple[str, str], Histogram] = field(default_factory=dict)  # (thread, kind): the past nights' merged


def offset(fig: fg.Figure, level: Sequence[Point]) -> float:
    """What the log scale adds to a figure's values: its unit's smallest step, or the nights' typical half interval when
    larger (a count of 0 of 10 callbacks is 0 [0, 0.37], and must not read as far from 0.05 as 0.05 is from 5)."""
    halves = sorted((p.high - p.low) / 2 for p in level if p.low is not None and p.high is not None)
    return max(_OFFSET[fig.unit], halves[len(halves) // 2] if halves else 0.0)


def y(fig: fg.Figure, value: float, add: float | None = None) -> float:
    """A figure's value on the scale its nights vary on: log for what cannot fall below zero (plus `add`, the `offset`),
    itself for signed figures."""
    if fig.signed:
        return value / 1_000.0 if fig.unit is fg.Unit.NS else value
    return math.log(max(value, 0.0) + (_OFFSET[fig.unit] if add is None else add))


def from_y(fig: fg.Figure, scaled: float, add: float | None = None) -> float:
    if fig.signed:
        return scaled * 1_000.0 if fig.unit is fg.Unit.NS else scaled
    return max(0.0, math.exp(scaled) - (_OFFSET[fig.unit] if add is None else add))


def level_starts(values: Sequence[float]) -> list[int]:
    """Indexes where the series' level changed (each the first night of a new level); [] without ruptures or changes."""
    if len(values) < 2 * 2:
        return []
    try:
        import numpy as np
        import ruptures
    except ImportError:
        return []
    diffs = sorted(abs(b - a) for a, b in itertools.pairwise(values))
    sigma = 1.4826 * diffs[len(diffs) // 2] / math.sqrt(2)
    if sigma <= 0:
        sigma = max(1e-9, (max(values) - min(values)) / 1e6)
    signal = np.asarray(values, dtype=float).reshape(-1, 1)
    ends = ruptures.Pelt(model="l1", min_size=2, jump=1).fit(signal).predict(pen=PENALTY * sigma * math.log(len(values)))
    return [int(e) for e in ends[:-1]]


def change_point_detection() -> bool:
    try:
        import ruptures  # noqa: F401
    except ImportError:
        return False
    return True


def judge(
    cells: Sequence[CellInput], thresholds: Sequence[Threshold], environments: Mapping[str, Mapping[str, str]], now: str
) -> NightVerdict:
    """Every cell of a night against its past nights; `environments` are the nights' facts by start time (this night's too)."""
    out = NightVerdict(started_at=now)
    pending: list[tuple[int, float | None, float | None]] = []  # (index in out.figures, p worse, p better) to adjust
    judged = [t for t in thresholds if not t.off]
    for cell in cells:
        if cell.new_spec:
            out.notes.append(f"{cell.cell}: {cell.new_spec}")
        rows = {(r.thread, r.figure): r for r in cell.rows}
        threads = list(dict.fromkeys([r.thread for r in cell.rows] + [t for t, _ in cell.past]))
        for thread in threads:
            for th in judged:
                fig = fg.figure(th.figure)
                row, past = rows.get((thread, fig.name)), list(cell.past.get((thread, fig.name), ()))
                if row is None and not past:
                    continue
                verdict, worse, better = _one(cell, thread, fig, th, row, past, environments)
                out.figures.append(verdict)
                if worse is not None or better is not None:
                    pending.append((len(out.figures) - 1, worse, better))
    _adjust(out, pending, cells, environments, now)
    return out


def _one(
    cell: CellInput,
    thread: str,
    fig: fg.Figure,
    th: Threshold,
    row: Optional[FigureRow],
    past: list[Point],
    environments: Mapping[str, Mapping[str, str]],
) -> tuple[FigureVerdict, Optional[float], Optional[float]]:
    """A figure's provisional verdict, with the raw p-values of worse and better when it was tested against a level."""
    base = FigureVerdict(cell.cell, thread, fig, Verdict.LEARNING, "")
    if row is None:
        last = past[-1]
        return _with(base, Verdict.MISSING, f"not measured tonight; the last night had {_num(fig, last.value)}"), None, None
    base = _with(base, Verdict.LEARNING, "", value=row.value, low=row.low, high=row.high)
    if not past:
        return _with(base, Verdict.NEW, "the first night of this figure here"), None, None
    if row.few:
        few = f"too few samples tonight ({row.samples:,} {fig.samples_word})" if row.samples else "too few samples tonight"
        return _with(base, Verdict.FEW, few), None, None
    recorded = sorted(c.started_at for c in cell.recorded if c.thread == thread and c.figure == fig.name)
    past, reported, previous, reported_at = _lasting(fig, past, recorded)
    if reported_at and len(past) - reported < MIN_NIGHTS:  # a change reported on an earlier night, still watched
        changed = f"the change of {_day(reported_at)}"
        before = past[previous:reported][-REFERENCE_NIGHTS:]
        up = past[reported].value > _median([p.value for p in before]) if before else True
        if len(before) >= MIN_NIGHTS and not _beyond(fig, row.value, before, up):
            verdict, worse, better = _ranged(base, fig, th, row, before)
            return _with(verdict, verdict.verdict, "", note=f"back at the level before {changed}"), worse, better
        if len(before) >= MIN_NIGHTS:  # a further change on top of it: from the changed nights, by how the nights before varied
            verdict, worse, better = _ranged(base, fig, th, row, past[reported:], spread_of=before)
            if verdict.verdict in (Verdict.REGRESSION, Verdict.BETTER):
                return _with(verdict, verdict.verdict, "", note=f"beyond {changed}, still continued"), worse, better
        was = _num(fig, _median([p.value for p in before])) if before else "?"
        words = f"continues {changed} (reported then; {was} before it)"
        return _with(base, Verdict.CONTINUING, words, since=reported_at, nights=len(past) - reported), None, None
    accepted = past[reported:]  # the nights since the last reported change: the level a change is measured from
    add = offset(fig, accepted)
    starts = [reported + i for i in level_starts([y(fig, p.value, add) for p in accepted])] if len(accepted) >= 2 * MIN_NIGHTS else []
    level = past[starts[-1] :] if starts else accepted
    if len(level) < MIN_NIGHTS and not starts:
        since = f" since {_day(level[0].started_at)}" if reported else ""
        return _with(base, Verdict.LEARNING, f"learning: {len(level)} of {MIN_NIGHTS} nights needed{since}", nights=len(level)), None, None
    reference = past[reported : starts[0]] if starts else accepted
    reference = reference[:REFERENCE_NIGHTS] if starts else reference[-REFERENCE_NIGHTS:]
    if len(reference) < MIN_NIGHTS:
        reference = accepted[-REFERENCE_NIGHTS:]
    verdict, worse, better = _ranged(base, fig, th, row, reference)
    worse, better = _extreme(fig, cell, thread, worse, better)
    if starts and verdict.verdict in (Verdict.REGRESSION, Verdict.BETTER):  # the level moved since: a change found over nights
        verdict = _with(verdict, verdict.verdict, verdict.words, since=past[starts[-1]].started_at)
    return verdict, worse, better


def _lasting(fig: fg.Figure, past: list[Point], recorded: Sequence[str]) -> tuple[list[Point], int, int, str]:
    """The past nights without the changes that did not last, and where the last one that did (or is still watched) began.

    A change is reported on its first night; the `MIN_NIGHTS - 1` nights after it say whether it was a level or one wild
    night: when most of them are nearer the level before it than the change, it was a wild night, and it is left out of
    the series (kept in the store and in the trend report), so it neither starts a level nor widens the range of the
    nights it sits among.  Returns (nights, index of the first night of the last change kept, index of the first night of
    the level before it, that change's time); 0, 0, "" when no change is kept.
    """
    kept, reported, previous, reported_at = list(past), 0, 0, ""
    for at in recorded:
        i = next((j for j, p in enumerate(kept) if p.started_at >= at), None)
        if i is None or i < reported or (reported_at and i == reported):
            continue  # tonight's own (a shard's judgement, then the merge's), or two on one night
        before = kept[reported:i][-REFERENCE_NIGHTS:]
        after = kept[i + 1 : i + MIN_NIGHTS]
        if len(after) == MIN_NIGHTS - 1 and len(before) >= MIN_NIGHTS:
            add = offset(fig, before)
            was, then = y(fig, _median([p.value for p in before]), add), y(fig, kept[i].value, add)
            back = sum(abs(y(fig, p.value, add) - was) < abs(y(fig, p.value, add) - then) for p in after)
            if 2 * back > len(after):  # most nights after it were nearer the level before than the change: a wild night
                del kept[i]
                continue
        reported, previous, reported_at = i, reported, at
    return kept, reported, previous, reported_at


def _extreme(
    fig: fg.Figure, cell: CellInput, thread: str, worse: Optional[float], better: Optional[float]
) -> tuple[Optional[float], Optional[float]]:
    """A min or a max is one sample of tonight's: it is also tested by how many of tonight's samples lie beyond the past
    nights' pooled extreme (beta-binomial, as a comparison tests one), and must pass both tests (the larger p-value)."""
    from runner.results.estimates import rank_bounds
    from runner.stats import betabinom_sf

    level, kind = fig.level, fig.histogram
    if level not in (0.0, 1.0) or kind is None:
        return worse, better
    now, past = cell.histograms.get((thread, kind)), cell.past_histograms.get((thread, kind))
    if now is None or past is None:
        return worse, better
    m, n = past.count, now.count
    rank = m if level == 1.0 else 1
    low, high = rank_bounds(past, rank)
    above = sum(c for lo, _hi, c in now.buckets if max(lo, now.min) > high)
    below = sum(c for _lo, hi, c in now.buckets if min(hi, now.max) < low)
    p_above = betabinom_sf(above, n, m - rank + 1, rank)
    p_below = betabinom_sf(below, n, rank, m - rank + 1)
    p_worse, p_better = (p_above, p_below) if fig.worse is fg.Worse.HIGHER else (p_below, p_above)
    return (None if worse is None else max(worse, p_worse)), (None if better is None else max(better, p_better))


def _ranged(
    base: FigureVerdict, fig: fg.Figure, th: Threshold, row: FigureRow, level: Sequence[Point], spread_of: Sequence[Point] = ()
) -> tuple[FigureVerdict, Optional[float], Optional[float]]:
    """Tonight against a level of nights: its threshold from their median, and its interval's nearer end against their range.

    `spread_of`: the nights whose variation the range takes, when `level` is too few nights to say (a change of a night or
    two: the nights before it say how much a night varies).
    """
    centre_value = _median([p.value for p in level])
    add = offset(fig, spread_of or level)
    centre, spread, df = _spread(fig, spread_of or level, centre_of=level)
    quantile = _t_quantile(0.975, df)
    low_y, high_y = centre - quantile * spread, centre + quantile * spread
    higher = fig.worse is fg.Worse.HIGHER
    has_interval = row.low is not None and row.high is not None
    worse_edge = y(fig, (row.low if higher else row.high) if has_interval else row.value, add)  # type: ignore[arg-type]
    better_edge = y(fig, (row.high if higher else row.low) if has_interval else row.value, add)  # type: ignore[arg-type]
    sign = 1 if higher else -1
    p_worse = stats.t_sf(sign * (worse_edge - centre) / spread, df)
    p_better = stats.t_sf(-sign * (better_edge - centre) / spread, df)
    if th.exceeded(centre_value, row.value):
        verdict = Verdict.REGRESSION
    elif th.exceeded(row.value, centre_value):
        verdict = Verdict.BETTER
    else:
        verdict = Verdict.WITHIN
    out = _with(
        base,
        verdict,
        "",
        centre=centre_value,
        range_low=from_y(fig, low_y, add),
        range_high=from_y(fig, high_y, add),
        nights=len(level),
        since=level[0].started_at,
    )
    return out, p_worse, p_better


def _spread(fig: fg.Figure, level: Sequence[Point], centre_of: Sequence[Point] = ()) -> tuple[float, float, int]:
    """(centre, spread of a new night about it, degrees of freedom) of a level's nights on the judged scale.

    The MAD, made consistent for a normal law and for few nights (k / (k - 0.8), Croux and Rousseeuw's
    correction), never below the nights' own sampling error; a new night varies by that and by the
    centre's own uncertainty, sqrt(1 + 1/k); Student's t for its tails with the k - 1 degrees of freedom of the nights'
    standard deviation: the spread is never below that standard deviation, so the range is at least as wide as normal
    theory's prediction interval for a new night.  (With the MAD's own, 0.37 (k - 1), a history of five nights had
    Cauchy's tails: a p99 ×5 was not a regression among 21 figures.)  Night-to-night figures have heavy
    tails (a calm fortnight, then a night 1.7 times as high, nothing changed): when the nights' standard deviation is
    larger than their MAD says, it is the spread (k - 1 degrees of freedom), so one calm stretch does not make the range
    too narrow to hold the next ordinary wild night.  When the nights vary less than
    their own sampling error says they must, that error is the spread, known rather than estimated (normal tails).
    The standard deviation leaves out wild nights, more than `WILD` robust standard deviations from the median: one night
    ×5 while learning (never judged) made the range three times wider for as long as it was among the nights, and a
    lasting +60% passed.  Ordinary nights of bench/nightly's identical ones lie within 7.

    `centre_of`: the nights whose median is the centre, when not `level`'s (a change of few nights, `_ranged`).
    """
    add = offset(fig, level)
    ys = [y(fig, p.value, add) for p in level]
    k = len(ys)
    centre, mad = stats.median_and_mad(ys)
    robust, sampling = 1.4826 * mad * k / (k - 0.8), _sampling_sd(fig, level)
    trimmed = [v for v in ys if abs(v - centre) <= WILD * robust] if robust > 0 else ys
    classical = statistics.stdev(trimmed) if len(trimmed) > 1 else 0.0
    if centre_of:
        centre, k = _median([y(fig, p.value, add) for p in centre_of]), len(centre_of)
    if max(robust, classical) < sampling:  # the nights vary less than their sampling says they must
        return centre, max(sampling, 1e-9) * math.sqrt(1 + 1 / k), KNOWN_DF
    # tails heavier than the calm nights' MAD says: the spread of every night counts
    return centre, max(robust, classical, 1e-9) * math.sqrt(1 + 1 / k), max(1, len(trimmed) - 1)


@functools.cache
def _t_quantile(p: float, df: int) -> float:
    """The t quantile by bisection on `stats.t_sf` (for the range shown); remembered: a night asks for the same few."""
    low, high = 0.0, 1_000.0
    for _ in range(80):
        mid = (low + high) / 2
        if stats.t_sf(mid, df) > 1 - p:
            low = mid
        else:
            high = mid
    return (low + high) / 2


def _beyond(fig: fg.Figure, value: float, level: Sequence[Point], up: bool) -> bool:
    """Whether a night's value lies beyond the range of `level`'s nights (95%) on the side of a change (`up`: above)."""
    centre, spread, df = _spread(fig, level)
    off = y(fig, value, offset(fig, level)) - centre
    return (off if up else -off) > _t_quantile(0.975, df) * spread


def _sampling_sd(fig: fg.Figure, level: Sequence[Point]) -> float:
    """The nights' typical sampling error on the judged scale: half their intervals' width over 1.96, median of them."""
    add = offset(fig, level)
    widths = [(y(fig, p.high, add) - y(fig, p.low, add)) / 2 / 1.96 for p in level if p.low is not None and p.high is not None]
    return _median(widths) if widths else 0.0


def _adjust(
    out: NightVerdict,
    pending: list[tuple[int, Optional[float], Optional[float]]],
    cells: Sequence[CellInput],
    environments: Mapping[str, Mapping[str, str]],
    now: str,
) -> None:
    """Holm over the night's tested figures; a change past its threshold that the nights' range explains is within it."""
    tested = len(pending)
    worse = stats.holm([w for _, w, _ in pending], ALPHA)
    better = stats.holm([b for _, _, b in pending], ALPHA)
    by_cell = {c.cell: c for c in cells}
    family = f"Holm, {tested} figure{'s' if tested != 1 else ''}"
    for (i, _w, _b), p_w, p_b in zip(pending, worse, better):
        f = out.figures[i]
        if f.verdict not in (Verdict.REGRESSION, Verdict.BETTER):
            out.figures[i] = _with(f, f.verdict, f.words, p=p_w)
            continue
        p = p_w if f.verdict == Verdict.REGRESSION else p_b
        shown = _shown(f)
        nights = f"the {f.nights} nights' range [{_num(f.figure, f.range_low)}, {_num(f.figure, f.range_high)}]"
        if p is None or p > ALPHA:
            why = f"{shown}: past its threshold, but within what {nights} and its sampling allow (p = {_p(p)}, {family})"
            out.figures[i] = _with(f, Verdict.WITHIN, why, p=p)
            continue
        cell = by_cell[f.cell]
        env = _environment_change(environments, now, cell)
        word = "regression" if f.verdict == Verdict.REGRESSION else "better"
        why = f"{word}: {shown}, outside {nights} (p = {_p(p)}, {family})" + (f"; changed tonight: {'; '.join(env)}" if env else "")
        out.figures[i] = _with(f, f.verdict, why, p=p)
        out.change_points.append(ChangePoint(f.cell, cell.spec_hash, f.thread, f.figure.name, now, now, why))
    for i, f in enumerate(out.figures):
        if f.verdict == Verdict.WITHIN and not f.words:
            f = out.figures[i] = _with(f, f.verdict, f"{_shown(f)}: within its threshold of the {f.nights} nights' median")
        if f.note:
            out.figures[i] = _with(f, f.verdict, f"{f.words}; {f.note}")


def _environment_change(environments: Mapping[str, Mapping[str, str]], now: str, cell: CellInput) -> list[str]:
    """What changed in the environment from the night before this one (of this cell's history) to this one."""
    before = [at for at in environments if at < now]
    if not before or now not in environments:
        return []
    return changes(environments[max(before)], environments[now])


def _shown(f: FigureVerdict) -> str:
    """`p99 57 µs → 451 µs [430, 470]`: the nights' median, then tonight with its interval."""
    name = f.figure.name.rsplit(".", 1)[-1] if "." in f.figure.name else f.figure.name
    interval = f" [{_num(f.figure, f.low)}, {_num(f.figure, f.high)}]" if f.low is not None and f.high is not None else ""
    return f"{name} {_num(f.figure, f.centre)} → {_num(f.figure, f.value)}{interval}"


def _num(fig: fg.Figure, value: Optional[float]) -> str:
    from runner.report.fmt import fmt_figure

    return "–" if value is None else fmt_figure(value if not fig.is_duration else round(value), fig.unit)


def _p(p: Optional[float]) -> str:
    if p is None:
        return "–"
    return "< 1e-300" if p < 1e-300 else f"{p:.2g}"


def _day(stamp: str) -> str:
    return stamp[:16].replace("T", " ")


def _median(values: Sequence[float]) -> float:
    ordered = sorted(values)
    n = len(ordered)
    return ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2


def _with(f: FigureVerdict, verdict: Verdict, words: str, **changes_: object) -> FigureVerdict:
    from dataclasses import replace

    return replace(f, verdict=verdict, words=words, **changes_)  # type: ignore[arg-type]
