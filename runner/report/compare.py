"""Compare a run with a baseline: align cells by id, check each figure against a threshold.  Pure, no I/O.

A figure regresses when it grows past its threshold: relative (`+20%` of the
baseline), absolute (`+0.5` switches, `+10us`), or both (then it must exceed
both, so a 3 µs wobble on a 10 µs baseline is not a 30% regression).  A figure
the baseline measured and this run did not (its thread gone, too) is a regression:
what it would have shown is unknown.  Repeated cells are compared by their median.
Cells whose resolved scenario differs are not comparable: the comparison is refused,
naming each differing setting.  What else differs between the runs (another version
of the scenario file or of its expectations, another host, a trace that lost events:
`run_differences`) is said instead of a ✅, and figures taken from a trace that lost
events are not compared.

Every figure of the registry (runner/figures.py) can be compared; the registry's
default thresholds are the ones checked unless told otherwise.  Values and absolute
thresholds are in the figure's unit: integer ns for durations.

A figure past its threshold regresses only when the change is also beyond what sampling
explains: each figure is an estimate with an interval (runner/results/estimates.py: an
order-statistic interval for a quantile, exact binomial and Poisson intervals for counts, a
standard error for a mean), and the change is tested exactly against both runs' samples.  The
comparison tests hundreds of figures at once, so the p-values are adjusted by Holm's step-down
over every figure tested, keeping the chance that any verdict of the comparison is a false
regression at most 5% (`stats.ALPHA`) under the tests' model: callbacks independent samples of
one unchanged host.  Real runs are overdispersed (one hiccup delays several callbacks; a host's
state differs between nights), so identical nights are still called regressions now and then
(6 of 19 on the 2-CPU development VM, from 18 of 19 before intervals); the report says so and
points to `--history` (runner/history/judge.py), which learns each figure's between-night
variation and called none of 15.  A figure past its threshold that sampling explains is
`within noise`; one whose sample is too small to be judged (a p99 of 20 callbacks) is `not judged`,
saying how many samples it needs and how long a run gives them.  A figure with no sampling error
to speak of (a total, a count the period fixes), or whose sample the results do not hold (files
of an older runner keep no histograms), is judged by its threshold alone, and says so.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from runner import figures as fg
from runner import stats, units
from runner.errors import Problem, ScenarioError, UsageError, did_you_mean
from runner.figures import Figure, Number
from runner.report.fmt import fmt_figure
from runner.results.document import CallbackResult, CellResult, RunDocument, Status, ThreadResult
from runner.results.files import show_value
from runner.results.merge import incomplete

if TYPE_CHECKING:
    from runner.results.estimates import Estimate


@dataclass(frozen=True)
class Threshold:
    """How much a figure may grow over its baseline before it counts as a regression."""

    figure: str
    relative: float | None = None  # 0.2 is +20%
    absolute: Number | None = None  # in the figure's unit (ns for durations)

    @property
    def off(self) -> bool:
        """`FIGURE=off`: the figure is shown beside its baseline, never judged."""
        return self.relative is None and self.absolute is None

    def exceeded(self, base: float, new: float) -> bool:
        """Whether `new` is worse than `base` by more than the threshold (worse: lower, for figures like slack)."""
        delta = new - base
        if fg.figure(self.figure).worse is fg.Worse.LOWER:
            delta = -delta
        if self.relative is None and self.absolute is None:
            return False
        return (self.relative is None or delta > self.relative * abs(base)) and (self.absolute is None or delta > self.absolute)

    def describe(self) -> str:
        fig = fg.figure(self.figure)
        sign = "\u2212" if fig.worse is fg.Worse.LOWER else "+"
        parts = []
        if self.relative is not None:
            parts.append(f"{sign}{self.relative * 100:g}%")
        if self.absolute is not None:
            parts.append(f"{sign}{fmt_figure(self.absolute, fig.unit)}")
        return " and ".join(parts) if parts else "off"


DEFAULT_THRESHOLDS: tuple[Threshold, ...] = tuple(Threshold(name, t.relative, t.absolute) for name, t in fg.default_thresholds().items())


def parse_threshold(text: str) -> Threshold:
    """`latency.p99=+20%`, `latency.p99=+20%,+10us` (10_000 ns), `involuntary.per_callback_mean=+0.5`, `latency.max=off`."""
    name, sep, spec = text.partition("=")
    name = name.strip()
    if not sep:
        raise UsageError(f"runner: --threshold {text!r}: expected FIGURE=LIMIT, e.g. latency.p99=+20%")
    if name not in fg.BY_NAME:
        raise UsageError(f"runner: --threshold: unknown figure {name!r}{did_you_mean(name, fg.BY_NAME)}; known: {', '.join(fg.BY_NAME)}")
    if spec.strip() == "off":
        return Threshold(name)
    duration = fg.figure(name).is_duration
    relative: float | None = None
    absolute: Number | None = None
    given: dict[str, str] = {}  # each kind of limit (relative, absolute) as written: a second one would silently win
    for item in spec.split(","):
        part = item.strip().lstrip("+")
        kind = "relative" if part.endswith("%") else "absolute"
        if kind in given:
            raise UsageError(
                f"runner: --threshold {text!r}: two {kind} limits, {given[kind]} and {item.strip()}; "
                "expected at most one +N% and one +N" + (" with a unit (+10us)" if duration else "")
            )
        given[kind] = item.strip()
        if fg.figure(name).worse is fg.Worse.LOWER:
            part = part.lstrip("-\u2212")  # slack.min=-10us: worse by 10 us, written either way
        try:
            if part.endswith("%"):
                relative = _finite(part[:-1]) / 100.0
            elif duration:
                absolute = units.parse_duration(part)
            else:
                absolute = _finite(part)
        except (ValueError, units.UnitError):
            raise UsageError(
                f"runner: --threshold {text!r}: {part!r} is not a limit; expected +N% or +N" + (" with a unit (+10us)" if duration else "")
            ) from None
    if (relative is not None and relative < 0) or (absolute is not None and absolute < 0):
        way = "fall" if fg.figure(name).worse is fg.Worse.LOWER else "grow"
        raise UsageError(f"runner: --threshold {text!r}: a limit is how far {name} may {way} before it is a regression; not less than 0")
    return Threshold(name, relative, absolute)


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def thresholds_with(overrides: Iterable[Threshold]) -> list[Threshold]:
    """The defaults, with `overrides` replacing or adding figures; a figure given twice is refused, not the last kept."""
    out = {t.figure: t for t in DEFAULT_THRESHOLDS}
    given: set[str] = set()
    for t in overrides:
        if t.figure in given:
            raise UsageError(
                f"runner: --threshold {t.figure} is given twice, and one would silently win; expected one --threshold per "
                "figure, with both its limits in it if need be (latency.p99=+20%,+10us)"
            )
        given.add(t.figure)
        out[t.figure] = t
    return list(out.values())


def thresholds_for(texts: Iterable[str], baseline: str | None, history: str | None = None, has_history: bool = False) -> list[Threshold]:
    """The --threshold options, which only a comparison or a history reads: refused without --baseline (or --history, for a
    command that has it: `has_history`), never ignored."""
    given = list(texts)
    if given and not baseline and not history:
        either = "--baseline RESULTS or --history FILE" if has_history else "--baseline RESULTS"
        raise UsageError(f"runner: --threshold {given[0]} sets a limit of a comparison; give {either} too")
    return thresholds_with(parse_threshold(t) for t in given)


class Verdict:
    REGRESSION = "regression"
    BETTER = "better"
    SAME = "within threshold"
    OFF = "not checked"  # its threshold is off
    NEW = "no baseline"
    MISSING = "missing"
    ERROR = "run error"  # a cell of this run that could not run or was cut short: an error whatever the baseline was
    UNCOMPARABLE = "not comparable"  # taken from a scheduler trace that lost events, in either run
    NOISE = "within noise"  # past its threshold, but not beyond what sampling explains
    FEW = "not judged"  # too few samples in either run for its interval (a p99 of 20 callbacks)


REGRESSED = (Verdict.REGRESSION, Verdict.MISSING)  # a figure's verdicts that fail the comparison
_OK = (Status.PASSED, Status.DEGRADED)
RUN_ERRORS = (Status.ERROR, Status.INTERRUPTED)  # a cell that could not run, or was cut short


@dataclass(frozen=True)
class FigureChange:
    cell: str
    thread: str
    figure: Figure
    base: Number | None
    new: Number | None
    threshold: Threshold
    verdict: str
    base_estimate: Estimate | None = None  # the baseline's figure with its interval
    new_estimate: Estimate | None = None
    p: float | None = None  # Holm-adjusted p-value of the change in the verdict's direction; None: not tested
    why: str = ""  # the verdict's reason, in words (sampling, too few samples, threshold alone)


@dataclass(frozen=True)
class CellChange:
    cell: str
    base_status: Status | None
    new_status: Status | None
    verdict: str
    note: str = ""

    @property
    def regressed(self) -> bool:
        """Its status got worse: it passed (or ran degraded) in the baseline and its expectations fail now.

        A cell that could not run or was cut short (`Verdict.ERROR`) is not a regression: it is its own
        outcome (`Comparison.statuses`, exit 4 or 130), and its figures, compared on their own, say whether
        anything measured got worse.  Counted as a regression too, `💥 cut short` read `❌ 1 regression`
        though every figure was within its threshold.
        """
        return self.base_status in _OK and self.new_status is not None and self.new_status not in _OK + RUN_ERRORS


@dataclass
class Comparison:
    base: RunDocument
    new: RunDocument
    thresholds: list[Threshold]
    cells: list[CellChange] = field(default_factory=list)
    figures: list[FigureChange] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    incomplete: str = ""  # why the new run is not the whole run it was asked to be (`merge.incomplete`); "" when it is
    threads_gone: list[tuple[str, str]] = field(default_factory=list)  # (cell, thread key) the baseline has and this run lacks
    other_version: str = ""  # how the scenario file the baseline ran differs from this run's, in words; "" when it does not
    differences: list[str] = field(default_factory=list)  # other ways the runs differ, in words: expectations, host, trace lost
    nothing: str = ""  # why there was nothing to compare (`empty_shard`): this run was asked for no cell; "" when it was

    @property
    def alike(self) -> bool:
        """Whether the runs differ in nothing that could explain a change but the scheduling measured (never ✅ when not)."""
        return not self.other_version and not self.differences

    def statuses(self) -> list[Status]:
        """What decides the comparison's exit code beside its regressions (`session.exit_code`): the new run's cells
        that could not run or were cut short (`Verdict.ERROR`), and the new run itself when it is incomplete,
        interrupted (130) when it was asked to stop, an error (4) when it never finished."""
        errors = [c.new_status for c in self.cells if c.new_status in RUN_ERRORS]
        if not self.incomplete:
            return errors
        return errors + [Status.INTERRUPTED if self.new.status == Status.INTERRUPTED.value else Status.ERROR]

    def compared(self) -> list[str]:
        """Cells present in both runs, which are the ones actually compared."""
        return [c.cell for c in self.cells if c.verdict in (Verdict.SAME, Verdict.REGRESSION, Verdict.ERROR)]

    def unmatched(self, verdict: str) -> list[str]:
        """Cells only in the baseline (`Verdict.MISSING`) or only in this run (`Verdict.NEW`)."""
        return [c.cell for c in self.cells if c.verdict == verdict]

    @property
    def regressions(self) -> int:
        """Cells whose expectations fail now and passed in the baseline (`CellChange.regressed`), figures worse than
        their threshold, and figures of the baseline this run lacks.  A cell cut short is a run error, not counted here.

        A figure the baseline measured and this run did not (a thread gone, a figure null or not a number)
        is a regression: what it would have shown is unknown, so it is never a pass.
        """
        return sum(c.regressed for c in self.cells) + sum(f.verdict in REGRESSED for f in self.figures)

    def regressed_cells(self) -> list[str]:
        """The cells with a regression, each once: those whose status regressed first, then those with a figure that did."""
        cells = [c.cell for c in self.cells if c.regressed]
        return list(dict.fromkeys(cells + [f.cell for f in self.figures if f.verdict in REGRESSED]))


def spec_differences(base: Any, new: Any, path: str = "") -> list[str]:
    """Settings that differ between two resolved specs, as `key.path: base -> new`."""
    if isinstance(base, dict) and isinstance(new, dict):
        out = []
        for key in list(base) + [k for k in new if k not in base]:
            sub = f"{path}.{key}" if path else str(key)
            if key not in new:
                out.append(f"{sub}: {show_value(base[key])} in the baseline, absent now")
            elif key not in base:
                out.append(f"{sub}: absent in the baseline, {show_value(new[key])} now")
            else:
                out.extend(spec_differences(base[key], new[key], sub))
        return out
    if isinstance(base, list) and isinstance(new, list) and len(base) == len(new):
        return [d for i, (a, b) in enumerate(zip(base, new)) for d in spec_differences(a, b, f"{path}[{i}]")]
    return [] if base == new else [f"{path}: {show_value(base)} in the baseline, {show_value(new)} now"]


def _groups(doc: RunDocument) -> dict[str, list[CellResult]]:
    out: dict[str, list[CellResult]] = {}
    for cell in doc.cells:
        out.setdefault(cell.id, []).append(cell)
    return out


def check_comparable(base: RunDocument, new: RunDocument, base_name: str, new_name: str) -> None:
    """Refuse cells with the same id but a different resolved scenario, naming what differs."""
    b, n = _groups(base), _groups(new)
    problems = []
    for cell_id in [c for c in n if c in b]:
        old, now = b[cell_id][0], n[cell_id][0]
        was, ran = _asked(base, old), _asked(new, now)
        longer = []
        if was is not None and ran is not None and was != ran:
            longer.append(f"ran for {units.format_duration(was)} in the baseline, {units.format_duration(ran)} now")
        if old.spec_hash == now.spec_hash and not longer:
            continue
        diffs = longer + (spec_differences(old.spec, now.spec) if old.spec_hash != now.spec_hash else [])
        diffs = diffs or ["the resolved scenario (no stored spec to say which setting)"]
        problems.append(
            Problem(
                new_name,
                1,
                1,
                f"cells.{cell_id}",
                f"differs from the baseline ({base_name}): "
                + "; ".join(diffs[:8])
                + (f"; and {len(diffs) - 8} more" if len(diffs) > 8 else ""),
            )
        )
    if problems:
        raise ScenarioError(problems)


def _asked(doc: RunDocument, cell: CellResult) -> int | None:
    """How long the cell was asked to run (ns): the run's --duration, else the scenario's; None when not recorded."""
    if doc.plan.duration_ns is not None:
        return doc.plan.duration_ns
    value = cell.spec.get("duration")
    try:
        return units.parse_duration(value) if isinstance(value, str) else None
    except units.UnitError:
        return None


def _ids(groups: dict[str, list[CellResult]]) -> str:
    if not groups:
        return "no cells"
    shown = ", ".join(list(groups)[:3]) + (f" and {len(groups) - 3} more" if len(groups) > 3 else "")
    return f"{len(groups)} cell{'s' if len(groups) != 1 else ''}: {shown}"


def _median(values: list[Number | None]) -> Number | None:
    """The median of the figures there are; NaN or infinity is no figure (never "within threshold")."""
    present = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(present) if present else None


def empty_shard(doc: RunDocument) -> str:
    """Why `doc` holds no cell though its run is whole: its shard holds none of the matrix (more CI jobs than cells); or "".

    Such a job stays green (README, `--shard`): it is not another scenario's run, and there is
    nothing of it to compare with a baseline, so the comparison says that instead of refusing it.
    """
    if doc.cells or doc.cell_ids or not doc.shard:  # one cut short is incomplete too (`Comparison.incomplete`), said apart
        return ""
    count = len(doc.matrix_cells)
    return f"shard {doc.shard} holds none of the scenario's {count} cell{'s' if count != 1 else ''}"


def check_common(base: RunDocument, new: RunDocument, base_name: str, new_name: str) -> None:
    """Refuse runs without a cell in common: nothing of them could be compared.

    A baseline whose run stopped before its first cell is said to be that, not another scenario's.
    A run whose shard holds no cell (`empty_shard`) has nothing to compare; it is refused only when
    its scenario's matrix (`matrix_cells`) shares no cell with the baseline: another scenario's.
    """
    b, n = _groups(base), _groups(new)
    if empty_shard(new):
        if not b or any(cell_id in b for cell_id in new.matrix_cells):
            return
        n = {cell_id: [] for cell_id in new.matrix_cells}  # said as the scenario's cells
    lacking = incomplete(base)
    if not b and lacking:
        why = f"the baseline {base_name} holds no cell: {lacking}; compare with a baseline whose run finished"
        raise ScenarioError([Problem(base_name, 1, 1, "cells", why)])
    if not any(cell_id in b for cell_id in n):
        why = f"no cell in common with the baseline {base_name} ({_ids(n)} here, {_ids(b)} there); compare runs of the same scenario"
        raise ScenarioError([Problem(new_name, 1, 1, "cells", why)])


def compare(
    base: RunDocument, new: RunDocument, thresholds: list[Threshold] | None = None, base_name: str = "baseline", new_name: str = "new"
) -> Comparison:
    """Align cells by id and compare status and figures; raises ScenarioError when cells are not comparable."""
    check_comparable(base, new, base_name, new_name)
    lacking = incomplete(new)
    if new.cells or not lacking:  # a run stopped before its first cell is incomplete (exit 4 or 130), not another scenario's
        check_common(base, new, base_name, new_name)
    out = Comparison(base, new, list(thresholds if thresholds is not None else DEFAULT_THRESHOLDS), incomplete=lacking)
    out.nothing = empty_shard(new)
    if out.nothing:  # the baseline's cells are other shards', not missing from this one
        return out
    b, n = _groups(base), _groups(new)
    out.other_version, out.differences = run_differences(base, new)
    for cell_id in list(n) + [c for c in b if c not in n]:
        if cell_id not in n:
            out.cells.append(CellChange(cell_id, _status(b[cell_id]), None, Verdict.MISSING, "in the baseline, not run now"))
            continue
        if cell_id not in b:
            out.cells.append(CellChange(cell_id, None, _status(n[cell_id]), Verdict.NEW, "not in the baseline"))
            continue
        old_status, new_status = _status(b[cell_id]), _status(n[cell_id])
        worse = old_status in _OK and new_status not in _OK
        if new_status in RUN_ERRORS:  # whatever the baseline was: an error in both runs is no pass
            verdict = Verdict.ERROR
        else:
            verdict = Verdict.REGRESSION if worse else Verdict.SAME
        note = f"{old_status.value} → {new_status.value}" if worse or verdict == Verdict.ERROR else ""
        out.cells.append(CellChange(cell_id, old_status, new_status, verdict, note))
        out.figures.extend(_figures(cell_id, b[cell_id], n[cell_id], out.thresholds))
        out.threads_gone.extend((cell_id, key) for key in compared_keys(b[cell_id]) if key not in compared_keys(n[cell_id]))
    out.figures = judge(out.figures)
    lossy = list(dict.fromkeys(f.cell for f in out.figures if f.verdict == Verdict.UNCOMPARABLE))
    if lossy:
        names = ", ".join(dict.fromkeys(f.figure.name for f in out.figures if f.verdict == Verdict.UNCOMPARABLE))
        base_lost = sum(_trace_loss(c) for cell_id in lossy for c in b.get(cell_id, []))
        new_lost = sum(_trace_loss(c) for cell_id in lossy for c in n.get(cell_id, []))
        out.differences.append(
            f"The scheduler trace lost events in {_ids({c: [] for c in lossy})} ({new_lost:,} lost or untracked now, "
            f"{base_lost:,} in the baseline): the figures taken from it there ({names}) are not compared."
        )
    return out


def run_differences(base: RunDocument, new: RunDocument) -> tuple[str, list[str]]:
    """How the two runs differ besides what they measured: another version of the scenario file (said apart, first),
    other expectations, another host or kernel.  A hash one of them does not record (an older runner's) is not held
    against it, as merge does.

    Unlike merge, which refuses shards of another version (they must be one run), a comparison is of two runs by
    nature: each cell is compared when its resolved settings agree (`check_comparable` refuses those that do not),
    and the headline says the rest of the difference instead of a ✅.
    """
    a, b = base.plan, new.plan
    version = ""
    if a.scenario_hash and b.scenario_hash and a.scenario_hash != b.scenario_hash:
        version = (
            f"the baseline ran another version of the scenario file (plan.scenario_hash {a.scenario_hash} there, "
            f"{b.scenario_hash} now); only its cells whose resolved settings are the same were compared"
        )
    out = []
    if a.expect_hash and b.expect_hash and a.expect_hash != b.expect_hash:
        out.append(
            f"The cells were judged by other expectations than the baseline's (plan.expect_hash {a.expect_hash} there, "
            f"{b.expect_hash} now): a status may differ for that alone."
        )
    was, now = base.machine, new.machine
    if (was.hostname, was.kernel) != (now.hostname, now.kernel):
        out.append(
            f"The baseline ran on {was.hostname or '?'} (kernel {was.kernel or '?'}), "
            f"this run on {now.hostname or '?'} (kernel {now.kernel or '?'}): figures may differ for that alone."
        )
    return version, out


def _trace_loss(cell: CellResult) -> int:
    """Events the cell's scheduler trace lost or could not attribute (beyond its bounded table of threads)."""
    return cell.trace.lost + cell.trace.untracked if cell.trace is not None else 0


def _status(cells: list[CellResult]) -> Status:
    order = list(Status)
    return min((c.status for c in cells), key=order.index)


def subjects(cell: CellResult) -> list[ThreadResult | CallbackResult]:
    """What a cell's comparison (and history) judges, each by its key: threads with callbacks, a program's threads (the
    figures measured from outside), and the ROS 2 callbacks of its programs (`program: node/symbol`)."""
    return [t for t in cell.threads if t.has_callbacks or t.program] + list(cell.callbacks)


def compared_keys(cells: list[CellResult]) -> list[str]:
    """The keys of the subjects (threads, ROS 2 callbacks) of a cell, all its repeats, whose figures are compared."""
    return list(dict.fromkeys(s.key for c in cells for s in subjects(c)))


def cell_estimate(cells: list[CellResult], key: str, fig: Figure) -> Estimate | None:
    """`fig` of thread `key` over a cell's repeats, with its interval (`estimates.estimate`)."""
    from runner.results.estimates import estimate  # statistics and the exact sums: only when a comparison is made

    pairs = [(t, c.duration_ns) for c in cells for t in subjects(c) if t.key == key]
    return estimate(fig, [t for t, _ in pairs], [d for _, d in pairs])


def _figures(cell_id: str, old: list[CellResult], now: list[CellResult], thresholds: list[Threshold]) -> list[FigureChange]:
    """Each figure of each thread of either run (a thread only the baseline has too: its figures are missing now).

    A figure taken from the scheduler trace is not comparable where the trace lost events in either run:
    it is undercounted by an unknown amount, so neither better nor worse can be told.  The verdicts past a
    threshold are provisional here: `judge` weighs them against sampling, over every figure compared.
    """
    out = []
    lossy = any(_trace_loss(c) for c in old + now)
    for key in dict.fromkeys(compared_keys(now) + compared_keys(old)):
        for th in thresholds:
            fig = fg.figure(th.figure)
            base = _median([fg.value(t.figures, fig) for c in old for t in subjects(c) if t.key == key])
            new = _median([fg.value(t.figures, fig) for c in now for t in subjects(c) if t.key == key])
            if base is None and new is None:
                continue
            if base is None:
                verdict = Verdict.NEW
            elif th.off:  # shown beside its baseline, never judged: not even when this run lacks it
                verdict = Verdict.OFF
            elif new is None:
                verdict = Verdict.MISSING
            elif fig.traced and lossy:
                verdict = Verdict.UNCOMPARABLE
            elif th.exceeded(base, new):
                verdict = Verdict.REGRESSION
            elif th.exceeded(new, base):
                verdict = Verdict.BETTER
            else:
                verdict = Verdict.SAME
            out.append(FigureChange(cell_id, key, fig, base, new, th, verdict, cell_estimate(old, key, fig), cell_estimate(now, key, fig)))
    return out


_JUDGED = (Verdict.REGRESSION, Verdict.BETTER, Verdict.SAME)


def judge(changes: list[FigureChange], alpha: float = stats.ALPHA) -> list[FigureChange]:
    """The figures' verdicts weighed against sampling: a change past its threshold is a regression (or better) only when
    its p-value, adjusted by Holm over every figure tested in the same direction, is at most `alpha`.

    The family is every figure judged whose sampling can be tested, past its threshold or not: testing only those
    past it would choose the hypotheses by the data they are tested on.
    """
    worse = [_p(f, True) for f in changes]
    better = [_p(f, False) for f in changes]
    worse_adjusted, better_adjusted = stats.holm(worse, alpha), stats.holm(better, alpha)
    tested = sum(p is not None for p in worse)
    out = []
    for f, p_worse, p_better in zip(changes, worse_adjusted, better_adjusted):
        out.append(_weighed(f, p_worse, p_better, tested, alpha))
    return out


def _p(f: FigureChange, worse: bool) -> float | None:
    from runner.results.estimates import p_change

    if f.verdict not in _JUDGED or f.base_estimate is None or f.new_estimate is None:
        return None
    return p_change(f.base_estimate, f.new_estimate, worse)


def _weighed(f: FigureChange, p_worse: float | None, p_better: float | None, tested: int, alpha: float) -> FigureChange:
    from dataclasses import replace

    if f.verdict not in _JUDGED:
        return f
    few = [(who, e) for who, e in (("the baseline", f.base_estimate), ("this run", f.new_estimate)) if e is not None and e.few]
    if few:
        if len(few) == 2 and few[0][1].lacking == few[1][1].lacking:
            return replace(f, verdict=Verdict.FEW, why=f"both runs: {few[0][1].lacking}")
        return replace(f, verdict=Verdict.FEW, why="; ".join(f"{who}: {e.lacking}" for who, e in few))
    if f.verdict == Verdict.SAME:
        return replace(f, p=p_worse)
    p = p_worse if f.verdict == Verdict.REGRESSION else p_better
    if p is None:
        lacking = next((e.lacking for e in (f.base_estimate, f.new_estimate) if e is not None and e.lacking), "")
        return replace(f, why=f"by its threshold alone ({lacking or 'a figure without sampling error'})")
    family = f"Holm, {tested} figure{'s' if tested != 1 else ''}"
    if p <= alpha:
        return replace(f, p=p, why=f"beyond its sampling error: p = {_p_text(p)} ({family})")
    return replace(f, verdict=Verdict.NOISE, p=p, why=f"sampling explains it: p = {_p_text(p)} > {alpha:g} ({family})")


def _p_text(p: float) -> str:
    """A p-value in two significant digits: `0.031`, `3.1e-09`, `< 1e-300`."""
    if p < 1e-300:
        return "< 1e-300"
    return f"{p:.2g}"
