"""The markdown report of a run: facts, findings, matrix summary, the seed's comparison view, per-cell tables.

Pure: a results document in, markdown out (no file access).  The layout lives in
`templates/report.md.j2`; this module turns results into rows of readable text
(units everywhere, no raw field names) and the template arranges them.  Tables
are GitHub-flavoured markdown from tabulate.
"""

from __future__ import annotations

import re
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import jinja2
from tabulate import tabulate

from runner import figures as fg
from runner import units
from runner.figures import Number, ThreadFigures
from runner.report import system
from runner.report.fmt import (
    Markdown,
    fmt_bytes,
    fmt_figure,
    fmt_int,
    fmt_mean,
    fmt_ns,
    md_code,
    md_code_block,
    md_text,
)
from runner.results.document import BackgroundKind, CellResult, RunDocument, Status, ThreadResult
from runner.results.pstable import render_ps
from runner.scenario.model import Policy
from runner.scenario.plan import Settings

if TYPE_CHECKING:
    from runner.report.compare import Comparison, FigureChange

MAX_SIDE_BY_SIDE = 12  # cells shown as columns in the comparison view; beyond that the summary table serves

ICON = {
    Status.PASSED: "✅ passed",
    Status.DEGRADED: "⚠️ degraded",
    Status.FAILED: "❌ failed",
    Status.ERROR: "💥 error",
    Status.INTERRUPTED: "⏸️ interrupted",
}


# ---------------------------------------------------------------- formatting


def policy_label(settings: Settings | None) -> str:
    """`FIFO 80`, `RR 10`, `OTHER`, `OTHER nice -5`: how people say a thread's scheduling."""
    if settings is None:
        return "?"
    text = settings.policy.name
    if settings.policy.is_realtime:
        text += f" {settings.priority}"
    if settings.nice and settings.policy in (Policy.OTHER, Policy.BATCH):
        text += f" nice {settings.nice}"
    return text


def table(headers: Sequence[str], rows: Iterable[Sequence[object]], align: Sequence[str] | None = None) -> Markdown:
    """A GitHub-flavoured markdown table; cells that are not already Markdown are text, escaped by `md_text`."""
    return Markdown(
        tabulate(
            [[md_text(c, in_table=True) for c in r] for r in rows],
            headers=[md_text(h, in_table=True) for h in headers],
            tablefmt="github",
            disable_numparse=True,
            colalign=align,
        )
    )


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


def periodic_threads(cell: CellResult) -> list[ThreadResult]:
    return [t for t in cell.threads if t.periodic]


def _switches(f: ThreadFigures) -> str:
    """`0 involuntary switches in 98 callbacks` or `8.94 involuntary switches per callback (98 of 99 ... preempted)`."""
    inv = f.involuntary
    if not inv.total:
        return f"0 involuntary switches in {f.callbacks:,} callbacks"
    return (
        f"{fmt_mean(inv.per_callback_mean)} involuntary switches per callback "
        f"({fmt_int(inv.callbacks_with_any)} of {f.callbacks:,} callbacks preempted)"
    )


def thread_finding(t: ThreadResult, label: str) -> Markdown:
    """One sentence of what a periodic thread measured, e.g. `at FIFO 80: 0 involuntary switches in 98 callbacks`."""
    f = t.figures
    lat = figure(t, "latency.p99")
    where = f"**{md_text(label)}** at {policy_label(t.applied)}"
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
    threads = periodic_threads(cell)
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
            groups.setdefault(t.applied.policy.name if t.applied else "?", []).append(t)
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
    prios = sorted({t.applied.priority for t in threads if t.applied and t.applied.policy.is_realtime})
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
        for t in periodic_threads(cell):
            out.setdefault(t.key, []).append((cell, t))
    return out


# ---------------------------------------------------------------- tables


@dataclass(frozen=True)
class Table:
    """A table of text cells (escaped when rendered) and Markdown cells (shown as they are)."""

    headers: list[str]
    rows: list[list[str]]
    align: list[str] | None = None

    def render(self) -> Markdown:
        return table(self.headers, self.rows, self.align)


