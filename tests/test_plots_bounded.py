"""Plots that do not grow with the run: a long run's samples are streamed into bounded digests, and drawn in bins that say so."""

from __future__ import annotations

import gzip
import tracemalloc

from hypothesis import given
from hypothesis import strategies as st
from reportdata import many_threads

from runner.report.plots import MAX_POINTS, Envelope, Series, write_plots
from runner.results.samplesfile import SAMPLE_COLUMNS


def _long_run(folder: str, callbacks: int, spike_at: int) -> None:
    """A one-thread cell whose samples file holds `callbacks` rows: one involuntary switch every 97th, 9 at `spike_at`."""
    doc = many_threads(folder, threads=1, processes=1, callbacks=10)
    cell, thread = doc.cells[0], doc.cells[0].threads[0]
    path = doc.samples_path(cell)
    assert path is not None
    tail = ",".join(["0"] * (len(SAMPLE_COLUMNS) - 10))
    with gzip.open(path, "wt", encoding="utf-8", newline="", compresslevel=1) as handle:
        handle.write(",".join(SAMPLE_COLUMNS) + "\n")
        handle.writelines(
            f"{thread.key},{thread.tid},{n},{n * 100_000},{n * 100_000 + 40_000},0,{40_000 + n % 13},0,0,"
            f"{9 if n == spike_at else int(n % 97 == 0)},{tail}\n"
            for n in range(callbacks)
        )


def _plotted(folder: str, monkeypatch) -> tuple[int, list[Series]]:
    """What writing the plots of the run in `folder` allocated at most (bytes), and the series it would draw.

    The drawing itself is left out (matplotlib under tracemalloc takes seconds); what it is handed is kept.
    """
    from runner.report import plots
    from runner.results.read import load

    drawn: list[Series] = []
    monkeypatch.setattr(plots, "latency_histogram", lambda title, series, *rest: drawn.extend(series))
    monkeypatch.setattr(plots, "involuntary_panels", lambda *args: None)
    doc = load(folder)
    tracemalloc.start()
    try:
        write_plots(doc, folder)
        return tracemalloc.get_traced_memory()[1], drawn
    finally:
        tracemalloc.stop()


def test_a_long_runs_plots_take_the_memory_of_a_short_runs(tmp_path, monkeypatch):
    """The switch plot read every row of every thread shown: 144 MB for 5 s of 4 threads at 100 us, 463 MB for 30 s."""
    short, long = str(tmp_path / "short"), str(tmp_path / "long")
    _long_run(short, 3 * MAX_POINTS, spike_at=1_234)
    _long_run(long, 60_000, spike_at=48_765)
    small, _ = _plotted(short, monkeypatch)
    large, drawn = _plotted(long, monkeypatch)
    assert large < small + 2**20, f"{small / 2**20:.1f} MiB for {3 * MAX_POINTS:,} callbacks, {large / 2**20:.1f} MiB for 60,000"
    (series,) = drawn
    assert series.involuntary is not None and series.involuntary.count == 60_000 and series.involuntary.width == 32
    assert max(series.involuntary.high) == 9  # the one callback with 9 switches, 48,765th of 60,000, is in its bin


def test_a_long_run_is_drawn_in_bins_that_the_plot_names_and_a_short_one_callback_by_callback(tmp_path):
    from runner.results.read import load

    for name, callbacks, label in (("long", 3 * MAX_POINTS, "in bins of 4 callbacks"), ("short", MAX_POINTS, "callback<")):
        folder = str(tmp_path / name)
        _long_run(folder, callbacks, spike_at=5)
        write_plots(load(folder), folder)
        svg = (tmp_path / name / "plots" / "threads.involuntary.svg").read_text()
        assert label in svg and (name == "long") == ("bins of" in svg)


@given(st.lists(st.integers(0, 50), max_size=300), st.sampled_from([2, 4, 6, 16]))
def test_an_envelope_keeps_each_bins_fewest_and_most_in_at_most_its_limit(values, limit):
    env = Envelope(limit)
    for v in values:
        env.add(v)
    assert env.count == len(values) and len(env.high) <= limit and len(env.low) == len(env.high)
    assert env.width == 1 or len(env.high) > limit // 2  # doubled only when it had to
    for i, (low, high) in enumerate(zip(env.low, env.high)):
        part = values[i * env.width : (i + 1) * env.width]
        assert (low, high) == (min(part), max(part))
    assert len(env.high) == -(-len(values) // env.width)
    edges = env.edges()
    assert len(edges) == len(env.high) + 1 and edges[-1] == len(values) + 0.5
