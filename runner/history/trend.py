"""`runner history FILE`: the trend report of a history, markdown and SVG, readable on GitHub as the run's report is.

Per host, cell and thread: each night's wake-up latency p50, p99 and max (the trace's when the thread
has no callbacks), missed releases and involuntary switches per callback (or per second, for a
program's threads), the changes of level reported on their first night, and the nights whose
environment changed (kernel, its command line, governors, IRQ placement...).  Over the nights shown the
thread's histograms merge exactly, so the report gives p99.99 of the whole span, not a median of
nightly p99s.  Plots need matplotlib (the `plots` extra); without it the report says they were skipped.
"""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

from runner import figures as fg
from runner.history.environment import changes
from runner.history.store import ChangePoint, Night, Point, Store
from runner.report.fmt import LEFT, RIGHT, md_code, md_text
from runner.report.tables import Table
from runner.results.files import slug
from runner.safefs import make_folders, write_atomic

SHOWN_NIGHTS = 30  # nights in each table (the plot shows them all)
LATENCY = ("latency.p50", "latency.p99", "latency.max")
WAKEUP = ("wakeup.p50", "wakeup.p99", "wakeup.max")


@dataclass
class Thread:
    host: str
    cell: str
    spec_hash: str
    thread: str
    series: dict[str, list[Point]] = field(default_factory=dict)

    @property
    def latency(self) -> tuple[str, ...]:
        return LATENCY if any(self.series.get(name) for name in LATENCY) else WAKEUP

    @property
    def switches(self) -> str:
        return "involuntary.per_callback_mean" if self.series.get("involuntary.per_callback_mean") else "involuntary.per_second"

    def nights(self) -> list[str]:
        return sorted({p.started_at for points in self.series.values() for p in points})

    def value(self, name: str, night: str) -> float | None:
        return next((p.value for p in self.series.get(name, []) if p.started_at == night), None)


def select(store: Store, cells: Sequence[str], threads: Sequence[str], since: str) -> list[Thread]:
    """Every (host, cell, spec, thread) of the history from `since` on that the --cell and --thread globs match."""
    out: dict[tuple[str, str, str, str], Thread] = {}
    for host, cell, spec, thread, figure, point in store.all_figures(since):
        if cells and not any(fnmatch.fnmatchcase(cell, g) for g in cells):
            continue
        if threads and not any(fnmatch.fnmatchcase(thread, g) for g in threads):
            continue
        item = out.setdefault((host, cell, spec, thread), Thread(host, cell, spec, thread))
        item.series.setdefault(figure, []).append(point)
    return list(out.values())


def environment_changes(nights: Sequence[Night]) -> list[tuple[str, str, list[str]]]:
    """(night, host, what changed) for each night whose environment differs from the host's night before."""
    out = []
    last: dict[str, Night] = {}
    for n in nights:
        before = last.get(n.host)
        if before is not None:
            said = changes(before.environment, n.environment)
            if said:
                out.append((n.started_at, n.host, said))
        last[n.host] = n
    return out


def write(store: Store, target: str, folder: str, cells: Sequence[str], threads: Sequence[str], since: str, plots: bool) -> str:
    """Write `folder`/history.md (and its plots); return its path."""
    from runner.report import plots as drawing

    make_folders(folder)
    chosen = select(store, cells, threads, since)
    nights = store.nights(since=since)
    points = store.change_points()
    env = environment_changes(nights)
    draw = plots and drawing.available()
    lines = [f"# History of {md_code(target)}", ""]
    hosts = sorted({n.host for n in nights})
    span = f"from {_day(nights[0].started_at)} to {_day(nights[-1].started_at)}" if nights else "none yet"
    lines += [md_text(f"{len(nights)} nights {span}, on {', '.join(hosts) or 'no host'}; {len(chosen)} threads shown."), ""]
    if plots and not draw:
        lines += [str(drawing.skipped_note()), ""]
    if env:
        lines += [
            "## Changes of environment",
            "",
            Table(["Night", "Host", "What changed"], [[_day(a), h, "; ".join(w)] for a, h, w in env]).render(),
            "",
        ]
    for item in sorted(chosen, key=lambda t: (t.host, t.cell, t.thread)):
        lines += _thread_section(
            store,
            item,
            [c for c in points if (c.cell, c.spec_hash, c.thread) == (item.cell, item.spec_hash, item.thread)],
            env,
            folder,
            draw,
            since,
        )
    path = os.path.join(folder, "history.md")
    write_atomic(path, "\n".join(lines).rstrip("\n") + "\n")
    return path


