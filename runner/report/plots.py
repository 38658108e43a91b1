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
from runner.results.samplesfile import SampleRow, read_samples
from runner.safefs import make_folders, write_atomic

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


@dataclass(frozen=True)
class Series:
    label: str
    latency: Histogram | None  # wake-up latency of every release answered, ns
    involuntary: list[int]  # involuntary switches in each callback, in order (empty without a samples file)


# ---------------------------------------------------------------- data


def _label(cell: CellResult) -> str:
    label = cell.id if not cell.repeat else f"{cell.id} #{cell.repeat + 1}"
    return " " + label if label.startswith("_") else label  # matplotlib leaves `_...` labels out of the legend


class _Samples:
    """Samples files read once per cell, only the rows of the threads asked for."""

    def __init__(self, doc: RunDocument, wanted: set[str]):
        self.doc, self.wanted = doc, wanted
        self.cache: dict[int, dict[str, list[SampleRow]]] = {}

    def rows(self, cell: CellResult, key: str) -> list[SampleRow]:
        if id(cell) not in self.cache:
            path = self.doc.samples_path(cell)
            self.cache[id(cell)] = read_samples(path, self.wanted) if path else {}
        return self.cache[id(cell)].get(key, [])


def _latency(t: ThreadResult, cell: CellResult, samples: _Samples) -> Histogram | None:
    """A thread's wake-up latency histogram: the native one, or (results from before those) built from its samples."""
    if t.histograms is not None and t.histograms.latency is not None:
        return t.histograms.latency
    return histogram.from_values(r.latency_ns for r in samples.rows(cell, t.key))


def _series(label: str, t: ThreadResult, cell: CellResult, samples: _Samples) -> Series:
    return Series(label, _latency(t, cell, samples), [r.nivcsw for r in samples.rows(cell, t.key)])


def _aggregate(cell: CellResult, samples: _Samples, label: str) -> Series:
    """Every periodic thread of `cell` as one latency histogram (the aggregate line); no switch series."""
    return Series(label, histogram.merge(_latency(t, cell, samples) for t in callback_threads(cell)), [])


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
    """Involuntary context switches in each callback, one panel per series (shared axes), so lines at 0 stay apart."""
    plt = _pyplot()
    drawn = [s for s in series if s.involuntary] or list(series[:1])
    fig, axes = plt.subplots(len(drawn), 1, figsize=(9, 0.5 + 0.75 * len(drawn)), sharex=True, sharey=True, squeeze=False)
    top = max((max(s.involuntary, default=0) for s in drawn), default=0)
    for i, (s, ax) in enumerate(zip(drawn, axes[:, 0])):
        ax.step(range(1, len(s.involuntary) + 1), s.involuntary, where="mid", linewidth=1.1, **style(i))
        ax.set_ylim(-0.5, max(1, top) * 1.15 + 0.5)
        ax.text(1.01, 0.5, s.label, transform=ax.transAxes, va="center", ha="left", fontsize=7)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("callback")
    axes[len(drawn) // 2, 0].set_ylabel("involuntary switches")
    axes[0, 0].set_title(_title(f"{title}: involuntary context switches per callback", len(series), total or len(series), what))
    _save(fig, path)


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
        if switches and any(s.involuntary for s in series):
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
