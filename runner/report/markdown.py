"""The markdown report of a run: facts, findings, matrix summary, the seed's comparison view, per-cell tables.

Pure: a results document in, markdown out (no file access).  The layout lives in
`templates/report.md.j2`; this module turns results into rows of readable text
(units everywhere, no raw field names) and the template arranges them.  Tables
are GitHub-flavoured markdown from `fmt.pipe_table` (not tabulate, which is too slow
for a 1,000-cell report).
"""

from __future__ import annotations

import re
import shlex
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import jinja2

from runner import figures as fg
from runner import units
from runner.figures import Number
from runner.report import system
from runner.report.fmt import (
    LEFT,
    RIGHT,
    Markdown,
    fmt_bytes,
    fmt_int,
    fmt_mean,
    fmt_ns,
    md_code,
    md_code_block,
    md_text,
    pipe_table,
    samples_words,
)
from runner.report.selection import REPORT_ROWS, lines_shown, ps_rows_shown, threads_shown, verdicts_shown
from runner.results.document import (
    NOT_STARTED,
    Background,
    BackgroundKind,
    CellResult,
    EventResult,
    FoldedThreads,
    PreemptedRun,
    Preemptor,
    ProgramResult,
    RunDocument,
    Status,
    ThreadResult,
    Verdict,
)
from runner.results.pstable import render_ps
from runner.results.threadfigures import ThreadFigures
from runner.scenario.model import Policy
from runner.scenario.plan import Settings

if TYPE_CHECKING:
    from runner.report.compare import Comparison, FigureChange
    from runner.results.estimates import Estimate

MAX_SIDE_BY_SIDE = 12  # cells shown in a thread's across-cells view; beyond that the summary table serves

ICON = {
    Status.PASSED: "✅ passed",
    Status.DEGRADED: "⚠️ degraded",
    Status.FAILED: "❌ failed",
    Status.ERROR: "💥 error",
    Status.INTERRUPTED: "⏸️ interrupted",
}


# ---------------------------------------------------------------- formatting


def policy_label(settings: Settings | None) -> str:
    """`FIFO 80`, `RR 10`, `OTHER`, `OTHER nice -5`, `DEADLINE 2ms/8ms/10ms` (runtime/deadline/period, as the terminal
    says them): how people say a thread's scheduling."""
    if settings is None:
        return "?"
    text = settings.policy.name
    if settings.policy is Policy.DEADLINE:
        text += " " + "/".join(units.format_duration(v) for v in (settings.runtime, settings.deadline, settings.period))
    if settings.policy.is_realtime:
        text += f" {settings.priority}"
    if settings.nice and settings.policy in (Policy.OTHER, Policy.BATCH):
        text += f" nice {settings.nice}"
    return text


def table(headers: Sequence[str], rows: Iterable[Sequence[object]], align: Sequence[str] | None = None) -> Markdown:
    """A GitHub-flavoured markdown table, left-aligned unless told; cells that are not Markdown are escaped by `md_text`."""
    return pipe_table(headers, rows, align or [LEFT] * len(headers))


# ---------------------------------------------------------------- findings


def thread_labels(cells: Sequence[CellResult]) -> dict[str, str]:
    """Each thread's label by key: `process/name (main)`, with `[instance]` only for a process that runs more than once."""
    multi = {t.process for c in cells for t in c.threads if t.instance > 0}
    return {t.key: t.label(show_instance=t.process in multi) for c in cells for t in c.threads}


def figure(t: ThreadResult, name: str) -> Number | None:
    """A thread's figure by its registry name (`latency.p99`), None where it has none."""
    return fg.value(t.figures, fg.figure(name))


def first_runs(cells: Sequence[CellResult]) -> list[CellResult]:
    """Each cell once (its first run), in order."""
    out: dict[str, CellResult] = {}
    for cell in cells:
        out.setdefault(cell.id, cell)
    return list(out.values())


def callback_threads(cell: CellResult) -> list[ThreadResult]:
    """The threads that run callbacks: periodic ones, and a chain's stages released by resumes."""
    return [t for t in cell.threads if t.has_callbacks]


def _switches(f: ThreadFigures) -> str:
    """`0 involuntary switches in 98 callbacks` or `8.94 involuntary switches per callback (98 of 99 ... preempted)`."""
    inv = f.involuntary
    if not inv.total:
        return f"0 involuntary switches in {f.callbacks:,} callbacks"
    return (
        f"{fmt_mean(inv.per_callback_mean)} involuntary switches per callback "
        f"({fmt_int(inv.callbacks_with_any)} of {f.callbacks:,} callbacks preempted)"
    )


def held_label(t: ThreadResult) -> str:
    """The policy a thread's callbacks ran at, as the kernel reported it: `FIFO 80`, or by phase `OTHER, then FIFO 50`."""
    held = t.callback_settings()
    return ", then ".join(policy_label(s) for s in held) if held else "?"


def thread_finding(t: ThreadResult, label: str) -> Markdown:
    """One sentence of what a periodic thread measured, e.g. `at FIFO 80: 0 involuntary switches in 98 callbacks`."""
    f = t.figures
    lat = figure(t, "latency.p99")
    where = f"**{md_text(label)}** at {held_label(t)}"
    if not f.callbacks:
        return Markdown(f"{where}: no callback ran")
    what = _switches(f)
    faults = f.faults.minor_after_first
    tail = f", {faults:,} minor page faults after the first callback" if faults else ""
    return Markdown(f"{where}: {_overload(f)}{what}, wake-up latency p99 {fmt_ns(lat)}{tail}")


def _overload(f: ThreadFigures) -> str:
    """`⚠️ could not keep up (missed 48 of 61 releases, 12 overruns, worst slack −118 ms); ` or nothing when it kept up."""
    if fg.kept_up(f):
        return ""
    parts = []
    if f.missed_releases:
        parts.append(f"missed {f.missed_releases:,} of {f.releases:,} releases")
    if f.overruns:
        parts.append(f"{f.overruns:,} overrun{'s' if f.overruns != 1 else ''}")
    if f.slack_ns is not None:
        parts.append(f"worst slack {fmt_ns(f.slack_ns.min)}")
    return f"⚠️ could not keep up ({', '.join(parts)}); "


def cell_finding(cell: CellResult, labels: dict[str, str]) -> Markdown:
    threads = callback_threads(cell)
    if cell.status is Status.ERROR and not any(t.figures.callbacks for t in threads):
        return Markdown(f"No measurement: {md_text(cell.reason or 'the cell did not run')}.")
    if not threads:
        return Markdown("No thread runs periodic work, so there are no per-callback figures; see the switch counts below.")
    return Markdown("; ".join(thread_finding(t, labels[t.key]) for t in threads) + ".")


