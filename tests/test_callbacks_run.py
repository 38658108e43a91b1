"""`callback:` expectations, callbacks in a cell's results, the report, JUnit and the schemas (issue 38), from hand-built captures."""

from __future__ import annotations

import json
import os
from pathlib import Path

import jsonschema
import pytest
from roscbbuild import BASE, MS, REALTIME, Node, capture
from test_outside import OTHER, _program, _thread

from runner.errors import ScenarioError
from runner.results.document import CellResult, RunDocument, Status, results_schema
from runner.run.evaluate import evaluate
from runner.run.rawcell import RawCell, Timeline
from runner.run.roscbdata import RosCapture
from runner.scenario.loader import load_scenario

SECOND = 1_000_000_000
END = BASE + SECOND
SCENARIO = """\
name: ros
duration: 1s
processes:
  - name: talker
    command: [talker]
expect:
  - {callback: "*tick*", metric: involuntary.per_callback_max, max: 0}
  - {callback: "*tick*", metric: missed_releases, max: 0}
  - {callback: "*on_message*", metric: message_age.p99, max: 1ms}
  - {callback: "*on_message*", metric: latency.p99, max: 1ms}
  - {callback: "*timer_callback*", metric: callbacks, min: 1}
"""


def _capture() -> RosCapture:
    n = Node(pid=500, tid=500)
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 100 * MS, BASE + 100 * MS, "Talker::tick()")
    n.node(0x11, "listener")
    n.subscription(0x11, 0x40, 0x41, 0x42, 0x43, "/chatter", "Listener::on_message(msg)")
    n.publisher(0x10, 0x50, 0x51, "/chatter")
    for k in range(1, 10):
        release = BASE + k * 100 * MS
        tick = n.run(0x30, release + 30_000, wall=200_000, nivcsw=1 if k == 3 else 0)
        src = n.publish(0x51, tick, release + 100_000)
        n.run(0x43, release + 400_000, tid=501, src_ts=src, age_ns=300_000, take_handle=0x41)
    return capture(n.process())


def _cell(tmp_path: Path, text: str = SCENARIO, cap: RosCapture | None = None, comm: str = "talker") -> CellResult:
    path = tmp_path / "ros.yaml"
    path.write_text(text)
    cell = load_scenario(os.fspath(path)).cells[0]
    program = _program(cell.scenario.programs[0], (_thread(500, 0, comm, OTHER),), callbacks=cap or _capture(), exited_ns=END + MS)
    raw = RawCell("now", (), 0, Timeline(0, BASE, END, END, END), programs=(program,))
    return evaluate(cell, cell.scenario, raw, allow_degraded=False)


def test_callback_expectations_pass_fail_and_are_not_measured_in_words(tmp_path: Path) -> None:
    result = _cell(tmp_path)
    got = [(v.thread, v.metric, v.passed, v.measured, v.samples, v.note) for v in result.expectations]
    assert got == [
        ("talker: talker/Talker::tick()", "involuntary.per_callback_max", False, 1, None, ""),
        ("talker: talker/Talker::tick()", "missed_releases", True, 0, None, ""),
        ("talker: listener/Listener::on_message(msg)", "message_age.p99", True, 300_000, 9, ""),
        (
            "talker: listener/Listener::on_message(msg)",
            "latency.p99",
            False,
            None,
            None,
            "not measured (latency.p99 is measured against a timer's releases; this is a subscription callback)",
        ),
        (
            "callback *timer_callback*",
            "callbacks",
            False,
            None,
            None,
            "not measured (no callback of that name was seen; callbacks: talker: listener/Listener::on_message(msg), "
            "talker: talker/Talker::tick())",
        ),
    ]
    assert all(v.line for v in result.expectations), "CI annotations point at the expectation"
    assert result.status is Status.FAILED
    listener = next(c for c in result.callbacks if c.kind == "subscription")
    assert listener.figures.chain_ns is not None and listener.figures.chain_ns.max == 500_000
    assert [(t.tid, t.count) for t in listener.threads] == [(501, 9)]
    assert result.programs[0].ros is not None and result.programs[0].ros.callbacks == 2