def _thread_section(
    store: Store, item: Thread, points: list[ChangePoint], env: list[tuple[str, str, list[str]]], folder: str, draw: bool, since: str
) -> list[str]:
    title = f"{item.host} · {item.cell} · {item.thread}"
    lines = [f"## {md_text(title)}", ""]
    if draw:
        name = f"plots/{slug(item.host)}-{slug(item.cell)}-{slug(item.thread)}.svg"
        make_folders(folder, "plots")
        _plot(item, points, [(a, w) for a, h, w in env if h == item.host], os.path.join(folder, name), title)
        lines += [f"![{md_text(title)}]({name})", ""]
    nights = item.nights()
    latency = item.latency
    scale = fg.scale(fg.Unit.NS, [item.value(n, night) for n in latency for night in nights])
    headers = ["Night", *(scale.header(fg.figure(n).name.split(".")[-1]) for n in latency), "missed", "switches", "change"]
    reported = {c.started_at: c for c in points}
    rows = []
    for night in nights[-SHOWN_NIGHTS:]:
        switches = item.value(item.switches, night)
        rows.append(
            [
                _day(night),
                *(scale.number(item.value(n, night)) for n in latency),
                fg.scale(fg.Unit.COUNT).number(item.value("missed_releases", night)),
                "–" if switches is None else f"{switches:.2f}",
                ("❌ " + reported[night].figure) if night in reported else "",
            ]
        )
    if len(nights) > SHOWN_NIGHTS:
        lines += [md_text(f"The last {SHOWN_NIGHTS} of {len(nights)} nights (the plot shows them all)."), ""]
    lines += [Table(headers, rows, [LEFT] + [RIGHT] * (len(headers) - 2) + [LEFT]).render(), ""]
    for c in points:
        lines += [f"- {md_text(_day(c.started_at))}: {md_text(c.figure)}: {md_text(c.words)}"]
    if points:
        lines.append("")
    kind = "latency" if latency == LATENCY else "wakeup"
    merged = store.histogram(item.host, item.cell, item.spec_hash, item.thread, kind, since)
    if merged is not None:
        q = merged.quantiles((0.5, 0.99, 0.9999))
        sc = fg.scale(fg.Unit.NS, [*q, merged.max])
        lines += [
            md_text(
                f"Over these {len(nights)} nights ({merged.count:,} samples, every night's histogram merged): p50 {sc.number(q[0])}, "
                f"p99 {sc.number(q[1])}, p99.99 {sc.number(q[2])}, max {sc.number(merged.max)} {sc.unit}."
            ),
            "",
        ]
    return lines


def _plot(item: Thread, points: list[ChangePoint], env: list[tuple[str, list[str]]], path: str, title: str) -> None:
    from matplotlib.ticker import NullFormatter

    from runner.report.plots import _plain_numbers, _pyplot, _save, style

    plt = _pyplot()
    nights = item.nights()
    x = {night: i for i, night in enumerate(nights)}
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    for i, name in enumerate(item.latency):
        series = item.series.get(name, [])
        axes[0].plot([x[p.started_at] for p in series], [p.value / 1_000 for p in series], marker=".", label=name, **style(i))
    axes[0].set_yscale("log")
    axes[0].yaxis.set_major_formatter(_plain_numbers())
    axes[0].yaxis.set_minor_formatter(NullFormatter())
    axes[0].set_ylabel("µs (log scale)")
    axes[0].legend(fontsize=7, loc="upper left")
    for ax, name, label in ((axes[1], "missed_releases", "missed releases"), (axes[2], item.switches, "involuntary switches")):
        series = item.series.get(name, [])
        ax.plot([x[p.started_at] for p in series], [p.value for p in series], marker=".", **style(0))
        ax.set_ylim(0, max([1.0] + [p.value * 1.15 for p in series]))
        ax.set_ylabel(label, fontsize=8)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        for c in points:
            if c.started_at in x:
                ax.axvline(x[c.started_at], color="C3", linestyle="--", linewidth=1)
        for night, _ in env:
            if night in x:
                ax.axvline(x[night], color="0.5", linestyle=":", linewidth=1)
    for night, said in env:
        if night in x:
            axes[0].annotate("; ".join(said)[:60], (x[night], 1), xycoords=("data", "axes fraction"), fontsize=6, rotation=90, va="top")
    step = max(1, len(nights) // 10)
    axes[-1].set_xticks(range(0, len(nights), step), [_day(n)[:10] for n in nights[::step]], rotation=30, fontsize=7)
    axes[0].set_title(f"{title}\ndashed: a change reported; dotted: the environment changed", fontsize=8)
    _save(fig, path)


def _day(stamp: str) -> str:
    return stamp[:16].replace("T", " ")
