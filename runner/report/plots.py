"""SVG plots beside the report: wake-up latency histograms and involuntary switches over time.

For each thread that runs periodic work, two plots with every cell of the matrix
overlaid (up to MAX_SERIES):

- the wake-up latency histogram, log-scale counts as in OSADL latency plots (and a
  log latency axis, since OTHER and FIFO differ by decades under contention);
- involuntary context switches per callback, callback by callback.

Data comes from each cell's samples.csv.gz.  Output is deterministic (no dates, a
fixed SVG id salt) so re-rendering the same results gives the same files.
"""

from __future__ import annotations

import io
import math
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

from runner.report.markdown import Plot
from runner.results.document import RunDocument, ThreadResult
from runner.results.files import slug, write_atomic
from runner.results.samplesfile import read_samples

MAX_SERIES = 12


@dataclass(frozen=True)
class Series:
    label: str
    latency_us: list[float]
    involuntary: list[int]


def collect(doc: RunDocument) -> dict[str, list[Series]]:
    """Per periodic thread key, one series per cell (in cell order) read from the samples files."""
    out: dict[str, list[Series]] = {}
    for cell in doc.cells:
        periodic = [t for t in cell.threads if t.periodic and t.figures.callbacks]
        if not periodic:
            continue
        path = doc.samples_path(cell)
        data = read_samples(path) if path else {}
        for t in periodic:
            rows = data.get(t.key)
            if not rows:
                continue
            label = cell.id if not cell.repeat else f"{cell.id} #{cell.repeat + 1}"
            label = " " + label if label.startswith("_") else label  # matplotlib leaves `_...` labels out of the legend
            out.setdefault(t.key, []).append(Series(label, [r.latency_ns / 1000.0 for r in rows], [r.nivcsw for r in rows]))
    return out


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    # text.parse_math off: names are text, `$\\foo$` in a thread name must not be parsed as mathtext
    matplotlib.rcParams.update({"svg.hashsalt": "runner", "svg.fonttype": "none", "font.size": 9, "text.parse_math": False})
    import matplotlib.pyplot as plt

    return plt


def _log_bins(values: Sequence[float], count: int = 60) -> list[float]:
    low = max(min(values), 0.1)
    high = max(max(values), low * 1.01)
    a, b = math.log10(low) - 0.02, math.log10(high) + 0.02
    return [10 ** (a + (b - a) * i / count) for i in range(count + 1)]


def latency_histogram(title: str, series: Sequence[Series], path: str) -> None:
    """Wake-up latency histogram (log counts, log latency), one step line per cell."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.2))
    values = [v for s in series for v in s.latency_us]
    bins = _log_bins(values)
    for s in series:
        ax.hist([max(v, bins[0]) for v in s.latency_us], bins=bins, histtype="step", linewidth=1.4, label=s.label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(bottom=0.7)
    plain = _plain_numbers()
    ax.xaxis.set_major_formatter(plain)
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)
    ax.xaxis.set_minor_formatter(_no_numbers())
    ax.set_xlabel("wake-up latency (µs, log scale)")
    ax.set_ylabel("callbacks (log scale)")
    ax.set_title(f"{title}: wake-up latency")
    ax.grid(True, which="both", alpha=0.3)
    _legend(ax)
    _save(fig, path)


def _plain_numbers():  # type: ignore[no-untyped-def]
    from matplotlib.ticker import FuncFormatter

    return FuncFormatter(lambda value, _pos: f"{value:g}")


def _no_numbers():  # type: ignore[no-untyped-def]
    from matplotlib.ticker import NullFormatter

    return NullFormatter()


def _legend(ax) -> None:  # type: ignore[no-untyped-def]
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, title="cell", title_fontsize=7)


def involuntary_timeline(title: str, series: Sequence[Series], path: str) -> None:
    """Involuntary context switches in each callback, callback by callback, one line per cell."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 3.6))
    for s in series:
        ax.step(range(1, len(s.involuntary) + 1), s.involuntary, where="mid", linewidth=1.2, label=s.label)
    ax.set_xlabel("callback")
    ax.set_ylabel("involuntary switches")
    ax.set_title(f"{title}: involuntary context switches per callback")
    ax.set_ylim(bottom=-0.5)
    ax.grid(True, alpha=0.3)
    _legend(ax)
    _save(fig, path)


def _save(fig, path: str) -> None:  # type: ignore[no-untyped-def]
    """Draw `fig` as SVG and replace `path` with it atomically (see results.write_atomic)."""
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


def plot_name(t: ThreadResult) -> str:
    """The file name (without extension) of a thread's plots: injective over threads, safe, bounded.

    A thread whose process and name are plain words (`[A-Za-z0-9_.]`) and whose numbers are
    not negative gets the readable `process-name-main` (`process-2-name-3` for instance 2,
    thread 3): none of those parts holds a `-`, so the name splits back into them.  Any other
    thread is named after its exact key, through results.slug (readable part and a hash).
    """
    plain = _WORD.fullmatch(t.process) and _WORD.fullmatch(t.name) and t.instance >= 0 and t.index >= 0
    if not plain:
        return slug(t.key)
    parts = [t.process] + ([str(t.instance)] if t.instance else []) + [t.name, "main" if t.index == 0 else str(t.index)]
    return slug("-".join(parts))


_WORD = re.compile(r"[A-Za-z0-9_.]+")


def write_plots(doc: RunDocument, folder: str, labels: dict[str, str] | None = None) -> dict[str, list[Plot]]:
    """Write the plots of `doc` under `folder`/plots; return, per thread key, the plots (paths relative to `folder`)."""
    data = collect(doc)
    if not data:
        return {}
    threads = {t.key: t for cell in doc.cells for t in cell.threads}
    os.makedirs(os.path.join(folder, "plots"), exist_ok=True)
    out: dict[str, list[Plot]] = {}
    for key, series in data.items():
        title = (labels or {}).get(key, key)
        shown = series[:MAX_SERIES]
        name = plot_name(threads[key])
        hist = os.path.join("plots", f"{name}.latency.svg")
        inv = os.path.join("plots", f"{name}.involuntary.svg")
        latency_histogram(title, shown, os.path.join(folder, hist))
        involuntary_timeline(title, shown, os.path.join(folder, inv))
        out[key] = [Plot("wake-up latency histogram", hist), Plot("involuntary context switches per callback", inv)]
    return out