def matrix_finding(cells: Sequence[CellResult], labels: dict[str, str]) -> list[Markdown]:
    """Per periodic thread seen in several cells, one sentence: its figures per policy, most preempted first.

    e.g. `at OTHER 8.94 involuntary switches per callback (98 of 99 callbacks preempted), wake-up p99 7.43 ms;
    at FIFO 10, 80: 0 per callback, p99 96.3 µs – 117 µs`.
    """
    out: list[Markdown] = []
    for key, entries in _by_thread(cells).items():
        if len(entries) < 2:
            continue
        groups: dict[str, list[ThreadResult]] = {}
        for _, t in entries:
            held = t.callback_settings()
            groups.setdefault(held[0].policy.name if len(held) == 1 else held_label(t), []).append(t)
        ranked = sorted(groups.items(), key=lambda kv: -max(t.figures.involuntary.per_callback_mean or 0.0 for t in kv[1]))
        out.append(Markdown(f"**{md_text(labels[key])}**: " + "; ".join(_group_finding(name, ts) for name, ts in ranked) + "."))
        faults = [t.figures.faults.minor_after_first for _, t in entries]
        if len(set(faults)) > 1:
            out.append(
                Markdown(
                    f"**{md_text(labels[key])}**, minor page faults after the first callback: "
                    + "; ".join(f"{fmt_int(n)} ({md_text(cell.id)})" for (cell, _), n in zip(entries, faults))
                    + "."
                )
            )
    return out


def _span(values: list[Number | None], fmt: Any) -> str:
    present = sorted(v for v in values if v is not None)
    if not present:
        return "–"
    low, high = fmt(present[0]), fmt(present[-1])
    return low if low == high else f"{low} – {high}"


def _group_finding(policy: str, threads: list[ThreadResult]) -> str:
    """One policy's cells of a thread: its switches and wake-up p99, as a single figure or a range."""
    single = [held[0] for held in (t.callback_settings() for t in threads) if len(held) == 1]  # a thread held one policy
    prios = sorted({s.priority for s in single if s.policy.is_realtime})
    where = f"at {policy}" + (f" {', '.join(map(str, prios))}" if prios else "")
    if len(threads) > 1 and not prios:
        where += f" ({len(threads)} cells)"
    p99 = _span([figure(t, "latency.p99") for t in threads], fmt_ns)
    if len(threads) == 1:
        f = threads[0].figures
        return f"{where}: no callback ran" if not f.callbacks else f"{where}: {_overload(f)}{_switches(f)}, wake-up p99 {p99}"
    inv_span = _span([t.figures.involuntary.per_callback_mean for t in threads], fmt_mean)
    missed = [t.figures.missed_releases for t in threads if not fg.kept_up(t.figures)]
    behind = ""
    if missed:
        slack = _span([figure(t, "slack.min") for t in threads if not fg.kept_up(t.figures)], fmt_ns)
        missed_span = _span(list(missed), fmt_int)
        worst = f", worst slack {slack}" if slack != "–" else ""
        behind = f"⚠️ {len(missed)} of {len(threads)} cells could not keep up ({missed_span} releases missed{worst}); "
    return f"{where}: {behind}{inv_span} involuntary switches per callback, wake-up p99 {p99}"


def _by_thread(cells: Sequence[CellResult]) -> dict[str, list[tuple[CellResult, ThreadResult]]]:
    out: dict[str, list[tuple[CellResult, ThreadResult]]] = {}
    for cell in cells:
        for t in callback_threads(cell):
            out.setdefault(t.key, []).append((cell, t))
    return out


# ---------------------------------------------------------------- tables


@dataclass(frozen=True)
class Table:
    """A table of text cells (escaped when rendered) and Markdown cells (shown as they are), aligned per column."""

    headers: list[str]
    rows: list[list[str]]
    align: list[str] | None = None

    def render(self) -> Markdown:
        return table(self.headers, self.rows, self.align)


Rows = Sequence[tuple[str, ThreadResult]]  # (what the row is: a thread's label, or a cell's id; the thread)


def _numbers(first: str, headers: Sequence[str], rows: list[list[str]]) -> Table:
    """A table whose first column names the row and whose other columns are numbers (right-aligned)."""
    return Table([first, *headers], rows, [LEFT] + [RIGHT] * len(headers))


def threads_table(rows: Rows, first: str = "Thread") -> Table:
    """Per thread (or per cell): the scheduling the kernel reported, the CPUs it ran on, its callbacks."""
    out = [
        [
            label + ("" if t.figures.complete else " (did not finish)"),
            policy_label(t.applied) + (" ⚠️" if t.degraded else ""),
            units.format_cpus(t.figures.cpus_seen) or "–",
            fmt_int(t.figures.callbacks) if t.has_callbacks else "–",
        ]
        for label, t in rows
    ]
    return Table([first, "Scheduling", "CPUs", "Callbacks"], out, [LEFT, LEFT, LEFT, RIGHT])


def switches_table(rows: Rows, first: str = "Thread") -> Table:
    """Per thread: involuntary switches inside its callbacks (periodic threads), and both kinds over the whole run."""
    per_cb = fg.scale(fg.Unit.PER_CALLBACK)
    out = [
        [
            label,
            per_cb.number(t.figures.involuntary.per_callback_mean),
            fmt_int(t.figures.involuntary.per_callback_max),
            fmt_int(t.figures.involuntary.callbacks_with_any),
            fmt_int(t.figures.involuntary.total),
            fmt_int(t.figures.voluntary.total),
        ]
        for label, t in rows
    ]
    headers = [
        "Involuntary / callback (mean)",
        "Involuntary / callback (max)",
        "Callbacks preempted",
        "Involuntary (total)",
        "Voluntary (total)",
    ]
    return _numbers(first, headers, out)


def faults_table(rows: Rows, first: str = "Thread") -> Table:
    """Per thread: minor page faults in the first callback and the later ones (periodic threads), and over the whole run."""
    out = [
        [
            label,
            fmt_int(t.figures.faults.minor_first_callback),
            fmt_int(t.figures.faults.minor_after_first),
            fmt_int(t.figures.faults.minor),
            fmt_int(t.figures.faults.major),
        ]
        for label, t in rows
    ]
    return _numbers(first, ["Minor, 1st callback", "Minor, later callbacks", "Minor (total)", "Major (total)"], out)


def _measured_outside(t: ThreadResult) -> bool:
    return t.program or t.figures.wakeup_ns is not None or t.figures.preemptions is not None


def outside_table(rows: Rows, first: str = "Thread") -> Table | None:
    """Per thread measured from outside (a program's, or any the scheduler trace followed): rates, CPU time, trace figures.

    The trace's latency is from each sched_waking to the switch onto a CPU, beside how many wake-ups it stands on
    (a p99 of 1 wake-up is that wake-up); it is not the release-to-run latency of `latency_table`.
    """
    chosen = [(label, t) for label, t in rows if _measured_outside(t)]
    if not chosen:
        return None
    f = [t.figures for _, t in chosen]
    rate = fg.scale(fg.Unit.PER_SECOND)
    cpu = fg.scale(fg.Unit.NS, [x.cpu_time_ns for x in f])
    after = fg.scale(fg.Unit.NS, [t.rule_after_ns for _, t in chosen])
    wake = fg.scale(fg.Unit.NS, [w.max for x in f if (w := x.wakeup_ns) is not None])
    out = [
        [
            label,
            md_code(t.rule, in_table=True) if t.rule else "–",
            after.number(t.rule_after_ns),
            rate.number(t.figures.involuntary.per_second),
            rate.number(t.figures.voluntary.per_second),
            cpu.number(t.figures.cpu_time_ns),
            fmt_int(t.figures.migrations),
            fmt_int(t.figures.preemptions),
            fmt_int(t.figures.wakeup_ns.count if t.figures.wakeup_ns else None),
            wake.number(t.figures.wakeup_ns.p50 if t.figures.wakeup_ns else None),
            wake.number(t.figures.wakeup_ns.p99 if t.figures.wakeup_ns else None),
            wake.number(t.figures.wakeup_ns.max if t.figures.wakeup_ns else None),
        ]
        for label, t in chosen
    ]
    headers = [
        "Rule",
        after.header("Rule applied after"),
        "Involuntary / s",
        "Voluntary / s",
        cpu.header("CPU time"),
        "Migrations",
        "Preemptions",
        "Wake-ups traced",
        wake.header("Waking to running p50"),
        wake.header("p99"),
        wake.header("max"),
    ]
    return Table([first, *headers], out, [LEFT, LEFT] + [RIGHT] * (len(headers) - 1))


