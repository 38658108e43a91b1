"""The report's tables: the run's facts, threads, switches, faults, latency, timing, events, phases, verdicts, summaries.

Each takes results rows and gives a `Table` (headers, rows, alignment) that the template
lays out; units everywhere, no raw field names.  The lines that go under a cell's tables
(preemption, trace, programs) live here too: they read the same rows.  Pure.
"""

from __future__ import annotations

import re
import shlex
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from runner import figures as fg
from runner import units
from runner.figures import Number
from runner.report import system
from runner.report.findings import ICON, callback_threads, figure, policy_label, table
from runner.report.fmt import (
    LEFT,
    RIGHT,
    Markdown,
    fmt_bytes,
    fmt_int,
    fmt_ns,
    md_code,
    md_text,
    relative_command,
    relative_path,
    samples_words,
)
from runner.report.selection import REPORT_ROWS, verdicts_shown
from runner.results.document import (
    NOT_STARTED,
    CellResult,
    EventResult,
    FoldedThreads,
    PreemptedRun,
    Preemptor,
    ProgramResult,
    RunDocument,
    ThreadResult,
    Verdict,
)

# ---------------------------------------------------------------- tables


@dataclass(frozen=True)
class Table:
    """A table of text cells (escaped when rendered) and Markdown cells (shown as they are), aligned per column."""

    headers: list[str]
    rows: list[list[str]]
    align: list[str] | None = None

    def render(self) -> Markdown:
        return table(self.headers, self.rows, self.align)

    def compact(self) -> Table | None:
        """This table without the columns that are empty (`–`) in every row; None when only the first, which names the
        row, is left.  A column of dashes says nothing and costs width a page may not have (GitHub's is 1012 px)."""
        keep = [0] + [i for i in range(1, len(self.headers)) if any(str(r[i]) not in EMPTY for r in self.rows)]
        if len(keep) == 1:
            return None
        if len(keep) == len(self.headers):
            return self
        align = [self.align[i] for i in keep] if self.align else None
        return Table([self.headers[i] for i in keep], [[r[i] for i in keep] for r in self.rows], align)


EMPTY = ("–", "")  # what a cell without a value shows


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


def outside_tables(rows: Rows, first: str = "Thread") -> tuple[Table | None, Table | None]:
    """Per thread measured from outside (a program's, or any the scheduler trace followed): two tables, each without
    the columns no row has a value in (the runner's own threads have no rule, rates or CPU time there).

    From /proc: the rule that set a program's thread, switches per second, CPU time.  From the scheduler trace:
    migrations, preemptions and the latency from each sched_waking to the switch onto a CPU, beside how many wake-ups
    it stands on (a p99 of 1 wake-up is that wake-up); not the release-to-run latency of `latency_table`.  Eleven
    columns in one table needed more than GitHub's 1012 px and hid the trace's, the ones an expectation checks.
    """
    chosen = [(label, t) for label, t in rows if _measured_outside(t)]
    if not chosen:
        return None, None
    f = [t.figures for _, t in chosen]
    rate = fg.scale(fg.Unit.PER_SECOND)
    cpu = fg.scale(fg.Unit.NS, [x.cpu_time_ns for x in f])
    after = fg.scale(fg.Unit.NS, [t.rule_after_ns for _, t in chosen])
    wake = fg.scale(fg.Unit.NS, [w.max for x in f if (w := x.wakeup_ns) is not None])
    proc = [
        [
            label,
            md_code(t.rule, in_table=True) if t.rule else "–",
            after.number(t.rule_after_ns),
            rate.number(t.figures.involuntary.per_second),
            rate.number(t.figures.voluntary.per_second),
            cpu.number(t.figures.cpu_time_ns),
        ]
        for label, t in chosen
    ]
    traced = [
        [
            label,
            fmt_int(t.figures.migrations),
            fmt_int(t.figures.preemptions),
            fmt_int(t.figures.wakeup_ns.count if t.figures.wakeup_ns else None),
            wake.number(t.figures.wakeup_ns.p50 if t.figures.wakeup_ns else None),
            wake.number(t.figures.wakeup_ns.p99 if t.figures.wakeup_ns else None),
            wake.number(t.figures.wakeup_ns.max if t.figures.wakeup_ns else None),
        ]
        for label, t in chosen
    ]
    proc_headers = ["Rule", after.header("Rule applied after"), "Involuntary / s", "Voluntary / s", cpu.header("CPU time")]
    trace_headers = ["Migrations", "Preemptions", "Wake-ups traced"]
    trace_headers += [wake.header("Waking to running p50"), wake.header("p99"), wake.header("max")]
    return (
        Table([first, *proc_headers], proc, [LEFT, LEFT] + [RIGHT] * (len(proc_headers) - 1)).compact(),
        _numbers(first, trace_headers, traced).compact(),
    )


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