SWITCH_HEADERS = [
    "Thread",
    "Scheduling",
    "CPU",
    "Callbacks",
    "Involuntary / callback (mean)",
    "Involuntary / callback (max)",
    "Callbacks preempted",
    "Involuntary (total)",
    "Voluntary (total)",
    "Wake-up p50",
    "Wake-up p99",
    "Wake-up max",
    "Minor faults (1st callback / after)",
    "Major faults",
]


def switch_table(cell: CellResult, labels: dict[str, str]) -> Table:
    """Per thread: switch counts, wake-up latency and page faults, with units."""
    rows = []
    for t in cell.threads:
        f = t.figures
        faults = (
            f"{fmt_int(f.faults.minor_first_callback)} / {fmt_int(f.faults.minor_after_first)}"
            if t.periodic
            else f"{fmt_int(f.faults.minor)} (total)"
        )
        rows.append(
            [
                labels[t.key] + ("" if f.complete else " (did not finish)"),
                policy_label(t.applied) + (" ⚠️" if t.degraded else ""),
                units.format_cpus(f.cpus_seen) or "–",
                fmt_int(f.callbacks) if t.periodic else "–",
                fmt_mean(f.involuntary.per_callback_mean),
                fmt_int(f.involuntary.per_callback_max),
                fmt_int(f.involuntary.callbacks_with_any),
                fmt_int(f.involuntary.total),
                fmt_int(f.voluntary.total),
                *(fmt_ns(figure(t, name)) for name in ("latency.p50", "latency.p99", "latency.max")),
                faults,
                fmt_int(f.faults.major),
            ]
        )
    return Table(SWITCH_HEADERS, rows, ["left", "left"] + ["right"] * (len(SWITCH_HEADERS) - 2))


TIMING_HEADERS = [
    "Thread",
    "Releases",
    "Callbacks",
    "Missed",
    "Overruns",
    "Slack worst",
    "Slack p1",
    "Wake-up mean",
    "Wake-up std dev",
    "Above bound",
]


def timing_table(cell: CellResult, labels: dict[str, str]) -> Table | None:
    """Per periodic thread: releases, misses, overruns, slack, and latency mean and deviation (cyclictest's Avg)."""
    rows = []
    for t in periodic_threads(cell):
        f = t.figures
        rows.append(
            [
                labels[t.key],
                fmt_int(f.releases),
                fmt_int(f.callbacks),
                fmt_int(f.missed_releases) + (" ⚠️" if f.missed_releases else ""),
                fmt_int(f.overruns) + (" ⚠️" if f.overruns else ""),
                *(fmt_ns(figure(t, name)) for name in ("slack.min", "slack.p1", "latency.mean", "latency.stddev")),
                fmt_int(figure(t, "latency.above_bound")),  # type: ignore[arg-type]
            ]
        )
    return Table(TIMING_HEADERS, rows, ["left"] + ["right"] * (len(TIMING_HEADERS) - 1)) if rows else None


EVENT_HEADERS = ["Thread", "Phase", "Event", "Measures", "Count", "p50", "p99", "Max", "Contended", "Held by"]


def events_table(cell: CellResult, labels: dict[str, str]) -> Table | None:
    """Per event of every program: how often it ran and what it took (lock wait, timer latency, run time), who held a lock."""
    rows = []
    for t in cell.threads:
        for e in t.events:
            sp = e.spread_ns
            held = ", ".join(f"{h.thread} ({fmt_int(h.contentions)}x, {fmt_ns(h.wait_ns)})" for h in e.holders)
            rows.append(
                [
                    labels[t.key],
                    md_text(e.phase),
                    md_text(e.event),
                    e.measures,
                    fmt_int(e.count),
                    *(fmt_ns(getattr(sp, q)) if sp is not None else "-" for q in ("p50", "p99", "max")),
                    fmt_int(e.contended) if e.kind == "lock" else "",
                    md_text(held),
                ]
            )
    return Table(EVENT_HEADERS, rows, ["left"] * 4 + ["right"] * 5 + ["left"]) if rows else None