def _preemptor(p: Preemptor) -> str:
    """`790 by hog[1234] (TS)`: the count, the task's name and TID, its class and RT priority as ps writes them."""
    prio = f" {p.rtprio}" if p.rtprio is not None else ""
    who = p.comm if not p.tid else f"{p.comm}[{p.tid}]"
    return f"{p.count:,} by {who} ({p.cls}{prio})"


def preemption_lines(rows: Rows) -> list[str]:
    """`talker/ctl_loop #1: preempted 812 times: 790 by hog0-1 (TS), 22 by ksoftirqd/1 (TS)`, for every thread the trace followed.

    A periodic thread of the runner's own says first how many of its callbacks were
    preempted (`111 of 159 callbacks preempted, preempted 146 times: ...`): it runs only in
    its callbacks, so who preempted it is who made those callbacks late.
    """
    out = []
    for label, t in rows:
        n = t.figures.preemptions
        if n is None:
            continue
        inv = t.figures.involuntary
        hit = inv.callbacks_with_any if t.has_callbacks else None
        during = f"{hit:,} of {t.figures.callbacks:,} callbacks preempted, " if hit else ""
        if not n:
            line = f"{label}: never preempted"
        else:
            named = ", ".join(_preemptor(p) for p in t.preempted_by)
            others = n - sum(p.count for p in t.preempted_by)
            rest = f", {others:,} by others" if others > 0 else ""
            line = f"{label}: {during}preempted {n:,} time{'s' if n != 1 else ''}: {named}{rest}"
        if t.late_wakeups:
            behind = ", ".join(_preemptor(p).replace(" by ", " behind ", 1) for p in t.late_wakeups_by)
            line += f"; its {t.late_wakeups:,} worst wake-up{'s' if t.late_wakeups != 1 else ''} beyond p99 waited: {behind}"
        if t.preempted_runs:
            what = "callbacks" if t.has_callbacks else "runs"
            worst = "; ".join(_run(r) for r in t.preempted_runs[:RUNS_SHOWN])
            line += f"; most preempted {what}: {worst}"
        out.append(line)
    return out


RUNS_SHOWN = 3  # of a thread's most preempted runs, in its preemption line (results.json keeps 16)


def _run(r: PreemptedRun) -> str:
    """`at 0.100 s: 48.0 of 88.0 ms preempted, 9 times, 5 by hog[22272] (TS) for 32.0 ms`."""
    sc = fg.scale(fg.Unit.NS, (r.preempted_ns, r.wall_ns))
    times = f"{r.preemptions:,} time{'s' if r.preemptions != 1 else ''}"
    held = f", {_preemptor(r.by)} for {sc.number(r.by_ns)} {sc.unit}" if r.by_ns else ""
    return f"at {r.at_ns / 1e9:.3f} s: {sc.number(r.preempted_ns)} of {sc.number(r.wall_ns)} {sc.unit} preempted, {times}{held}"


def trace_line(cell: CellResult) -> str | None:
    """What the scheduler trace was in this cell, or why there was none."""
    info = cell.trace
    if info is None:
        return None
    if not info.enabled:
        return (
            f"Scheduler trace: not taken ({info.reason}); wake-up latency per wake-up and who preempted whom are missing, "
            "the /proc figures are complete."
        )
    lost = f"{info.lost:,} lost" if info.lost else "none lost"
    cost = f"{info.reader_cpu_ns / 1e6:.1f} ms of CPU for the reader"
    unseen = (
        f" {info.unseen_switch_ins:,} wake-ups unmeasured: the kernel traced no switch onto the CPU they ran on"
        " (some kernels trace none out of an idle CPU); the wake-ups traced are fewer, never wrong."
        if info.unseen_switch_ins
        else ""
    )
    return f"Scheduler trace: {info.events:,} events ({lost}), {cost}.{unseen}"


def _ended(p: ProgramResult) -> str:
    if p.failure:  # its own failure, or its cell's, which stopped before the program's start (said in words already)
        return p.failure if p.failure.startswith(NOT_STARTED) else f"could not start: {p.failure}"
    if p.stopped:
        how = "stopped with SIGTERM" if p.stopped == "SIGTERM" else "killed with SIGKILL after ignoring SIGTERM"
        return f"{how} at the end of the cell"
    if p.exit_signal == "SIGKILL" and p.oom_kills:
        return "killed by the OOM killer (SIGKILL) at its memory_max"
    if p.exit_signal:
        return f"killed by {p.exit_signal}"
    return f"exited with code {p.exit_code}" if p.exit_code is not None else "still running when the cell ended"


GAPS_SHOWN = 3  # threads of a program whose settings history left changes out, named in its line; the rest are counted


def _instant(ns: int) -> str:
    """An instant of the cell, from its start gate, in seconds: `2.10 s`."""
    return f"{ns / 1e9:.2f} s"


def _folded_words(f: FoldedThreads) -> Markdown:
    """`; 12,000 threads that exited once it had 4,096 thread records were counted together, not kept one by one (...)`."""
    span = f"between {_instant(f.first_seen_ns)} and {_instant(f.last_gone_ns)}"
    if f.measured:
        cpu = f", {units.human_duration(f.cpu_time_ns)} of CPU time"
        moved = f", {f.migrations:,} migrations" if f.migrations is not None else ""
        sums = (
            f"the {f.measured:,} measured: {f.involuntary:,} involuntary and {f.voluntary:,} voluntary switches, "
            f"{f.minor_faults:,} minor and {f.major_faults:,} major faults{cpu}{moved}"
        )
    else:
        sums = "none of them was read in the measured window"
    out: str = md_text(
        f"; {f.count:,} thread{'s' if f.count != 1 else ''} that exited once it had {f.cap:,} thread records "
        f"{'were' if f.count != 1 else 'was'} counted together, not kept one by one ({span}; {sums})"
    )
    for r in f.rules:
        missed = f", {r.not_as_asked:,} not as asked" if r.not_as_asked else ""
        out += f"{md_text('; rule')} {md_code(r.rule)} {md_text(f'was applied to {r.applied:,} of them{missed}')}"
    return Markdown(out)


def _history_words(p: ProgramResult, threads: list[ThreadResult]) -> Markdown:
    """`; talker/rtprog (main): its settings history keeps its first 16 and last 48 snapshots; 1,234 further changes ... not kept`."""
    gaps = [(t, gap) for t in threads if t.program and t.process == p.name and (gap := t.history_not_kept) is not None]
    out = ""
    for t, gap in gaps[:GAPS_SHOWN]:
        kept = f"its settings history keeps its first {gap.kept_first} and last {gap.kept_last} snapshots"
        span = f"between {_instant(gap.from_ns)} and {_instant(gap.to_ns)}"
        out += md_text(f"; {t.label(False)}: {kept}; {gap.count:,} further change{'s' if gap.count != 1 else ''} {span} not kept")
    rest = gaps[GAPS_SHOWN:]
    if rest:
        changes = sum(gap.count for _, gap in rest)
        out += md_text(f"; {len(rest):,} more threads' histories the same way: {changes:,} further changes not kept")
    return Markdown(out)