def test_a_program_without_callbacks_fails_a_callback_expectation_saying_why(tmp_path: Path) -> None:
    result = _cell(tmp_path, cap=RosCapture(loaded=False))
    assert not result.callbacks
    note = result.expectations[0].note
    assert note.startswith("not measured (no ROS 2 callback was seen: no ROS 2 callbacks seen: the runner's library was not loaded")


def test_a_timer_callback_that_could_not_keep_up_fails_its_cell_unless_the_scenario_bounds_it(tmp_path: Path) -> None:
    """As a periodic thread of the runner's own: an implicit verdict, replaced by a callback: bound on missed_releases,
    and then a warning in words."""
    n = Node(pid=500, tid=500)
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 100 * MS, BASE + 100 * MS, "Talker::tick()")
    n.run(0x30, BASE + 100 * MS)
    n.run(0x30, BASE + 900 * MS)  # served release 8: releases 1 to 7 were missed
    bare = SCENARIO.split("expect:")[0]
    result = _cell(tmp_path, bare, capture(n.process()))
    (verdict,) = result.expectations
    assert (verdict.thread, verdict.metric, verdict.measured, verdict.passed) == (
        "talker: talker/Talker::tick()",
        "missed_releases",
        7,
        False,
    )
    assert verdict.note.startswith("could not keep up: missed 7 of 9 releases")
    assert result.status is Status.FAILED and not any("could not keep up" in w for w in result.warnings)
    bounded = _cell(tmp_path, bare + "expect:\n  - {callback: '*tick*', metric: missed_releases, max: 10}\n", capture(n.process()))
    assert [(v.metric, v.passed) for v in bounded.expectations] == [("missed_releases", True)]
    assert bounded.status is Status.PASSED
    assert any(w.startswith("callback talker: talker/Talker::tick() could not keep up: missed 7 of 9 releases") for w in bounded.warnings)


@pytest.mark.parametrize(
    "expect, words",
    [
        ("{callback: '*x*', metric: involuntary.total, max: 1}", "involuntary.total is measured for every thread, not per ROS 2 callback"),
        ("{callback: '*x*', metric: cpu_time, max: 1ms}", "a callback has callbacks, releases, missed_releases"),
        ("{callback: '*x*', thread: talker, metric: callbacks, min: 1}", "exactly one of thread: (a thread's name) and callback:"),
        ("{metric: callbacks, min: 1}", "exactly one of thread:"),
        ("{thread: own/a, metric: message_age.p99, max: 1ms}", "message_age.p99 is measured per message a ROS 2 callback took"),
    ],
)
def test_callback_expectations_are_refused_where_they_can_never_apply(tmp_path: Path, expect: str, words: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        "name: bad\nprocesses:\n  - name: talker\n    command: [talker]\n"
        "  - name: own\n    threads: [{name: a, work: {kind: periodic, period: 10ms}}]\n"
        f"expect:\n  - {expect}\n"
    )
    with pytest.raises(ScenarioError) as err:
        load_scenario(os.fspath(path))
    assert words in str(err.value)


def test_a_callback_expectation_needs_a_program_with_callbacks(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        "name: bad\nprocesses:\n  - name: talker\n    command: [talker]\n    callbacks: off\n"
        "expect:\n  - {callback: '*', metric: callbacks, min: 1}\n"
    )
    with pytest.raises(ScenarioError) as err:
        load_scenario(os.fspath(path))
    assert "bad.yaml:7:" in str(err.value) and "a callback: expectation needs a command: program with callbacks on" in str(err.value)