PHASE_HEADERS = ["Thread", "Phase", "Passes", "Time", "Settings on entry (kernel)", "CPUs seen", "Involuntary", "Voluntary", "Minor faults"]


def phases_table(cell: CellResult, labels: dict[str, str]) -> Table | None:
    """Per phase of every program: passes, time, the settings the kernel reported on entry, CPUs, switches and faults."""
    rows = []
    for t in cell.threads:
        for p in t.phases:
            applied = f"{p.applied.label()}, cpus {p.applied.cpus_label()}" if p.applied is not None else "not entered"
            rows.append(
                [
                    labels[t.key],
                    md_text(p.name),
                    fmt_int(p.passes),
                    fmt_ns(p.time_ns),
                    applied + (" ⚠️" if p.degraded else ""),
                    ",".join(str(c) for c in p.cpus_seen) or "-",
                    fmt_int(p.involuntary),
                    fmt_int(p.voluntary),
                    fmt_int(p.minor_faults),
                ]
            )
    return Table(PHASE_HEADERS, rows, ["left", "left", "right", "right", "left", "left", "right", "right", "right"]) if rows else None


def verdict_table(cell: CellResult) -> Table | None:
    if not cell.expectations:
        return None
    rows = []
    for v in cell.expectations:
        measured = "not measured" if v.measured is None else fmt_figure(v.measured, v.figure.unit)
        rows.append(
            ["✅ pass" if v.passed else "❌ FAIL", v.thread, v.figure.words, v.limit, measured + (f" ({v.note})" if v.note else "")]
        )
    return Table(["Verdict", "Thread", "Expectation", "Limit", "Measured"], rows)


def summary_table(cells: Sequence[CellResult], repeated: bool = False) -> Table:
    """One row per cell: status, the worst periodic thread's key figures, expectations met; misses when any cell had some."""
    overloaded = any(not fg.kept_up(t.figures) for cell in cells for t in periodic_threads(cell))
    rows = []
    for cell in cells:
        threads = periodic_threads(cell)
        worst_inv = max(threads, key=lambda t: t.figures.involuntary.per_callback_mean or 0.0, default=None)
        p99s = [figure(t, "latency.p99") for t in threads]
        p99 = max((p for p in p99s if p is not None), default=None)
        passed = sum(v.passed for v in cell.expectations)
        behind = [t.figures for t in threads if not fg.kept_up(t.figures)]
        rows.append(
            [
                Markdown(f"[{md_text(section_title(cell, repeated)[5:], in_table=True)}](#{anchor(cell, repeated)})"),
                ICON[cell.status],
                ", ".join(sorted({policy_label(t.applied) for t in threads})) or "–",
                fmt_int(sum(t.figures.callbacks for t in threads)) if threads else "–",
                fmt_mean(worst_inv.figures.involuntary.per_callback_mean) if worst_inv else "–",
                fmt_ns(p99),
                f"{passed} of {len(cell.expectations)}" if cell.expectations else "–",
                f"{cell.duration_s:.1f} s",
            ]
            + ([_behind(behind)] if overloaded else [])
        )
    return Table(
        [
            "Cell",
            "Status",
            "Scheduling (periodic threads)",
            "Callbacks",
            "Involuntary / callback (worst thread)",
            "Wake-up p99 (worst thread)",
            "Expectations met",
            "Duration",
        ]
        + (["Missed releases (worst slack)"] if overloaded else []),
        rows,
        ["left", "left", "left", "right", "right", "right", "right", "right"] + (["right"] if overloaded else []),
    )


