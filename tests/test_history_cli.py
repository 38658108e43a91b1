"""--history on `runner merge` (and a run): nights judged and added, verdicts in the report, JUnit and exit code, and a
history that cannot be used never costs the night its results."""

from __future__ import annotations

import json
import sqlite3
import xml.etree.ElementTree as ET

from conftest import run_cli
from reportdata import heavy_tail, latencies, main_thread, matrix, with_latencies
from test_history_store import night

FIFO = "policy=fifo,priority=80"


def merged(tmp_path, name: str, doc, history: str, *args: str):
    """`runner merge` of one results folder holding `doc`, with --history; (outcome, merged folder)."""
    source = tmp_path / f"{name}-in"
    source.mkdir()
    doc.save(str(source / "results.json"))
    out = tmp_path / name
    done = run_cli("merge", str(source), "--out", str(out), "--no-plots", "--history", history, *args)
    return done, out


def test_nights_are_judged_against_their_history_and_a_planted_regression_fails_naming_thread_and_figure(tmp_path):
    history = str(tmp_path / "history.sqlite")
    for n in range(6):
        done, out = merged(tmp_path, f"n{n}", night(24 * n, seed=n), history)
        assert done.code == 0, done.out + done.err
    report = (out / "report.md").read_text()
    assert "## Against the history" in report and "✅ within history" in report
    assert "No regression against the history" in done.out
    worse = with_latencies(night(24 * 6), FIFO, heavy_tail(latencies(2_000, seed=99), share=0.05, factor=4))
    done, out = merged(tmp_path, "n6", worse, history, "--junit", str(tmp_path / "j.xml"))
    assert done.code == 1, done.out + done.err
    key = main_thread(matrix().cells[1]).key
    assert f"regression against the history in 1 cell: latency.p99 of {key} ({FIFO})" in done.out
    report = (out / "report.md").read_text()
    assert "regression: p99" in report and "outside the 6 nights' range" in report
    failures = ET.parse(tmp_path / "j.xml").getroot().findall(".//failure")
    assert [f.get("type") for f in failures] == ["regression against the history"]
    assert "latency.p99" in failures[0].get("message", "") or "wake-up latency p99" in failures[0].get("message", "")


def test_the_next_night_of_the_same_step_is_not_failed_again(tmp_path):
    history = str(tmp_path / "history.sqlite")
    for n in range(6):
        assert merged(tmp_path, f"n{n}", night(24 * n, seed=n), history)[0].code == 0
    step = [heavy_tail(latencies(2_000, seed=50 + n), share=0.05, factor=4) for n in range(2)]
    assert merged(tmp_path, "n6", with_latencies(night(24 * 6), FIFO, step[0]), history)[0].code == 1
    done, out = merged(tmp_path, "n7", with_latencies(night(24 * 7), FIFO, step[1]), history)
    assert done.code == 0, done.out
    assert "continues the change of 2026-11-07" in (out / "report.md").read_text()


def test_a_corrupt_history_is_invalid_input_and_the_nights_results_are_kept(tmp_path):
    history = tmp_path / "history.sqlite"
    history.write_bytes(b"not a database " * 1000)
    done, out = merged(tmp_path, "n0", night(0), str(history))
    assert done.code == 2, done.out + done.err
    assert "not a runner history, or a corrupt one" in done.err
    assert json.loads((out / "results.json").read_text())["cells"]  # the night's results are written first, and kept
    assert (out / "report.md").exists()


def test_a_history_of_a_newer_schema_is_refused_and_left_as_it_is(tmp_path):
    history = str(tmp_path / "history.sqlite")
    assert merged(tmp_path, "n0", night(0), history)[0].code == 0
    with sqlite3.connect(history) as db:
        db.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
    done, out = merged(tmp_path, "n1", night(24), history)
    assert done.code == 2 and "its schema is version 2, this runner knows up to 1" in done.err
    assert (out / "results.json").exists()
    with sqlite3.connect(history) as db:
        assert db.execute("SELECT COUNT(*) FROM nights").fetchone() == (1,)


def test_a_locked_history_is_a_run_error_and_the_results_are_kept(tmp_path, monkeypatch):
    history = str(tmp_path / "history.sqlite")
    assert merged(tmp_path, "n0", night(0), history)[0].code == 0
    monkeypatch.setenv("RUNNER_HISTORY_TIMEOUT", "0.3")
    holder = sqlite3.connect(history, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        done, out = merged(tmp_path, "n1", night(24), history)
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert done.code == 4 and "locked by another writer" in done.err, done.err
    assert (out / "results.json").exists()


def test_threshold_is_taken_with_history_alone():
    done = run_cli("merge", "x", "--out", "y", "--threshold", "latency.p99=+50%")
    assert done.code == 2 and "give --baseline RESULTS or --history FILE too" in done.err


def test_a_run_with_history_adds_its_night_after_its_results_are_written(tmp_path, capsys):
    from fakebackend import Act, FakeBackend
    from test_session import FIFO80, run

    from runner.history.store import open_store

    history = str(tmp_path / "h.sqlite")
    code, doc = run(FIFO80, tmp_path / "r", FakeBackend({"default": Act(latency_ns=50_000)}), "--duration", "1s", "--history", history)
    assert code == 0 and doc["cells"]
    assert "Nothing judged against the history yet" in capsys.readouterr().out
    assert "## Against the history" in (tmp_path / "r" / "report.md").read_text()
    with open_store(history) as store:
        (only,) = store.nights()
        assert only.results.endswith("results.json") and only.environment["runner"]


def test_runner_history_imports_old_results_and_writes_a_trend_report_with_plots(tmp_path):
    folders = []
    for n in range(7):
        doc = night(24 * n, seed=n, kernel="6.12.8" if n < 6 else "6.12.9")
        if n == 6:
            doc = with_latencies(doc, FIFO, heavy_tail(latencies(2_000, seed=77), share=0.05, factor=4))
        folder = tmp_path / f"r{n}"
        folder.mkdir()
        doc.save(str(folder / "results.json"))
        folders.append(str(folder))
    history = str(tmp_path / "h.sqlite")
    junit = tmp_path / "j.xml"
    done = run_cli("history", history, "--import", *reversed(folders), "--junit", str(junit), "--out", str(tmp_path / "trend"))
    assert done.code == 0, done.out + done.err
    assert done.out.count("❌ 1 regression against the history") == 1  # the last night, imported last though given first
    report = (tmp_path / "trend" / "history.md").read_text()
    assert "## Changes of environment" in report and "kernel 6.12.8 → 6.12.9" in report
    assert f"## vm · {FIFO} · " in report and "p99.99" in report
    assert "❌ latency.p99" in report  # the night of the change, in the thread's table
    plots = list((tmp_path / "trend" / "plots").glob("*.svg"))
    assert len(plots) == 5 and all(p.stat().st_size > 1_000 for p in plots)
    assert "regression against the history" in junit.read_text()
    only = run_cli("history", history, "--cell", FIFO, "--since", "2026-11-03", "--out", str(tmp_path / "only"), "--no-plots")
    assert only.code == 0, only.err
    text = (tmp_path / "only" / "history.md").read_text()
    assert text.count("\n## vm · ") == 1 and "2026-11-01" not in text.split("## vm")[1]
