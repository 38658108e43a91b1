"""SVG plots beside the report: wake-up latency histograms and involuntary switches, callback by callback.

The number of plots does not grow with the threads: they show the periodic threads of
interest (`markdown.threads_of_interest`: the few with the highest wake-up p99) and one
aggregate view of all periodic threads, so a 256-thread cell draws as fast as a 1-thread one.

- One cell: one latency histogram with a line per thread of interest (and the aggregate of
  every periodic thread when there are more), one switch plot with a panel per thread.
- A matrix: per thread of interest, a latency histogram with a line per cell and a switch plot
  with a panel per cell; and, when the cells have several periodic threads, the aggregate
  latency histogram with a line per cell.  At most MAX_SERIES lines or panels per plot.

The latency histograms follow OSADL's latency plots (the field's convention for cyclictest
histograms): a linear latency axis in µs, a logarithmic count axis, fixed-width bins.  They
are drawn from the results' native histograms (every release answered), or from the samples
file for results written before those existed.  Each line has its own colour and line style,
so lines stay apart past ten cells.  The switch plots put each series in its own panel, so
threads at 0 switches do not hide behind one another.

Nothing here grows with the run: the samples file is streamed once per cell, and each series
keeps a bounded digest of it (`Envelope`: at most MAX_POINTS bins of callbacks, each bin's
fewest and most switches, as long-run plotters keep a min/max envelope per pixel column;
`histogram.Counter` for the latency of results without native histograms).  A run of up to
MAX_POINTS callbacks is drawn callback by callback; a longer one in bins, which its plot says.

matplotlib is an extra (`PLOTS_EXTRA_INSTALL` from a clone): `available()` says whether it is
installed, and the report says plots were skipped when it is not.  Output is deterministic
(no dates, a fixed SVG id salt) so re-rendering the same results gives the same files.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import io
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

from runner import histogram
from runner.errors import RunnerError
from runner.histogram import Histogram
from runner.report.fmt import Markdown, md_code, md_text
from runner.report.markdown import Plot, callback_threads, first_runs, matrix_order, threads_of_interest
from runner.results.document import CellResult, RunDocument, ThreadResult
from runner.results.files import slug
from runner.results.samplesfile import scan_samples
from runner.safefs import make_folders, write_atomic

MAX_POINTS = 2048  # bins of a switch series at most: one callback each up to this many callbacks, then 2, 4, 8, ... callbacks
MAX_SERIES = 12  # lines (or panels) in one plot; beyond that the plot's title says how many it shows
MAX_BINS = 200  # bins of a latency histogram at most: the bin width is the first of 1, 2, 5, 10, 20, ... µs that keeps to it
LINE_STYLES = ("-", "--", ":", "-.")  # with the ten colours of tab10: 40 lines, no two alike


PLOTS_EXTRA_INSTALL = "pip install '.[plots]'"
"""How the README tells a user to add the plots extra (from runner's clone); the skipped note says the same words.

The README cannot import it: tests/test_report.py checks that the README still says it.
"""


def install_hint() -> str:
    """How to add what the plots extra adds: the extra as the README names it, then its requirement for other installs.

    The extra works from runner's clone (`.[plots]`); installed otherwise (pipx, a wheel), the
    requirement itself as the installed package declares it (`pip install 'matplotlib>=3.7'`)
    is what works: `pip install 'runner[plots]'` would fetch an unrelated package of that name from PyPI.
    """
    try:
        requires = importlib.metadata.requires("runner") or []
    except importlib.metadata.PackageNotFoundError:
        requires = []
    spec = next((r.split(";")[0].strip() for r in requires if r.startswith("matplotlib") and "plots" in r), "matplotlib")
    return f"the plots extra, {md_code(PLOTS_EXTRA_INSTALL)} in runner's clone, or {md_code(f'pip install {spec!r}')} into its environment"


def available() -> bool:
    """Whether matplotlib is installed (without importing it: that takes half a second)."""
    return importlib.util.find_spec("matplotlib") is not None


def skipped_note(failure: BaseException | None = None) -> Markdown:
    """The report's line when plots were asked for and not drawn: matplotlib is not installed, or drawing failed.

    A failure is said with what raised it, so the report and the JUnit file written after it are not
    lost to a plot: an error the user can act on (a samples file outside the results folder) in its
    own words, anything else as the bug in the runner it is.
    """
    if failure is None:
        return Markdown(
            f"Plots skipped: matplotlib is not installed (plotting is {install_hint()}; then {md_code('runner report')} draws them)."
        )
    if isinstance(failure, RunnerError):
        why = str(failure)
    else:
        why = f"a bug in the runner, please report it: {type(failure).__name__}: {failure}"
    return Markdown(f"Plots skipped: drawing them failed ({md_text(why)}); the rest of the report is complete.")


class Envelope:
    """A series of counts, one per callback, kept in at most `limit` bins: each bin's fewest and most.

    Streamed as the samples file is read: bins start one callback wide; when `limit` bins are
    full and another callback comes, neighbours merge pairwise and the width doubles.  So it
    holds between limit/2 and `limit` bins whatever the run's length, and the most switches of
    any callback (the spike a plot is for) is in the bin that holds it, never averaged away.
    """

    def __init__(self, limit: int = MAX_POINTS):
        assert limit >= 2 and limit % 2 == 0
        self.limit = limit
        self.width = 1  # callbacks per bin
        self.count = 0  # callbacks seen
        self.low: list[int] = []
        self.high: list[int] = []

    def add(self, value: int) -> None:
        if self.count % self.width:
            self.low[-1] = min(self.low[-1], value)
            self.high[-1] = max(self.high[-1], value)
        else:
            if len(self.high) == self.limit:  # every bin full: count is limit * width, a multiple of the width doubled
                self.low = [min(pair) for pair in zip(self.low[::2], self.low[1::2])]
                self.high = [max(pair) for pair in zip(self.high[::2], self.high[1::2])]
                self.width *= 2
            self.low.append(value)
            self.high.append(value)
        self.count += 1

    def edges(self) -> list[float]:
        """Where each bin starts on the callback axis (callback n drawn centred on n), and where the last ends."""
        return [i * self.width + 0.5 for i in range(len(self.high))] + [self.count + 0.5]


@dataclass(frozen=True)
class Series:
    label: str
    latency: Histogram | None  # wake-up latency of every release answered, ns
    involuntary: Envelope | None  # involuntary switches in each callback, in order (None without a samples file, or no rows)


# ---------------------------------------------------------------- data


def _label(cell: CellResult) -> str:
    label = cell.id if not cell.repeat else f"{cell.id} #{cell.repeat + 1}"
    return " " + label if label.startswith("_") else label  # matplotlib leaves `_...` labels out of the legend


@dataclass(frozen=True)
class _Digest:
    """What the plots keep of one thread's rows in a samples file: bounded, whatever the run's length."""

    switches: Envelope
    latency: histogram.Counter


class _Samples:
    """Samples files streamed once per cell, keeping a digest of the rows of the threads asked for."""

    def __init__(self, doc: RunDocument, wanted: set[str]):
        self.doc, self.wanted = doc, wanted
        self.cache: dict[int, dict[str, _Digest]] = {}

    def digest(self, cell: CellResult, key: str) -> _Digest | None:
        if id(cell) not in self.cache:
            path = self.doc.samples_path(cell)
            digests: dict[str, _Digest] = {}
            for row_key, row in scan_samples(path, self.wanted) if path else ():
                digest = digests.get(row_key)
                if digest is None:
                    digest = digests[row_key] = _Digest(Envelope(), histogram.Counter())
                digest.switches.add(row.nivcsw)
                digest.latency.add(row.latency_ns)
            self.cache[id(cell)] = digests
        return self.cache[id(cell)].get(key)


def _latency(t: ThreadResult, cell: CellResult, samples: _Samples) -> Histogram | None:
    """A thread's wake-up latency histogram: the native one, or (results from before those) built from its samples."""
    if t.histograms is not None and t.histograms.latency is not None:
        return t.histograms.latency
    digest = samples.digest(cell, t.key)
    return digest.latency.histogram() if digest is not None else None


def _series(label: str, t: ThreadResult, cell: CellResult, samples: _Samples) -> Series:
    digest = samples.digest(cell, t.key)
    return Series(label, _latency(t, cell, samples), digest.switches if digest is not None else None)


def _aggregate(cell: CellResult, samples: _Samples, label: str) -> Series:
    """Every periodic thread of `cell` as one latency histogram (the aggregate line); no switch series."""
    return Series(label, histogram.merge(_latency(t, cell, samples) for t in callback_threads(cell)), None)


def osadl_bins(hists: Sequence[Histogram]) -> tuple[list[float], list[list[int]]]:
    """Common fixed-width bins (µs) from 0 to the largest value, and each histogram's counts in them.

    A native bucket wider than a bin is counted at its upper end (clamped to the exact maximum),
    as `runner report --histogram` counts it, so a latency is never drawn smaller than it was.
    """
    top_us = max(0.0, max((h.max for h in hists), default=0) / 1000)
    width = next((w * 10**e for e in range(30) for w in (1, 2, 5) if w * 10**e * MAX_BINS >= top_us), 10**30)
    bins = min(MAX_BINS + 1, int(top_us // width) + 1)
    counts = []
    for h in hists:
        row = [0] * bins
        for _low, high, n in h.buckets:
            row[min(bins - 1, max(0, int(min(high, h.max) / 1000 // width)))] += n
        counts.append(row)
    return [i * width for i in range(bins + 1)], counts


# ---------------------------------------------------------------- drawing


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    # text.parse_math off: names are text, `$\\foo$` in a thread name must not be parsed as mathtext
    matplotlib.rcParams.update({"svg.hashsalt": "runner", "svg.fonttype": "none", "font.size": 9, "text.parse_math": False})
    import matplotlib.pyplot as plt

    return plt


def style(i: int) -> dict[str, object]:
    """The i-th line's colour and line style: tab10's ten colours, then again dashed, dotted, dash-dotted."""
    return {"color": f"C{i % 10}", "linestyle": LINE_STYLES[(i // 10) % len(LINE_STYLES)]}


def _title(title: str, shown: int, total: int, what: str) -> str:
    return title if shown == total else f"{title} (first {shown} of {total} {what})"


def latency_histogram(title: str, series: Sequence[Series], path: str, total: int | None = None, what: str = "cells") -> None:
    """Wake-up latency histogram as OSADL draws it: linear latency (µs), log counts, one step line per series."""
    plt = _pyplot()
    drawn = [s for s in series if s.latency is not None]
    fig, ax = plt.subplots(figsize=(9, 4.2))
    edges, counts = osadl_bins([s.latency for s in drawn if s.latency is not None])
    for i, (s, row) in enumerate(zip(drawn, counts)):
        ax.stairs(row, edges, linewidth=1.3, label=s.label, **style(i))
    ax.set_yscale("log")
    ax.set_ylim(bottom=0.7)
    ax.set_xlim(left=0, right=edges[-1] + 2 * edges[1])  # a margin: the worst release stays clear of the frame
    ax.yaxis.set_major_formatter(_plain_numbers())
    ax.set_xlabel(f"wake-up latency (µs; bins of {edges[1]:g} µs)")
    ax.set_ylabel("releases (log scale)")
    ax.set_title(_title(f"{title}: wake-up latency", len(series), total or len(series), what))
    ax.grid(True, which="major", alpha=0.3)
    _legend(ax, "cell" if what == "cells" else "thread")
    _save(fig, path)


def involuntary_panels(title: str, series: Sequence[Series], path: str, total: int | None = None, what: str = "cells") -> None:
    """Involuntary context switches in each callback, one panel per series (shared axes), so lines at 0 stay apart.

    A series of more than MAX_POINTS callbacks comes in bins (`Envelope`): its line is each bin's
    most switches, under it a band down to the bin's fewest, and the axis says how wide the bins are.
    """
    plt = _pyplot()
    drawn = [s for s in series if s.involuntary is not None and s.involuntary.count] or list(series[:1])
    fig, axes = plt.subplots(len(drawn), 1, figsize=(9, 0.5 + 0.75 * len(drawn)), sharex=True, sharey=True, squeeze=False)
    top = max((max(s.involuntary.high, default=0) for s in drawn if s.involuntary is not None), default=0)
    for i, (s, ax) in enumerate(zip(drawn, axes[:, 0])):
        env = s.involuntary
        if env is not None and env.width == 1:  # callback by callback
            ax.step(range(1, env.count + 1), env.high, where="mid", linewidth=1.1, **style(i))
        elif env is not None:
            edges = env.edges()
            low, high = env.low + env.low[-1:], env.high + env.high[-1:]  # step="post" draws the last value to the last edge
            ax.fill_between(edges, low, high, step="post", alpha=0.3, linewidth=0, color=style(i)["color"])
            ax.step(edges, high, where="post", linewidth=1.1, **style(i))
        ax.set_ylim(-0.5, max(1, top) * 1.15 + 0.5)
        ax.text(1.01, 0.5, s.label, transform=ax.transAxes, va="center", ha="left", fontsize=7)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel(_callback_axis([s.involuntary.width for s in drawn if s.involuntary is not None]))
    axes[len(drawn) // 2, 0].set_ylabel("involuntary switches")
    axes[0, 0].set_title(_title(f"{title}: involuntary context switches per callback", len(series), total or len(series), what))
    _save(fig, path)


def _callback_axis(widths: Sequence[int]) -> str:
    """The callback axis's label, saying when series are drawn in bins and how wide they are."""
    binned = sorted({w for w in widths if w > 1})
    if not binned:
        return "callback"
    size = f"{binned[0]:,}" if len(binned) == 1 else f"{binned[0]:,} to {binned[-1]:,}"
    return f"callback (in bins of {size} callbacks: the line is each bin's most switches, the band its fewest to most)"


def _plain_numbers():  # type: ignore[no-untyped-def]
    from matplotlib.ticker import FuncFormatter

    return FuncFormatter(lambda value, _pos: f"{value:g}")


def _legend(ax, title: str) -> None:  # type: ignore[no-untyped-def]
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, title=title, title_fontsize=7)


def _save(fig, path: str) -> None:  # type: ignore[no-untyped-def]
    """Draw `fig` as SVG and replace `path` with it atomically, never through a link (safefs.write_atomic)."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    try:
        with warnings.catch_warnings():  # text stays text in the SVG (svg.fonttype none): the viewer's fonts draw it
            warnings.filterwarnings("ignore", message="Glyph .* missing from font")
            fig.tight_layout()
            fig.savefig(buf, format="svg", metadata={"Date": None})
    finally:
        plt.close(fig)
    write_atomic(path, buf.getvalue())


# ---------------------------------------------------------------- files


def plot_name(t: ThreadResult) -> str:
    """The file name (without extension) of a thread's plots: injective over threads, safe, bounded.

    A thread whose process and name are plain words (`[A-Za-z0-9_.]`) and whose numbers are
    not negative gets the readable `process-name-main` (`process-2-name-3` for instance 2,
    thread 3): none of those parts holds a `-`, so the name splits back into them.  Any other
    thread is named after its exact key, through results.slug (readable part and a hash).
    Neither kind is `threads` or `all-threads`, the names of the plots of several threads.
    """
    plain = _WORD.fullmatch(t.process) and _WORD.fullmatch(t.name) and t.instance >= 0 and t.index >= 0
    if not plain:
        return slug(t.key)
    parts = [t.process] + ([str(t.instance)] if t.instance else []) + [t.name, "main" if t.index == 0 else str(t.index)]
    return slug("-".join(parts))


_WORD = re.compile(r"[A-Za-z0-9_.]+")


def write_plots(doc: RunDocument, folder: str, labels: dict[str, str] | None = None) -> list[Plot]:
    """Write the plots of `doc` under `folder`/plots; return them in the report's order (paths relative to `folder`)."""
    labels = labels or {}
    ordered = matrix_order(doc)  # as the report orders them, so both pick the same threads of interest
    cells = [c for c in ordered if any(t.figures.callbacks for t in callback_threads(c))]
    # of the cells drawn only: a thread only a cell without callbacks has (one that errored) has nothing to draw
    keys = threads_of_interest(first_runs(cells))
    if not cells or not keys:
        return []
    make_folders(folder, "plots")  # a link named plots (a folder elsewhere) is refused, never written into
    # rows of the threads of interest (their switches), and of any periodic thread without a native histogram (old results)
    samples = _Samples(doc, set(keys) | {t.key for c in cells for t in callback_threads(c) if _no_histogram(t)})
    out: list[Plot] = []

    def draw(name: str, title: str, series: list[Series], total: int, what: str, switches: bool = True) -> None:
        hist = os.path.join("plots", f"{name}.latency.svg")
        latency_histogram(title, series, os.path.join(folder, hist), total, what)
        out.append(Plot(f"{title}: wake-up latency histogram", hist))
        if switches and any(s.involuntary is not None and s.involuntary.count for s in series):
            inv = os.path.join("plots", f"{name}.involuntary.svg")
            involuntary_panels(title, series, os.path.join(folder, inv), total, what)
            out.append(Plot(f"{title}: involuntary context switches per callback", inv))

    periodic_keys = {t.key for c in cells for t in callback_threads(c)}
    if len({c.id for c in cells}) == 1:  # one cell (repeats aside): its threads of interest side by side
        cell = cells[0]
        by_key = {t.key: t for t in cell.threads}
        series = [_series(labels.get(k, k), by_key[k], cell, samples) for k in keys if k in by_key]
        if len(periodic_keys) > len(series):
            series.append(_aggregate(cell, samples, f"all {len(periodic_keys)} periodic threads"))
        title = f"{len(keys)} of {len(periodic_keys)} periodic threads" if len(periodic_keys) > len(keys) else "periodic threads"
        draw("threads", title, series, len(series), "threads")
        return out
    shown = cells[:MAX_SERIES]
    for key in keys:
        entries = [(c, next(t for t in c.threads if t.key == key)) for c in cells if any(t.key == key for t in c.threads)]
        if not entries:
            continue
        series = [_series(_label(c), t, c, samples) for c, t in entries[:MAX_SERIES]]
        thread = entries[0][1]
        draw(plot_name(thread), labels.get(key, key), series, len(entries), "cells")
    if len(periodic_keys) > 1:
        series = [_aggregate(c, samples, _label(c)) for c in shown]
        draw("all-threads", f"all {len(periodic_keys)} periodic threads", series, len(cells), "cells", switches=False)
    return out


def _no_histogram(t: ThreadResult) -> bool:
    return t.histograms is None or t.histograms.latency is None