def test_callbacks_are_stored_in_the_results_schema_and_read_back(tmp_path: Path) -> None:
    from runner.results.read import load

    result = _cell(tmp_path)
    doc = RunDocument.model_validate({"scenario": {"name": "ros"}, "cells": [result.model_dump()]})
    path = tmp_path / "results.json"
    doc.save(os.fspath(path))
    data = json.loads(path.read_text())
    jsonschema.validate(data, results_schema())
    back = load(os.fspath(path)).cells[0]
    assert back.callbacks == result.callbacks and back.programs[0].ros == result.programs[0].ros
    stored = json.loads((Path(__file__).parent.parent / "results.schema.json").read_text())
    assert stored == results_schema(), "runner schema --results > results.schema.json"
    assert REALTIME


def _traced(cell: CellResult) -> CellResult:
    """The cell as if the scheduler trace had followed the talker's main thread: a hog preempted it during its third tick."""
    from runner.results.document import PreemptedRun, Preemptor

    hog = Preemptor(comm="hog0", tid=900, pid=900, cls="TS", count=1)
    thread = cell.threads[0]
    run = PreemptedRun(at_ns=300 * MS + 40_000, wall_ns=150_000, preempted_ns=60_000, preemptions=1, by=hog, by_ns=60_000)
    traced = thread.model_copy(
        update={"figures": thread.figures.model_copy(update={"preemptions": 1}), "preempted_by": [hog], "preempted_runs": [run]}
    )
    return cell.model_copy(update={"threads": [traced]})


def test_the_report_has_a_callbacks_table_per_program_words_and_the_slowest_joined_with_the_trace(tmp_path: Path) -> None:
    from test_report import golden

    from runner.report.markdown import render_run

    cell = _traced(_cell(tmp_path, comm="tk"))  # a short name: the table of figures from outside is a wide one
    doc = RunDocument.model_validate({"scenario": {"name": "ros"}, "started_at": "2026-01-01T00:00:00+00:00", "cells": [cell.model_dump()]})
    text = render_run(doc)
    assert "| `talker/Talker::tick()` | timer 100ms | thread500 (500) | 9 | 0 | 0 |" in text
    assert "| `listener/Listener::on_message(msg)` | – | – | – | 100 | 300 | 500 |" in text  # its age and chain, no latency
    slowest = "| `talker/Talker::tick()` | 0.300 | 500 | 200 | 30 | 1 | at 0.300 s: 60 of 150 µs preempted, 1 time, "
    slowest += "1 by hog0\\[900\\] (TS) for 60 µs |"
    assert slowest in text
    assert "| `talker/Talker::tick()` | 0.100 | 500 | 200 | 30 | 0 | – |" in text  # not hit: nothing to join
    golden("ros_callbacks.md", text)


def test_the_report_says_why_a_program_has_no_callbacks(tmp_path: Path) -> None:
    from runner.report.markdown import render_run

    cell = _cell(tmp_path, SCENARIO.split("expect:")[0], RosCapture(loaded=True, libraries=("librclcpp.so",)))
    doc = RunDocument.model_validate({"scenario": {"name": "ros"}, "cells": [cell.model_dump()]})
    assert "| the program | no ROS 2 callbacks seen: it loaded librclcpp but reached no tracing hook" in render_run(doc)


def _doc(cell: CellResult, started: str = "2026-01-01T00:00:00+00:00") -> RunDocument:
    return RunDocument.model_validate(
        {"scenario": {"name": "ros"}, "started_at": started, "machine": {"hostname": "vm"}, "cells": [cell.model_dump()]}
    )


def _preempted(tmp_path: Path, every: int) -> CellResult:
    """The cell with a talker whose tick is preempted in every `every`-th of its 200 callbacks."""
    n = Node(pid=500, tid=500)
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 4 * MS, BASE + 4 * MS, "Talker::tick()")
    for k in range(1, 201):
        n.run(0x30, BASE + k * 4 * MS + 30_000, nivcsw=3 if k % every == 0 else 0)
    return _cell(tmp_path, SCENARIO.split("expect:")[0], capture(n.process()))