def _stream(file: str, written: int | None, dropped: int | None) -> str:
    """A program's output file, with how much of what it wrote the file holds when not all (its output_limit)."""
    if not dropped or written is None:
        return md_code(file)
    return f"{md_code(file)} (the first {fmt_bytes(written - dropped)} of {fmt_bytes(written)})"


def program_lines(cell: CellResult) -> list[Markdown]:
    """Per program: its command, the settings it was started with, how it ended, where its output is.

    What the runner counted without keeping (threads folded beyond its cap, settings
    changes a thread's history left out) is said here, with the span it covers.
    """
    out = []
    for p in cell.programs:
        pid = f" (pid {p.pid})" if p.pid else ""
        ran = f" after {units.human_duration(p.ran_ns)}" if p.ran_ns is not None and not p.stopped else ""
        output = f"; output: {_stream(p.stdout, p.stdout_bytes, p.stdout_dropped)}, {_stream(p.stderr, p.stderr_bytes, p.stderr_dropped)}"
        output = output if p.stdout else ""
        memory = ""
        if p.memory_max is not None:
            peak = f", peak {fmt_bytes(p.memory_peak)}" if p.memory_peak is not None else ""
            kills = f", {p.oom_kills} OOM kill{'s' if p.oom_kills != 1 else ''}" if p.oom_kills else ""
            memory = f"; memory_max {fmt_bytes(p.memory_max)}{peak}{kills}"
        listed = ""
        if p.threads_seen_by == "listing":
            why = f" ({p.threads_seen_note})" if p.threads_seen_note else ""
            listed = f"; its threads were found by listing /proc every 2 ms, not by the kernel's process events{why}"
        elif p.threads_seen_note:
            listed = f"; {p.threads_seen_note}"
        folded = _folded_words(p.threads_folded) if p.threads_folded is not None else ""
        out.append(
            Markdown(
                f"{md_text(p.name)}: {md_code(shlex.join(p.argv))}{pid}, started as {md_text(policy_label(p.requested))}; "
                f"{md_text(_ended(p))}{ran}{md_text(memory)}{output}{md_text(listed)}{folded}{_history_words(p, cell.threads)}"
            )
        )
    return out


LATENCY_COLUMNS = (
    ("p50", "latency.p50"),
    ("p99", "latency.p99"),
    ("max", "latency.max"),
    ("mean", "latency.mean"),
    ("std dev", "latency.stddev"),
)


def latency_table(rows: Rows, first: str = "Thread") -> Table | None:
    """Per thread with callbacks: wake-up latency percentiles, mean and deviation, all in one unit, and releases above the bound."""
    periodic = [(label, t) for label, t in rows if t.has_callbacks]
    if not periodic:
        return None
    sc = fg.scale(fg.Unit.NS, (figure(t, name) for _, t in periodic for _, name in LATENCY_COLUMNS))
    out = [
        [label, *(sc.number(figure(t, name)) for _, name in LATENCY_COLUMNS), fmt_int(figure(t, "latency.above_bound"))]  # type: ignore[arg-type]
        for label, t in periodic
    ]
    return _numbers(first, [sc.header(words) for words, _ in LATENCY_COLUMNS] + ["Above bound"], out)


def timing_table(rows: Rows, first: str = "Thread") -> Table | None:
    """Per periodic thread: releases, misses, overruns and slack (end of a callback to its next release)."""
    periodic = [(label, t) for label, t in rows if t.periodic]
    if not periodic:
        return None
    sc = fg.scale(fg.Unit.NS, (figure(t, name) for _, t in periodic for name in ("slack.min", "slack.p1")))
    out = []
    for label, t in periodic:
        f = t.figures
        out.append(
            [
                label,
                fmt_int(f.releases),
                fmt_int(f.missed_releases) + (" ⚠️" if f.missed_releases else ""),
                fmt_int(f.overruns) + (" ⚠️" if f.overruns else ""),
                sc.number(figure(t, "slack.min")),
                sc.number(figure(t, "slack.p1")),
            ]
        )
    return _numbers(first, ["Releases", "Missed", "Overruns", sc.header("Slack, worst"), sc.header("Slack p1")], out)


EVENT_HEADERS = ["Thread", "Phase: event", "Measures", "Count", "p50", "p99", "max", "Contended", "Held by"]


def event_count(e: EventResult) -> str:
    """`41`, `41 + 1 cut` (under way at the end: in no figure), `8, 2 lost` (resumes nobody waited for, pending: drop)."""
    text = fmt_int(e.count)
    if e.cut:
        text += f" + {fmt_int(e.cut)} cut"
    if e.lost:
        text += f", {fmt_int(e.lost)} lost"
    return text


def events_table(cell: CellResult, labels: dict[str, str]) -> Table | None:
    """Per event of every program: how often it ran and what it took (lock wait, timer latency, run time), who held a lock."""
    events = [(t, e) for t in cell.threads for e in t.events]
    if not events:
        return None
    sc = fg.scale(fg.Unit.NS, (getattr(e.spread_ns, q) for _, e in events if e.spread_ns is not None for q in ("p50", "p99", "max")))
    rows = []
    for t, e in events:
        sp = e.spread_ns
        held = ", ".join(f"{h.thread} ({fmt_int(h.contentions)}×, {fmt_ns(h.wait_ns)})" for h in e.holders)
        rows.append(
            [
                labels[t.key],
                Markdown(f"{md_text(e.phase, in_table=True)}: {md_text(e.event, in_table=True)}"),
                e.measures,
                event_count(e),
                *(sc.number(getattr(sp, q)) if sp is not None else "–" for q in ("p50", "p99", "max")),
                fmt_int(e.contended) if e.kind == "lock" else "",
                md_text(held, in_table=True),
            ]
        )
    headers = EVENT_HEADERS[:4] + [sc.header(h) for h in EVENT_HEADERS[4:7]] + EVENT_HEADERS[7:]
    return Table(headers, rows, [LEFT] * 3 + [RIGHT] * 5 + [LEFT])


PHASE_HEADERS = ["Thread", "Phase", "Passes", "Time", "Settings on entry (kernel)", "CPUs seen", "Involuntary", "Voluntary", "Minor faults"]


def phases_table(cell: CellResult, labels: dict[str, str]) -> Table | None:
    """Per phase of every program: passes, time, the settings the kernel reported on entry, CPUs, switches and faults."""
    phases = [(t, p) for t in cell.threads for p in t.phases]
    if not phases:
        return None
    sc = fg.scale(fg.Unit.NS, (p.time_ns for _, p in phases))
    rows = []
    for t, p in phases:
        applied = f"{p.applied.label()}, cpus {p.applied.cpus_label()}" if p.applied is not None else "not entered"
        rows.append(
            [
                labels[t.key],
                md_text(p.name, in_table=True),
                fmt_int(p.passes),
                sc.number(p.time_ns),
                applied + (" ⚠️" if p.degraded else ""),
                ",".join(str(c) for c in p.cpus_seen) or "–",
                fmt_int(p.involuntary),
                fmt_int(p.voluntary),
                fmt_int(p.minor_faults),
            ]
        )
    headers = PHASE_HEADERS[:3] + [sc.header("Time")] + PHASE_HEADERS[4:]
    return Table(headers, rows, [LEFT, LEFT, RIGHT, RIGHT, LEFT, LEFT, RIGHT, RIGHT, RIGHT])