def _behind(figures: list[ThreadFigures]) -> str:
    """`48 ⚠️ (−118 ms)`: releases missed by the cell's periodic threads and their worst slack; `0` when all kept up."""
    if not figures:
        return "0"
    slack = min((f.slack_ns.min for f in figures if f.slack_ns is not None), default=None)
    return f"{sum(f.missed_releases for f in figures):,} ⚠️" + (f" ({fmt_ns(slack)})" if slack is not None else "")


def side_by_side(key: str, entries: Sequence[tuple[CellResult, ThreadResult]]) -> Table:
    """The seed's comparison: one thread, one column per cell (other vs fifo vs rr)."""

    def row(name: str, value: Any) -> list[str]:
        return [name] + [value(t) for _, t in entries]

    def lat(q: str) -> Any:
        return lambda t: fmt_ns(figure(t, f"latency.{q}"))

    rows = [
        row("Scheduling (read back from the kernel)", lambda t: policy_label(t.applied)),
        row("CPUs it ran on", lambda t: units.format_cpus(t.figures.cpus_seen) or "–"),
        row("Callbacks", lambda t: fmt_int(t.figures.callbacks)),
        row("Involuntary switches per callback (mean)", lambda t: fmt_mean(t.figures.involuntary.per_callback_mean)),
        row("Involuntary switches per callback (max)", lambda t: fmt_int(t.figures.involuntary.per_callback_max)),
        row("Callbacks preempted at least once", lambda t: fmt_int(t.figures.involuntary.callbacks_with_any)),
        row("Voluntary switches (total)", lambda t: fmt_int(t.figures.voluntary.total)),
        row("Wake-up latency p50", lat("p50")),
        row("Wake-up latency p99", lat("p99")),
        row("Wake-up latency max", lat("max")),
        row("Wake-up latency mean ± std dev", lambda t: f"{fmt_ns(figure(t, 'latency.mean'))} ± {fmt_ns(figure(t, 'latency.stddev'))}"),
        row("Releases missed", lambda t: fmt_int(t.figures.missed_releases)),
        row("Overruns", lambda t: fmt_int(t.figures.overruns)),
        row("Slack, worst", lambda t: fmt_ns(figure(t, "slack.min"))),
        row("Minor page faults after the first callback", lambda t: fmt_int(t.figures.faults.minor_after_first)),
    ]
    return Table(["Figure"] + [cell.id for cell, _ in entries], rows, ["left"] + ["right"] * len(entries))