IN_A_ROW = fg.figure("missed_releases.consecutive_max")  # its column, named by the registry, beside the misses


def timing_table(rows: Rows, first: str = "Thread") -> Table | None:
    """Per periodic thread: releases, misses (and the most in a row), overruns and slack (end of a callback to its next release)."""
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
                fmt_int(figure(t, IN_A_ROW.name)),  # type: ignore[arg-type]  # a count
                fmt_int(f.overruns) + (" ⚠️" if f.overruns else ""),
                sc.number(figure(t, "slack.min")),
                sc.number(figure(t, "slack.p1")),
            ]
        )
    headers = ["Releases", "Missed", f"Missed {IN_A_ROW.column}", "Overruns", sc.header("Slack, worst"), sc.header("Slack p1")]
    return _numbers(first, headers, out)


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


def facts(doc: RunDocument, cwd: str | None = None) -> Table:
    """The run's facts: what a reader needs to trust or compare its numbers; paths relative to the working directory `cwd`.

    The run's outcome is not among them: the report's headline says it (`headline`), first.
    """
    m, p = doc.machine, doc.permissions
    throttle = m.rt_throttling
    if throttle and throttle.enabled:
        runtime, period = throttle.runtime_ns or 0, throttle.period_ns or 1
        rt = f"on: RT threads may use {runtime / 1e6:g} ms of every {period / 1e6:g} ms ({100 * runtime / period:.0f}%)"
    else:
        rt = "off (an RT busy loop can starve a CPU)"
    preempt = Markdown("**yes**" if m.preempt_rt else f"no ({md_text(known(m.preempt, 'unknown'), in_table=True)})")
    caps = ", ".join(
        f"{name} {'yes' if held else 'no'}" for name, held in (("CAP_SYS_NICE", p.cap_sys_nice), ("CAP_IPC_LOCK", p.cap_ipc_lock))
    )
    perms = md_text(
        f"{known(p.user)} (uid {known(p.uid)}): {caps}, RLIMIT_RTPRIO {known(p.rlimit_rtprio)}, "
        f"RLIMIT_MEMLOCK {fmt_bytes(p.rlimit_memlock)}",
        in_table=True,
    )
    if p.missing:
        perms = Markdown(perms + "; **missing:** " + "; ".join(md_text(why, in_table=True) for why in p.missing))
    rows: list[list[str]] = [
        [
            "Scenario",
            Markdown(f"{md_text(doc.name, in_table=True)} ({md_code(relative_path(known(doc.scenario.path), cwd), in_table=True)})"),
        ],
        ["Date", f"{when(doc.started_at)} to {when(doc.finished_at)}" if doc.finished_at else f"{when(doc.started_at)} (still running)"],
        [
            "Host",
            (
                f"{known(m.hostname)}, {known(m.arch)}, CPUs {known(m.cpus_online)} online"
                f" ({known(m.cpus_allowed)} usable), isolated CPUs: {m.isolated_cpus or 'none'},"
                f" memory {fmt_bytes(m.memory_total_bytes)}"
            ),
        ],
        ["Kernel", Markdown(f"{md_text(known(m.kernel), in_table=True)} {md_code(m.kernel_version, in_table=True)}")],
        ["PREEMPT_RT", preempt],
        ["RT throttling", rt],
        ["CPU frequency governor", ", ".join(m.cpufreq_governors) or "not exposed"],
        ["Permissions", perms],
        ["Tool", f"runner {doc.tool_version}, Python {known(m.python)}"],
        ["Command", md_code(shlex.join(relative_command(doc.command, cwd)), in_table=True)],
    ]
    system_rows = system.system_rows(m)
    if any(name == "CPU frequency governor" for name, _ in system_rows):  # the per-CPU form replaces the plain list
        rows = [row for row in rows if row[0] != "CPU frequency governor"]
    at = next(i for i, row in enumerate(rows) if row[0] == "Permissions")
    rows[at:at] = system_rows
    hosts: dict[str, int] = {}
    for cell in doc.cells:
        name = known(cell.machine.hostname if cell.machine else None)
        hosts[name] = hosts.get(name, 0) + 1
    if len(hosts) > 1:
        rows.insert(3, ["Hosts", ", ".join(f"{h} ({n} cell{'s' if n != 1 else ''})" for h, n in hosts.items())])
    if doc.shard:
        rows.append(["Shard", doc.shard])
    if doc.merged_from:
        rows.append(["Merged from", Markdown(", ".join(md_code(relative_path(p, cwd), in_table=True) for p in doc.merged_from))])
    return Table(["Fact", "Value"], rows)


def known(value: object, unknown: str = "?") -> str:
    """A recorded fact as text; `?` where the results do not have it."""
    return unknown if value is None else str(value)


def when(stamp: str | None) -> str:
    return (stamp or "?").replace("T", " ").replace("+00:00", " UTC")