_BOUND = re.compile(r"(>=|<=)\s*(\S+)")


def limit_values(v: Verdict) -> list[tuple[str, Number]] | None:
    """The bounds of an expectation's limit as written (`>= 1ms and <= 2ms`), in the figure's unit; None if it does not read."""
    found = _BOUND.findall(v.limit)
    if not found or " and ".join(f"{op} {text}" for op, text in found) != v.limit.strip():
        return None
    out: list[tuple[str, Number]] = []
    for op, text in found:
        try:
            out.append(("≥" if op == ">=" else "≤", units.parse_duration(text) if v.figure.is_duration else float(text)))
        except (ValueError, units.UnitError):
            return None
    return out


def verdict_table(cell: CellResult) -> Table | None:
    """Each expectation: its limit and the measured value in one unit and precision, the unit beside the figure's words."""
    if not cell.expectations:
        return None
    rows = []
    verdicts, more = verdicts_shown(cell.expectations, REPORT_ROWS)
    for v in verdicts:
        bounds = limit_values(v)
        sc = fg.scale(v.figure.unit, [v.measured, *(b for _, b in bounds or [])])
        limit = " and ".join(f"{op} {sc.number(b)}" for op, b in bounds) if bounds is not None else v.limit
        measured = sc.number(v.measured) if v.measured is not None else "not measured"
        if v.measured is not None and v.samples is not None:
            measured += f" ({samples_words(v.figure, v.samples)})"
        rows.append(
            [
                "✅ pass" if v.passed else "❌ FAIL",
                v.thread,
                sc.header(v.figure.words) + (f": {v.note}" if v.note else ""),
                limit,
                measured,
            ]
        )
    if more:
        failed = sum(not v.passed for v in cell.expectations) - sum(not v.passed for v in verdicts)
        rows.append(["…", f"{more:,} more", f"{failed:,} of them failed: see results.json", "", ""])
    return Table(["Verdict", "Thread", "Expectation", "Limit", "Measured"], rows, [LEFT, LEFT, LEFT, RIGHT, RIGHT])


def summary_tables(cells: Sequence[CellResult], repeated: bool = False) -> list[Table]:
    """Per cell: its status, scheduling, expectations and duration; then its periodic threads' worst figures.

    Two tables, so a long cell id and ten columns do not make one table wider than GitHub's page;
    the misses and slack columns only when some cell did not keep up.
    """
    overloaded = any(not fg.kept_up(t.figures) for cell in cells for t in callback_threads(cell))
    p99s = [max((p for t in callback_threads(c) if (p := figure(t, "latency.p99")) is not None), default=None) for c in cells]
    slacks = [min((t.figures.slack_ns.min for t in callback_threads(c) if t.figures.slack_ns is not None), default=None) for c in cells]
    lat, slack, per_cb = fg.scale(fg.Unit.NS, p99s), fg.scale(fg.Unit.NS, slacks), fg.scale(fg.Unit.PER_CALLBACK)
    status, worst = [], []
    for cell, p99, worst_slack in zip(cells, p99s, slacks):
        threads = callback_threads(cell)
        link = Markdown(f"[{md_text(section_title(cell, repeated)[5:], in_table=True)}](#{anchor(cell, repeated)})")
        passed = sum(v.passed for v in cell.expectations)
        status.append(
            [
                link,
                ICON[cell.status],
                ", ".join(sorted({policy_label(t.applied) for t in threads})) or "–",
                f"{passed} of {len(cell.expectations)}" if cell.expectations else "–",
                f"{cell.duration_s:.1f}",
            ]
        )
        missed = sum(t.figures.missed_releases for t in threads)
        worst.append(
            [
                md_text(cell.id, in_table=True),
                fmt_int(sum(t.figures.callbacks for t in threads)) if threads else "–",
                per_cb.number(max((t.figures.involuntary.per_callback_mean or 0.0 for t in threads), default=None)),
                lat.number(p99),
            ]
            + ([f"{missed:,}" + (" ⚠️" if missed else ""), slack.number(worst_slack)] if overloaded else [])
        )
    headers = ["Callbacks", "Involuntary / callback", lat.header("Wake-up p99")]
    headers += ["Missed releases", slack.header("Slack, worst")] if overloaded else []
    return [
        Table(["Cell", "Status", "Scheduling (periodic threads)", "Expectations met", "Duration (s)"], status, [LEFT] * 3 + [RIGHT] * 2),
        _numbers("Cell", headers, worst),
    ]


def across_cells(entries: Sequence[tuple[CellResult, ThreadResult]]) -> list[tuple[str, Table]]:
    """The seed's comparison (other vs fifo vs rr): one thread, a row per cell, in the groups of a cell's own tables."""
    rows = [(cell.id, t) for cell, t in entries]
    built = (
        ("Scheduling", threads_table(rows, "Cell")),
        ("Context switches", switches_table(rows, "Cell")),
        ("Wake-up latency", latency_table(rows, "Cell")),
        ("Releases and slack", timing_table(rows, "Cell")),
        ("Page faults", faults_table(rows, "Cell")),
    )
    return [(caption, t) for caption, t in built if t is not None]


def spread_table(cells: Sequence[CellResult], labels: dict[str, str]) -> Table | None:
    """For repeated cells: each periodic thread's key figures as median (min – max) over the repeats, one unit per column."""
    groups: dict[tuple[str, str], list[ThreadResult]] = {}
    for cell in cells:
        for t in callback_threads(cell):
            groups.setdefault((cell.id, t.key), []).append(t)
    if not any(len(ts) > 1 for ts in groups.values()):
        return None
    names = ("latency.p50", "latency.p99", "latency.max")
    lat = fg.scale(fg.Unit.NS, (figure(t, name) for ts in groups.values() for t in ts for name in names))
    per_cb = fg.scale(fg.Unit.PER_CALLBACK)

    def spread(values: list[Number | None], sc: fg.Scale) -> str:
        present = sorted(v for v in values if v is not None)
        if not present:
            return "–"
        mid = statistics.median(present)
        return sc.number(mid) if len(present) == 1 else f"{sc.number(mid)} ({sc.number(present[0])} – {sc.number(present[-1])})"

    rows = []
    for (cell_id, key), ts in groups.items():
        rows.append(
            [
                cell_id,
                labels[key],
                str(len(ts)),
                spread([t.figures.involuntary.per_callback_mean for t in ts], per_cb),
                *(spread([figure(t, name) for t in ts], lat) for name in names),
            ]
        )
    return Table(
        ["Cell", "Thread", "Repeats", "Involuntary / callback", *(lat.header(f"Wake-up {q}") for q in ("p50", "p99", "max"))],
        rows,
        [LEFT, LEFT, RIGHT, RIGHT, RIGHT, RIGHT, RIGHT],
    )


def section_title(cell: CellResult, repeated: bool) -> str:
    return f"Cell {cell.id}" + (f" (repeat {cell.repeat + 1})" if repeated else "")


def anchor(cell: CellResult, repeated: bool = False) -> str:
    """The GitHub heading anchor of a cell's section (`## Cell <id>`)."""
    text = section_title(cell, repeated).lower()
    return "".join(ch for ch in text.replace(" ", "-") if ch.isalnum() or ch in "-_")


# ---------------------------------------------------------------- facts