def spread_table(cells: Sequence[CellResult], labels: dict[str, str]) -> Table | None:
    """For repeated cells: each periodic thread's key figures as median (min – max) over the repeats."""
    groups: dict[tuple[str, str], list[ThreadResult]] = {}
    for cell in cells:
        for t in periodic_threads(cell):
            groups.setdefault((cell.id, t.key), []).append(t)
    if not any(len(ts) > 1 for ts in groups.values()):
        return None

    def spread(values: list[Number | None], fmt: Any) -> str:
        present = sorted(v for v in values if v is not None)
        if not present:
            return "–"
        mid = statistics.median(present)
        return fmt(mid) if len(present) == 1 else f"{fmt(mid)} ({fmt(present[0])} – {fmt(present[-1])})"

    rows = []
    for (cell_id, key), ts in groups.items():
        rows.append(
            [
                cell_id,
                labels[key],
                str(len(ts)),
                spread([t.figures.involuntary.per_callback_mean for t in ts], fmt_mean),
                *(spread([figure(t, name) for t in ts], fmt_ns) for name in ("latency.p50", "latency.p99", "latency.max")),
            ]
        )
    return Table(
        ["Cell", "Thread", "Repeats", "Involuntary / callback", "Wake-up p50", "Wake-up p99", "Wake-up max"],
        rows,
        ["left", "left", "right", "right", "right", "right", "right"],
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
    missing = len([c for c in doc.cell_ids if c not in {cell.id for cell in doc.cells}])
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
        ["Command", md_code(" ".join(doc.command), in_table=True)],
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
    switches: Table
    timing: Table | None
    events: Table | None
    phases: Table | None
    verdicts: Table | None
    degraded: list[str]
    load: Markdown


@dataclass
class ThreadView:
    label: str
    side_by_side: Table | None
    plots: list[Plot]
    cells: int


@dataclass
class ReportModel:
    title: str
    description: str
    facts: Table
    findings: list[Markdown]
    summary: Table | None
    spread: Table | None
    threads: list[ThreadView]
    sections: list[CellSection]
    comparison: Markdown | None = None
    notes: list[str] = field(default_factory=list)


def _load_line(cell: CellResult) -> Markdown:
    hogs = [b for b in cell.background if b.kind is BackgroundKind.HOG]
    commands = [b for b in cell.background if b.kind is BackgroundKind.COMMAND]
    parts = []
    if hogs:
        parts.append(f"{len(hogs)} busy-loop hog{'s' if len(hogs) != 1 else ''}")
    parts += [md_code(" ".join(c.argv)) for c in commands]
    return Markdown(", ".join(parts) or "none")


def build(doc: RunDocument, plots: dict[str, list[Plot]] | None = None, comparison: str | None = None, pid_width: int = 5) -> ReportModel:
    """Everything the template shows, as text and tables; `plots` maps a thread key to its plot files."""
    plots = plots or {}
    order = {cell_id: i for i, cell_id in enumerate(doc.matrix_cells)}
    cells = sorted(doc.cells, key=lambda c: (order.get(c.id, len(order)), c.repeat))  # matrix order, not run order
    labels = thread_labels(cells)
    repeated = any(c.repeat for c in cells)
    firsts = first_runs(cells)
    matrix = len(firsts) > 1
    threads = []
    for key, entries in _by_thread(firsts).items():
        shown = entries[:MAX_SIDE_BY_SIDE]
        threads.append(ThreadView(labels[key], side_by_side(key, shown) if matrix else None, plots.get(key, []), len(entries)))
    sections = [
        CellSection(
            cell=cell,
            title=section_title(cell, repeated),
            anchor=anchor(cell, repeated),
            icon=ICON[cell.status],
            finding=cell_finding(cell, labels),
            ps=md_code_block(render_ps(cell.thread_table, pid_width=pid_width), "text") if cell.thread_table else None,
            switches=switch_table(cell, labels),
            timing=timing_table(cell, labels),
            events=events_table(cell, labels),
            phases=phases_table(cell, labels),
            verdicts=verdict_table(cell),
            degraded=[f"{labels[t.key]}: {why}" for t in cell.threads for why in t.degraded],
            load=_load_line(cell),
        )
        for cell in cells
    ]
    findings = matrix_finding(firsts, labels) if matrix else []
    if not findings:
        findings = [
            Markdown(f"{md_text(cell.id)}: {cell_finding(cell, labels)}") if matrix else cell_finding(cell, labels) for cell in firsts
        ]
    findings += system.placement_findings(cells, doc.machine, labels, matrix)
    if repeated:
        findings.append(
            Markdown(
                "Cells ran more than once: the side-by-side view and these findings show each cell's "
                "first run; the spread table shows every repeat."
            )
        )
    notes = []
    if any(len(v.side_by_side.rows[0]) - 1 < v.cells for v in threads if v.side_by_side):
        notes.append(f"The side-by-side view shows the first {MAX_SIDE_BY_SIDE} cells; the summary table has them all.")
    return ReportModel(
        title=f"{doc.name}: scheduling report",
        description=doc.scenario.description,
        facts=facts(doc),
        findings=findings,
        summary=summary_table(cells, repeated) if len(cells) > 1 else None,
        spread=spread_table(cells, labels),
        threads=threads,
        sections=sections,
        comparison=Markdown(comparison) if comparison else None,
        notes=notes,
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


def render_run(doc: RunDocument, plots: dict[str, list[Plot]] | None = None, comparison: str | None = None, pid_width: int = 5) -> str:
    return render(build(doc, plots, comparison, pid_width))


# ---------------------------------------------------------------- comparison with a baseline

VERDICT_ICON = {
    "regression": "❌ regression",
    "better": "🟢 better",
    "within threshold": "✅ within threshold",
    "no baseline": "🆕 no baseline",
    "missing": "➖ missing",
}


@dataclass
class ComparisonModel:
    headline: Markdown
    facts: Table
    regressions: Table | None
    cells: Table
    figures: Table | None
    notes: list[str]


def build_comparison(cmp: Comparison, base_name: str, new_name: str) -> ComparisonModel:
    """What the comparison section shows: a headline, regressions first, then every figure compared."""
    labels = thread_labels(cmp.base.cells + cmp.new.cells)
    regressed = cmp.regressed_cells()
    total = len(cmp.compared())
    headline = (
        f"❌ **{cmp.regressions} regression{'s' if cmp.regressions != 1 else ''}** in {len(regressed)} of {total} "
        f"cell{'s' if total != 1 else ''}: {', '.join(md_text(c) for c in regressed)}"
        if regressed
        else f"✅ No regression in {total} cell{'s' if total != 1 else ''} compared with the baseline."
    )
    gone, new_cells = cmp.unmatched("missing"), cmp.unmatched("no baseline")
    if gone:
        headline += f" {len(gone)} cell{'s' if len(gone) != 1 else ''} of the baseline not in this run: {', '.join(map(md_text, gone))}."
    if new_cells:
        headline += f" {len(new_cells)} cell{'s' if len(new_cells) != 1 else ''} not in the baseline: {', '.join(map(md_text, new_cells))}."
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
    notes = ["Regression thresholds: " + "; ".join(f"{fg.figure(t.figure).words} {t.describe()}" for t in cmp.thresholds) + "."] + list(
        cmp.notes
    )

    def figure_rows(items: Iterable[Any]) -> list[list[str]]:
        return [
            [
                f.cell,
                labels.get(f.thread, f.thread),
                f.figure.words,
                format_value(f, "base"),
                format_value(f, "new"),
                change_text(f),
                f.threshold.describe(),
                VERDICT_ICON[f.verdict],
            ]
            for f in items
        ]

    headers = ["Cell", "Thread", "Figure", "Baseline", "This run", "Change", "Threshold", "Verdict"]
    bad = [f for f in cmp.figures if f.verdict == "regression"]
    status_rows = [
        [
            c.cell,
            c.base_status.value if c.base_status else "–",
            c.new_status.value if c.new_status else "–",
            VERDICT_ICON["regression" if c.cell in regressed else c.verdict] + (f" ({c.note})" if c.note else ""),
        ]
        for c in cmp.cells
    ]
    return ComparisonModel(
        headline=Markdown(headline),
        facts=facts,
        regressions=Table(headers, figure_rows(bad)) if bad else None,
        cells=Table(["Cell", "Baseline status", "Status now", "Verdict"], status_rows),
        figures=Table(headers, figure_rows(cmp.figures)) if cmp.figures else None,
        notes=notes,
    )


def change_text(f: FigureChange) -> str:
    """`+200 µs (+200%)`: how much a compared figure moved."""
    if f.base is None or f.new is None:
        return "–"
    delta = f.new - f.base
    text = ("+" if delta >= 0 else "−") + fmt_figure(abs(delta), f.figure.unit)
    if f.base:
        text += f" ({delta / abs(f.base) * 100:+.0f}%)"
    return text


def format_value(f: FigureChange, which: str) -> str:
    return fmt_figure(f.base if which == "base" else f.new, f.figure.unit)


def render_comparison(cmp: Comparison, base_name: str, new_name: str) -> Markdown:
    """The comparison as a markdown section (`## Comparison with the baseline`)."""
    text = environment().get_template("compare.md.j2").render(c=build_comparison(cmp, base_name, new_name))
    return Markdown(re.sub(r"\n{3,}", "\n\n", text).strip("\n") + "\n")
