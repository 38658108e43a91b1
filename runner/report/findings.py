"""The report's words about threads: labels, scheduling as people say it, and the findings.

A finding is one sentence on a thread, a cell or the whole matrix (`thread_finding`,
`cell_finding`, `matrix_finding`): what it held, whether it kept up, its wake-up p99.  The
tables, the report and the comparison view (`tables`, `markdown`, `compareview`) build on the
labels and helpers here.  Pure: results in, markdown text out.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from runner import figures as fg
from runner import units
from runner.figures import Number
from runner.report.fmt import LEFT, Markdown, fmt_int, fmt_mean, fmt_ns, md_text, pipe_table
from runner.results.document import CellResult, Status, ThreadResult
from runner.results.threadfigures import ThreadFigures
from runner.scenario.model import Policy
from runner.scenario.plan import Settings

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
    if not threads and cell.callbacks:
        return Markdown("No thread of the runner's own runs periodic work; the ROS 2 callbacks of its programs are measured below.")
    if not threads:
        return Markdown("No thread runs periodic work, so there are no per-callback figures; see the switch counts below.")
    return Markdown("; ".join(thread_finding(t, labels[t.key]) for t in threads) + ".")


def matrix_finding(cells: Sequence[CellResult], labels: dict[str, str]) -> list[Markdown]:
    """Per periodic thread seen in several cells, one sentence: its figures per policy, most preempted first.

    e.g. `at OTHER 8.94 involuntary switches per callback (98 of 99 callbacks preempted), wake-up p99 7.43 ms;
    at FIFO 10, 80: 0 per callback, p99 96.3 µs – 117 µs`.
    """
    out: list[Markdown] = []
    for key, entries in entries_by_thread(cells).items():
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


def entries_by_thread(cells: Sequence[CellResult]) -> dict[str, list[tuple[CellResult, ThreadResult]]]:
    out: dict[str, list[tuple[CellResult, ThreadResult]]] = {}
    for cell in cells:
        for t in callback_threads(cell):
            out.setdefault(t.key, []).append((cell, t))
    return out