def facts(doc: RunDocument) -> Table:
    """The run's facts: what a reader needs to trust or compare its numbers."""
    m, p = doc.machine, doc.permissions
    throttle = m.rt_throttling
    if throttle and throttle.enabled:
        runtime, period = throttle.runtime_ns or 0, throttle.period_ns or 1
        rt = f"on: RT threads may use {runtime / 1e6:g} ms of every {period / 1e6:g} ms ({100 * runtime / period:.0f}%)"
    else:
        rt = "off (an RT busy loop can starve a CPU)"
    preempt = Markdown("**yes**" if m.preempt_rt else f"no ({md_text(_known(m.preempt, 'unknown'), in_table=True)})")
    caps = ", ".join(
        f"{name} {'yes' if held else 'no'}" for name, held in (("CAP_SYS_NICE", p.cap_sys_nice), ("CAP_IPC_LOCK", p.cap_ipc_lock))
    )
    perms = md_text(
        f"{_known(p.user)} (uid {_known(p.uid)}): {caps}, RLIMIT_RTPRIO {_known(p.rlimit_rtprio)}, "
        f"RLIMIT_MEMLOCK {fmt_bytes(p.rlimit_memlock)}",
        in_table=True,
    )
    if p.missing:
        perms = Markdown(perms + "; **missing:** " + "; ".join(md_text(why, in_table=True) for why in p.missing))
    counts: dict[Status, int] = {}
    for cell in doc.cells:
        counts[cell.status] = counts.get(cell.status, 0) + 1
    outcome = ", ".join(f"{n} {s.value}" for s, n in sorted(counts.items(), key=lambda kv: list(Status).index(kv[0])))
    ran = {cell.id for cell in doc.cells}
    missing = len([c for c in doc.cell_ids if c not in ran])
    rows: list[list[str]] = [
        ["Scenario", Markdown(f"{md_text(doc.name, in_table=True)} ({md_code(_known(doc.scenario.path), in_table=True)})")],
        ["Date", f"{_when(doc.started_at)} to {_when(doc.finished_at)}" if doc.finished_at else f"{_when(doc.started_at)} (still running)"],
        [
            "Host",
            (
                f"{_known(m.hostname)}, {_known(m.arch)}, CPUs {_known(m.cpus_online)} online"
                f" ({_known(m.cpus_allowed)} usable), isolated CPUs: {m.isolated_cpus or 'none'},"
                f" memory {fmt_bytes(m.memory_total_bytes)}"
            ),
        ],
        ["Kernel", Markdown(f"{md_text(_known(m.kernel), in_table=True)} {md_code(m.kernel_version, in_table=True)}")],
        ["PREEMPT_RT", preempt],
        ["RT throttling", rt],
        ["CPU frequency governor", ", ".join(m.cpufreq_governors) or "not exposed"],
        ["Permissions", perms],
        ["Tool", f"runner {doc.tool_version}, Python {_known(m.python)}"],
        ["Command", md_code(shlex.join(doc.command), in_table=True)],
        [
            "Result",
            Markdown(
                f"**{md_text(doc.status, in_table=True)}**: {len(doc.cells)} cell{'s' if len(doc.cells) != 1 else ''} run "
                f"({outcome or 'none'})" + (f", {missing} not run" if missing else "")
            ),
        ],
    ]
    system_rows = system.system_rows(m)
    if any(name == "CPU frequency governor" for name, _ in system_rows):  # the per-CPU form replaces the plain list
        rows = [row for row in rows if row[0] != "CPU frequency governor"]
    at = next(i for i, row in enumerate(rows) if row[0] == "Permissions")
    rows[at:at] = system_rows
    hosts: dict[str, int] = {}
    for cell in doc.cells:
        name = _known(cell.machine.hostname if cell.machine else None)
        hosts[name] = hosts.get(name, 0) + 1
    if len(hosts) > 1:
        rows.insert(3, ["Hosts", ", ".join(f"{h} ({n} cell{'s' if n != 1 else ''})" for h, n in hosts.items())])
    if doc.shard:
        rows.append(["Shard", doc.shard])
    if doc.merged_from:
        rows.append(["Merged from", Markdown(", ".join(md_code(p, in_table=True) for p in doc.merged_from))])
    return Table(["Fact", "Value"], rows)


def _known(value: object, unknown: str = "?") -> str:
    """A recorded fact as text; `?` where the results do not have it."""
    return unknown if value is None else str(value)


def _when(stamp: str | None) -> str:
    return (stamp or "?").replace("T", " ").replace("+00:00", " UTC")


# ---------------------------------------------------------------- the report


@dataclass(frozen=True)
class Plot:
    title: str
    path: str  # relative to the report


@dataclass
class CellSection:
    cell: CellResult
    title: str
    anchor: str
    icon: str
    finding: Markdown
    ps: Markdown | None
    threads: Table
    switches: Table
    latency: Table | None
    timing: Table | None
    faults: Table
    events: Table | None
    phases: Table | None
    verdicts: Table | None
    degraded: list[str]
    load: Markdown
    programs: list[Markdown] = field(default_factory=list)
    outside: Table | None = None
    preemptions: list[str] = field(default_factory=list)
    trace: str | None = None
    warnings: list[str] = field(default_factory=list)
    shown: str = ""  # which threads the tables show, when not every one


@dataclass
class ThreadView:
    """One periodic thread of interest across the cells of a matrix: its figures in a row per cell."""

    label: str
    tables: list[tuple[str, Table]]  # (caption, table)
    cells: int


@dataclass
class ReportModel:
    title: str
    description: str
    facts: Table
    findings: list[Markdown]
    summary: list[Table]
    spread: Table | None
    threads: list[ThreadView]
    sections: list[CellSection]
    comparison: Markdown | None = None
    notes: list[str] = field(default_factory=list)
    plots: list[Plot] = field(default_factory=list)
    plots_note: Markdown | None = None  # why there are no plots, when they were asked for


def _load_line(cell: CellResult) -> Markdown:
    hogs = [b for b in cell.background if b.kind is BackgroundKind.HOG]
    commands = [b for b in cell.background if b.kind is BackgroundKind.COMMAND]
    parts = []
    if hogs:
        parts.append(f"{len(hogs)} busy-loop hog{'s' if len(hogs) != 1 else ''}")
    parts += [_command(c) for c in commands]
    return Markdown(", ".join(parts) or "none")


def _command(c: Background) -> str:
    """A background command as the load line names it: `stress-ng --cpu 2`, or by its name when the scenario gave it one."""
    line = md_code(shlex.join(c.argv))
    return f"{md_text(c.name)} ({line})" if c.name and c.argv and c.name != c.argv[0] else line


def _section(cell: CellResult, labels: dict[str, str], repeated: bool, pid_width: int) -> CellSection:
    picked = threads_shown(cell, REPORT_ROWS)
    rows = [(labels[t.key], t) for t in picked.threads]
    ps_rows, _ = ps_rows_shown(cell.thread_table, picked)
    warnings, more_warnings = lines_shown(cell.warnings, REPORT_ROWS)
    degraded, more_degraded = lines_shown([f"{labels[t.key]}: {why}" for t in cell.threads for why in t.degraded], REPORT_ROWS)
    return CellSection(
        cell=cell,
        title=section_title(cell, repeated),
        anchor=anchor(cell, repeated),
        icon=ICON[cell.status],
        finding=cell_finding(cell, labels),
        ps=md_code_block(render_ps(ps_rows, pid_width=pid_width), "text") if cell.thread_table else None,
        threads=threads_table(rows),
        switches=switches_table(rows),
        latency=latency_table(rows),
        timing=timing_table(rows),
        faults=faults_table(rows),
        events=events_table(cell, labels),
        phases=phases_table(cell, labels),
        verdicts=verdict_table(cell),
        degraded=degraded + ([f"... {more_degraded:,} more: see results.json"] if more_degraded else []),
        warnings=warnings + ([f"... {more_warnings:,} more warnings: see results.json"] if more_warnings else []),
        shown=picked.note(),
        load=_load_line(cell),
        programs=program_lines(cell),
        outside=outside_table(rows),
        preemptions=preemption_lines(rows),
        trace=trace_line(cell),
    )