def test_callbacks_are_compared_like_threads_by_their_key(tmp_path: Path) -> None:
    from runner.report.compare import compare

    calm, busy = _doc(_preempted(tmp_path, 100)), _doc(_preempted(tmp_path, 2))
    changes = [f for f in compare(calm, busy).figures if f.thread == "talker: talker/Talker::tick()"]
    per_callback = next(f for f in changes if f.figure.name == "involuntary.per_callback_mean")
    assert (per_callback.base, per_callback.new, per_callback.verdict) == (0.03, 1.5, "regression")
    assert per_callback.new_estimate is not None and per_callback.new_estimate.exposure == 200  # callbacks


def test_callback_verdicts_reach_junit_and_annotations(tmp_path: Path) -> None:
    from runner.report.github import for_run
    from runner.report.junit import junit_xml

    doc = _doc(_cell(tmp_path))
    xml = junit_xml(doc).decode()
    assert "talker: talker/Talker::tick(): involuntary switches in one callback (max) &lt;= 0" in xml
    assert "callback *timer_callback*: callbacks run &gt;= 1: not measured (no callback of that name was seen" in xml
    messages = " ".join(a.message for a in for_run(doc, None, "ros.yaml"))
    assert "talker: talker/Talker::tick()" in messages and "callback *timer_callback*" in messages


def test_callbacks_go_into_the_history_with_their_histograms(tmp_path: Path) -> None:
    from runner.history.night import record

    night = record(_doc(_cell(tmp_path)))
    (cell,) = night.cells
    rows = {(r.thread, r.figure): r for r in cell.figures}
    age = rows[("talker: listener/Listener::on_message(msg)", "message_age.p99")]
    assert (age.value, age.samples) == (300_000, 9)
    assert ("talker: talker/Talker::tick()", "involuntary.per_callback_mean") in rows
    assert ("talker: listener/Listener::on_message(msg)", "message_age") in {(k, kind) for k, kind, _ in cell.histograms}


def test_records_the_capture_lost_are_a_warning_of_the_cell(tmp_path: Path) -> None:
    from dataclasses import replace

    from runner.run.roscbdata import RosThread

    cap = _capture()
    lossy = replace(cap, processes=(replace(cap.processes[0], threads=(RosThread(tid=500, comm="talker", written=99, lost=7),)),))
    result = _cell(tmp_path, SCENARIO.split("expect:")[0], lossy)
    assert any(w.startswith("talker: thread talker (500): 7 records were overwritten") for w in result.warnings)


def test_the_terminal_shows_a_row_per_callback_with_the_seed_figure(tmp_path: Path) -> None:
    from runner.report.cellview import render_cell

    text = render_cell(_cell(tmp_path))
    row = next(line for line in text.splitlines() if line.strip().startswith("talker: talker/Talker::tick()"))
    assert row.split()[2:5] == ["500", "9", "0.11"]  # its thread, callbacks, involuntary switches per callback


@pytest.mark.parametrize(
    "expect, valid",
    [
        ({"thread": "a", "metric": "callbacks", "min": 1}, True),
        ({"callback": "*tick*", "metric": "callbacks", "min": 1}, True),
        ({"thread": "a", "callback": "*tick*", "metric": "callbacks", "min": 1}, False),
        ({"metric": "callbacks", "min": 1}, False),
    ],
)
def test_the_editors_schema_takes_exactly_one_of_thread_and_callback(expect: dict[str, object], valid: bool) -> None:
    schema = json.loads((Path(__file__).parent.parent / "runner.schema.json").read_text())
    data = {"name": "x", "processes": [{"name": "p", "command": ["a"]}], "expect": [expect]}
    errors = list(jsonschema.Draft202012Validator(schema).iter_errors(data))
    assert (not errors) is valid