def matrix_order(doc: RunDocument) -> list[CellResult]:
    """The cells in the matrix's order (repeats after their first run), not the order they ran in."""
    order = {cell_id: i for i, cell_id in enumerate(doc.matrix_cells)}
    return sorted(doc.cells, key=lambda c: (order.get(c.id, len(order)), c.repeat))


MAX_THREAD_VIEWS = 4  # periodic threads shown across cells and plotted one by one: the worst by wake-up p99


def threads_of_interest(cells: Sequence[CellResult], most: int = MAX_THREAD_VIEWS) -> list[str]:
    """The keys of the periodic threads worth a view of their own: the `most` with the highest wake-up p99 in any cell.

    A matrix of one callback thread shows it; a cell of 256 threads shows the few that did worst,
    so what the report draws does not grow with the threads (every thread stays in the tables).
    Ties keep the order the threads first appear in.
    """
    worst: dict[str, float] = {}
    for cell in cells:
        for t in callback_threads(cell):
            p99 = figure(t, "latency.p99")
            worst[t.key] = max(worst.get(t.key, -1.0), float(p99) if p99 is not None else -1.0)
    order = {key: i for i, key in enumerate(worst)}
    return sorted(worst, key=lambda key: (-worst[key], order[key]))[:most]


def build(
    doc: RunDocument,
    plots: Sequence[Plot] | None = None,
    comparison: str | None = None,
    pid_width: int = 5,
    plots_note: Markdown | None = None,
) -> ReportModel:
    """Everything the template shows, as text and tables; `plots` are the plot files drawn beside the report."""
    cells = matrix_order(doc)
    labels = thread_labels(cells)
    repeated = any(c.repeat for c in cells)
    firsts = first_runs(cells)
    matrix = len(firsts) > 1
    threads = []
    by_thread = _by_thread(firsts)
    if matrix:
        for key in threads_of_interest(firsts):
            entries = by_thread[key]
            if len(entries) > 1:
                threads.append(ThreadView(labels[key], across_cells(entries[:MAX_SIDE_BY_SIDE]), len(entries)))
    sections = [_section(cell, labels, repeated, pid_width) for cell in cells]
    findings = matrix_finding(firsts, labels) if matrix else []
    if not findings:
        findings = [
            Markdown(f"{md_text(cell.id)}: {cell_finding(cell, labels)}") if matrix else cell_finding(cell, labels) for cell in firsts
        ]
    findings += system.placement_findings(cells, doc.machine, labels, matrix)
    if repeated:
        findings.append(
            Markdown(
                "Cells ran more than once: the across-cells views and these findings show each cell's "
                "first run; the spread table shows every repeat."
            )
        )
    notes = []
    if any(v.cells > MAX_SIDE_BY_SIDE for v in threads):
        notes.append(f"The across-cells views show the first {MAX_SIDE_BY_SIDE} cells; the summary table has them all.")
    shown_keys = set(threads_of_interest(firsts)) if matrix else set()
    if matrix and len(by_thread) > len(shown_keys):
        notes.append(
            f"Across cells: the {len(shown_keys)} periodic threads with the highest wake-up p99, of {len(by_thread)}; "
            "each cell's tables list every thread."
        )
    return ReportModel(
        title=f"{doc.name}: scheduling report",
        description=doc.scenario.description,
        facts=facts(doc),
        findings=findings,
        summary=summary_tables(cells, repeated) if len(cells) > 1 else [],
        spread=spread_table(cells, labels),
        threads=threads,
        sections=sections,
        comparison=Markdown(comparison) if comparison else None,
        notes=notes,
        plots=list(plots or []),
        plots_note=plots_note,
    )


_ENV: jinja2.Environment | None = None


def environment() -> jinja2.Environment:
    """The template environment (templates ship inside the package).

    Every `{{ value }}` that is not Markdown is text and goes through `md_text`, as an HTML
    template escapes what is not marked safe: a name from the scenario cannot become a heading,
    a table row, a link or HTML in the report.
    """
    global _ENV
    if _ENV is None:
        _ENV = jinja2.Environment(
            loader=jinja2.PackageLoader("runner.report", "templates"),
            autoescape=False,
            trim_blocks=True,
            lstrip_blocks=True,
            keep_trailing_newline=True,
            undefined=jinja2.StrictUndefined,
            finalize=md_text,
        )
    return _ENV


def render(model: ReportModel) -> str:
    """The report as markdown."""
    return re.sub(r"\n{3,}", "\n\n", environment().get_template("report.md.j2").render(r=model))


def render_run(
    doc: RunDocument,
    plots: Sequence[Plot] | None = None,
    comparison: str | None = None,
    pid_width: int = 5,
    plots_note: Markdown | None = None,
) -> str:
    return render(build(doc, plots, comparison, pid_width, plots_note))


# ---------------------------------------------------------------- comparison with a baseline

VERDICT_ICON = {
    "regression": "❌ regression",
    "better": "🟢 better",
    "within threshold": "✅ within threshold",
    "not checked": "⏸️ not checked (threshold off)",
    "no baseline": "🆕 no baseline",
    "missing": "❌ missing",
    "run error": "💥 run error",
    "not comparable": "⚠️ not comparable (trace events lost)",
    "within noise": "〰️ within noise",
    "not judged": "⏸️ not judged",
}


@dataclass
class ComparisonModel:
    headline: Markdown
    facts: Table
    regressions: Table | None
    cells: Table
    figures: Table | None
    notes: list[str]


HEADLINE_NAMES = 5  # names a headline lists of each kind (cells, threads, figures) before "and N more"


def _capped(names: Sequence[str], most: int = HEADLINE_NAMES) -> str:
    """`a, b, c, d, e and 995 more`: a headline names a few of each kind; the tables below name them all.

    The headline is also the terminal line `compared with BASE: ...` (`publish.say_comparison`), which
    on a matrix of a thousand cells listed every one of them.
    """
    shown = ", ".join(names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def build_comparison(cmp: Comparison, base_name: str, new_name: str) -> ComparisonModel:
    """What the comparison section shows: a headline, regressions first, then every figure compared."""
    labels = thread_labels(cmp.base.cells + cmp.new.cells)
    regressed = cmp.regressed_cells()
    total = len(cmp.compared())
    incomplete = cmp.incomplete  # what it holds may compare well; what it lacks was never measured: never ✅
    errored = [c for c in cmp.cells if c.new_status in (Status.ERROR, Status.INTERRUPTED)]  # cells that did not run to the end: never ✅
    gone, new_cells = cmp.unmatched("missing"), cmp.unmatched("no baseline")
    # a thread or a cell of the baseline this run lacks was never compared (even with every threshold off): never ✅
    headline = (
        f"❌ **{cmp.regressions} regression{'s' if cmp.regressions != 1 else ''}** in {len(regressed)} of {total} "
        f"cell{'s' if total != 1 else ''}: {_capped([md_text(c) for c in regressed])}."
        if regressed
        else f"{'' if incomplete or errored or not cmp.alike or cmp.threads_gone or gone else '✅ '}"
        f"No regression in {total} cell{'s' if total != 1 else ''} compared with the baseline."
    )
    if cmp.nothing:  # a shard with no cell: nothing compared is neither a pass nor a failure
        headline = f"Nothing to compare: this run holds no cell ({md_text(cmp.nothing)})."
    for difference in cmp.differences:  # what could explain a change (or hide one) besides the scheduling: never ✅
        headline += f" ⚠️ {md_text(difference)}"
    if errored:
        shown = _capped([f"{md_text(c.cell)} ({c.new_status.value if c.new_status else '?'})" for c in errored])
        which = "cell of this run could not run or was" if len(errored) == 1 else "cells of this run could not run or were"
        headline = f"💥 **{len(errored)} {which} cut short**: {shown}. {headline}"
    if incomplete:
        headline = f"⚠️ This run is incomplete: {md_text(incomplete)}. {headline}"
    if cmp.other_version:  # first: every figure below is of another version of the scenario
        headline = f"⚠️ **Another version of the scenario**: {md_text(cmp.other_version)}. {headline}"
    gone_threads = set(cmp.threads_gone)
    if gone_threads:  # its figures are missing too: said once, as the thread
        where = [f"{md_text(labels.get(key, key))} ({md_text(cell)})" for cell, key in cmp.threads_gone]
        headline += f" {len(where)} thread{'s' if len(where) != 1 else ''} of the baseline not in this run: {_capped(where)}."
    lost = [f for f in cmp.figures if f.verdict == "missing" and (f.cell, f.thread) not in gone_threads]
    if lost:
        where = sorted({f"{f.figure.name} ({md_text(f.cell)})" for f in lost})
        headline += f" {len(lost)} figure{'s' if len(lost) != 1 else ''} of the baseline not measured now: {_capped(where)}."
    if gone:
        shown = _capped(list(map(md_text, gone)))
        headline += f" {len(gone)} cell{'s' if len(gone) != 1 else ''} of the baseline not in this run: {shown}."
    if new_cells:
        shown = _capped(list(map(md_text, new_cells)))
        headline += f" {len(new_cells)} cell{'s' if len(new_cells) != 1 else ''} not in the baseline: {shown}."
    facts = Table(
        ["", "Baseline", "This run"],
        [
            ["Results", md_code(base_name, in_table=True), md_code(new_name, in_table=True)],
            ["Started", _when(cmp.base.started_at), _when(cmp.new.started_at)],
            [
                "Host, kernel",
                f"{_known(cmp.base.machine.hostname)}, {_known(cmp.base.machine.kernel)}",
                f"{_known(cmp.new.machine.hostname)}, {_known(cmp.new.machine.kernel)}",
            ],
        ],
    )
    notes = [
        "A figure regresses when it is worse than its baseline by more than its threshold: "
        + "; ".join(f"{fg.figure(t.figure).words} {t.describe()}" for t in cmp.thresholds)
        + ", and by more than sampling explains. Each figure is shown with its 95% interval [low, high] (a quantile's "
        "from the order statistics of its histogram, a count's exact binomial or Poisson one, a mean's standard error); "
        "the change is tested exactly against both runs' samples, and the p-values are adjusted by Holm's method over "
        "every figure tested, so that a whole comparison would call a false regression at most 5% of the time if each "
        "callback were an independent sample of one unchanged host. Neither quite holds: one hiccup delays several "
        "callbacks, and a host varies from night to night (of 19 identical nights on a 2-CPU VM, 6 were called "
        "regressions against the night before). For a nightly verdict, judge against a history (--history), which "
        "learns each figure's variation between nights. A change past its threshold that sampling explains is within "
        "noise; a figure with too few samples for an interval is not judged, and says what it needs."
    ] + list(cmp.notes)

    def figure_rows(items: Iterable[FigureChange]) -> list[list[str]]:
        rows = []
        for f in items:
            sc = fg.scale(f.figure.unit, (f.base, f.new, *interval_ends(f.base_estimate), *interval_ends(f.new_estimate)))
            rows.append(
                [
                    f.cell,
                    labels.get(f.thread, f.thread),
                    sc.header(f.figure.words),
                    sc.number(f.base) + interval_text(f.base_estimate, sc),
                    sc.number(f.new) + interval_text(f.new_estimate, sc),
                    change_text(f, sc),
                    VERDICT_ICON[f.verdict],
                    md_text(f.why) if f.why else "–",
                ]
            )
        return rows

    headers = ["Cell", "Thread", "Figure", "Baseline", "This run", "Change", "Verdict", "Why"]
    align = [LEFT, LEFT, LEFT, RIGHT, RIGHT, RIGHT, LEFT, LEFT]
    bad = [f for f in cmp.figures if f.verdict in ("regression", "missing")]  # a figure of the baseline this run lacks fails too
    status_rows = [
        [
            c.cell,
            c.base_status.value if c.base_status else "–",
            c.new_status.value if c.new_status else "–",
            VERDICT_ICON["regression" if c.cell in regressed and c.verdict != "run error" else c.verdict]
            + (f" ({c.note})" if c.note else ""),
        ]
        for c in cmp.cells
    ]
    return ComparisonModel(
        headline=Markdown(headline),
        facts=facts,
        regressions=Table(headers, figure_rows(bad), align) if bad else None,
        cells=Table(["Cell", "Baseline status", "Status now", "Verdict"], status_rows),
        figures=Table(headers, figure_rows(cmp.figures), align) if cmp.figures else None,
        notes=notes,
    )


def interval_ends(est: Estimate | None) -> tuple[float, ...]:
    """The ends of an estimate's interval, to choose a row's scale with (none when it has none)."""
    if est is None or est.low is None or est.high is None:
        return ()
    return (est.low, est.high)


def interval_text(est: Estimate | None, sc: fg.Scale) -> str:
    """` [49, 66]`: an estimate's interval in the scale of its row; "" when it has none."""
    if est is None or est.low is None or est.high is None:
        return ""
    return f" [{sc.number(est.low)}, {sc.number(est.high)}]"


def change_text(f: FigureChange, sc: fg.Scale, with_unit: bool = False) -> str:
    """`+316 (+373%)` (`+316 µs (+373%)` `with_unit`): how much a compared figure moved, in the scale of its row.

    One minus sign, U+2212, as in every number the report writes.
    """
    if f.base is None or f.new is None:
        return "–"
    delta = f.new - f.base
    text = sc.number(delta, sign=True) + (f" {sc.unit}" if with_unit and sc.unit else "")
    if f.base:
        percent = fg.scale(fg.Unit.COUNT).number(delta / abs(f.base) * 100, sign=True)
        text += f" ({percent}%)"
    return text


def render_comparison(cmp: Comparison, base_name: str, new_name: str) -> Markdown:
    """The comparison as a markdown section (`## Comparison with the baseline`)."""
    text = environment().get_template("compare.md.j2").render(c=build_comparison(cmp, base_name, new_name))
    return Markdown(re.sub(r"\n{3,}", "\n\n", text).strip("\n") + "\n")
