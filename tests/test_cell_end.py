"""When the supervising loop watches for the end of the measured work, and how often it looks then.

Once no measured thread works, the trace's last read and the end of the background load no
longer wait for the workers' exits; a program's threads have no slots to say they are done,
so with programs both wait.  The rule is checked here on a cell run's state, without processes;
that the load and the trace still cover a callback running past the end is checked against the
kernel (test_kernel_overload.py, test_kernel_trace.py).
"""

from __future__ import annotations

import mmap
import os
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from types import SimpleNamespace
from typing import Any

import pytest

from runner.run import gate, samples, spawn
from runner.run.gate import gate_late, load_late, start_load, start_margin
from runner.run.samples import Layout
from runner.run.spawn import _CellRun
from runner.run.workers import Worker

_WORK_START_AT = 112  # a slot header's work_start_ns, as the native core lays it out (after loops and missed)
_GATE_AT = 464  # and gate_ns, when the thread passed the start gate


def _cell_run(**state: Any) -> _CellRun:
    run = _CellRun.__new__(_CellRun)  # the state the rule reads, nothing started
    defaults: dict[str, Any] = {
        "programs": [],
        "tracer": None,
        "hogs": [],
        "commands": [],
        "load_ended": False,
        "options": SimpleNamespace(follow=None),
    }
    for name, value in {**defaults, **state}.items():
        setattr(run, name, value)
    return run


@pytest.mark.parametrize(
    ("state", "awaited"),
    [
        ({}, False),  # nothing to end early: the loop waits for the exits
        ({"tracer": object()}, True),
        ({"hogs": [object()]}, True),
        ({"commands": [object()]}, True),
        ({"hogs": [object()], "load_ended": True}, False),
        ({"hogs": [object()], "load_ended": True, "tracer": object()}, True),
        ({"tracer": object(), "programs": [object()]}, False),
        ({"hogs": [object()], "programs": [object()]}, False),
    ],
)
def test_the_end_is_watched_for_while_a_trace_or_load_would_wait_on_exits(state: dict[str, Any], awaited: bool) -> None:
    assert _cell_run(**state).awaiting_end is awaited


def test_after_the_end_the_loop_looks_soon_then_less_often(monkeypatch: pytest.MonkeyPatch) -> None:
    now = 50_000_000_000
    monkeypatch.setattr(spawn.time, "monotonic_ns", lambda: now)  # a clock that stands still: the waits, exactly
    watching = _cell_run(tracer=object())
    assert watching._next_wait(now + 10_000_000_000) == 0.2  # a tick while the window runs
    assert watching._next_wait(now + 80_000_000) == 0.08  # up to the end itself
    assert watching._next_wait(now - 100_000) == 0.001  # a millisecond once it passed
    assert watching._next_wait(now - 100_000_000) == 0.05  # half the time since, later
    assert watching._next_wait(now - 10_000_000_000) == 0.2  # a tick at most
    assert _cell_run()._next_wait(now - 100_000) == 0.2  # nothing awaited: the exits wake the loop


def test_the_start_margin_grows_with_processes_and_threads() -> None:
    assert start_margin(1, 10) == pytest.approx(0.00542)  # fifo80: a worker of ten slots (its two hogs start after)
    assert start_margin(16, 1024) == pytest.approx(0.022088)  # measured: the last through its gate 10 ms after it opened
    assert start_margin(64, 8192) == 0.060


T0 = 5_000_000_000


@contextmanager
def _three_slots(name: str, at: int, values: tuple[int, int, int]) -> Iterator[tuple[mmap.mmap, samples.Buffer]]:
    """A buffer of three slots whose field at offset `at` of each slot header holds `values`, as a worker's threads left it:
    a writable map to change them, and the runner's view."""
    layout = Layout(3, 0, histograms=False)
    fd = samples.create(name, layout)
    try:
        writable = mmap.mmap(fd, layout.size)
        for index, value in enumerate(values):
            struct.pack_into("<q", writable, layout.slot(index) + at, value)
        buffer = samples.Buffer(fd, layout)
    finally:
        os.close(fd)
    try:
        yield writable, buffer
    finally:
        buffer.close()
        writable.close()


def test_a_cpus_load_is_late_by_the_first_hog_to_begin_there_and_a_hog_that_never_began_is_not_counted() -> None:
    """Hogs woken on one CPU share it: one waiting for its turn beside a hog that spins leaves no CPU without load."""
    with _three_slots("hog-test", _WORK_START_AT, (T0 - 3_000_000, T0 + 400_000, T0 + 900_000)) as (writable, buffer):
        hog = Worker("hog busy[0]", {}, buffer.layout, [], False, os.devnull)
        hog.buffer = buffer
        cpu0, cpu1 = [(hog, 0), (hog, 1)], [(hog, 2)]  # a thread in time and one waiting its turn; one alone, late
        assert load_late([cpu0, cpu1], T0) == [("hog busy[0]", 900_000)]
        assert load_late([cpu0, cpu1], T0 + 1_000_000) == [], "a load that began before the start is in time"
        assert load_late([cpu0, cpu1], None) == [], "a cell that never started had no load to be late"
        struct.pack_into("<q", writable, buffer.layout.slot(0) + _WORK_START_AT, 0)
        assert load_late([cpu0], T0) == [("hog busy[0]", 400_000)], "the first to begin on the CPU loads it"
        struct.pack_into("<q", writable, buffer.layout.slot(1) + _WORK_START_AT, 0)
        assert load_late([cpu0], T0) == [], "no hog there ever began: a dead hog, said elsewhere"


def test_a_workers_release_is_late_by_its_last_thread_through_the_gate_and_one_that_never_passed_is_not_counted() -> None:
    with _three_slots("gate-late-test", _GATE_AT, (T0 - 2_000_000, T0 + 700_000, 0)) as (_, buffer):  # in time, late, never
        assert gate_late(buffer, T0) == 700_000
        assert gate_late(buffer, None) == 0, "a cell that never started released nobody late"
        assert buffer.work_started() == [0, 0, 0], "the gate is not the work's start"


def test_the_start_waits_for_the_gates_of_threads_that_start_with_the_cell_and_of_workers_alive() -> None:
    """A thread spawned mid-run is at no gate, and an exited worker passes none: waiting for them until the hogs'
    own time left the hogs 1 ms to begin, where the margin gives them 5."""
    import time

    def planned(index: int, spawned: bool) -> Any:
        return SimpleNamespace(index=index, spawned=spawned)

    with _three_slots("gate-wait-test", _GATE_AT, (T0, T0, 0)) as (writable, buffer):
        worker = Worker("app[0]", {}, buffer.layout, [planned(0, False), planned(1, False), planned(2, True)], True, os.devnull)
        worker.buffer = buffer
        began = time.monotonic()
        gate.await_gates([worker], time.monotonic_ns() + 5_000_000_000)
        assert time.monotonic() - began < 1, "slot 2 is spawned mid-run: nothing to wait for"
        struct.pack_into("<q", writable, buffer.layout.slot(1) + _GATE_AT, 0)
        worker.popen = SimpleNamespace(poll=lambda: 0)  # type: ignore[assignment]  # exited: slot 1 will never pass
        began = time.monotonic()
        gate.await_gates([worker], time.monotonic_ns() + 5_000_000_000)
        assert time.monotonic() - began < 1, "a worker that exited is not waited for"
        worker.popen = SimpleNamespace(poll=lambda: None)  # type: ignore[assignment]  # alive, slot 1 not through
        began = time.monotonic()
        gate.await_gates([worker], time.monotonic_ns() + 200_000_000)
        assert time.monotonic() - began >= 0.2, "a live thread not through its gate is waited for, until the time given"


class _GateRecorder:
    """A hog's buffer that notes the CPUs its thread may use when its gate opens; its load has begun at once."""

    def __init__(self, tid: int) -> None:
        self.tid = tid
        self.allowed_at_open: set[int] = set()

    def open_gate(self, start_ns: int, end_ns: int) -> bool:
        self.allowed_at_open = os.sched_getaffinity(self.tid)
        return True

    def work_started(self) -> list[int]:
        return [1]

    def close(self) -> None:
        pass


@contextmanager
def _sleeping_hogs(pinned: dict[int, set[int]]) -> Iterator[tuple[list[Worker], list[int]]]:
    """Two hogs of one thread each, sleeping processes whose gates note where they were woken (`pinned`: hog index -> CPUs
    it may use), and the pids of their threads."""
    import subprocess
    import sys

    sleepers = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"]) for _ in range(2)]
    try:
        hogs = []
        for index, proc in enumerate(sleepers):
            if index in pinned:
                os.sched_setaffinity(proc.pid, pinned[index])
            hog = Worker(f"hog busy[{index}]", {}, Layout(1, 0, histograms=False), [], False, os.devnull)
            hog.ready = {"tids": [proc.pid]}
            hog.buffer = _GateRecorder(proc.pid)  # type: ignore[assignment]
            hogs.append(hog)
        yield hogs, [proc.pid for proc in sleepers]
    finally:
        for proc in sleepers:
            proc.kill()
            proc.wait()


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to spread over")
def test_hogs_are_woken_one_per_cpu_and_given_their_cpus_back() -> None:
    """Woken together, two hogs could share a CPU for milliseconds before the balancer moved one; each is woken
    on a CPU of its own instead, and may go anywhere it could before once its load began."""
    cpus = sorted(os.sched_getaffinity(0))
    with _sleeping_hogs({}) as (hogs, pids):
        groups = start_load(hogs, 0, 1, 2**62)
        woken_on = [h.buffer.allowed_at_open for h in hogs]  # type: ignore[union-attr]
        assert woken_on == [{cpus[0]}, {cpus[1]}], "one CPU each, the least taken first"
        assert groups == [[(hogs[0], 0)], [(hogs[1], 0)]], "the threads by the CPU they were woken on"
        assert all(os.sched_getaffinity(pid) == set(cpus) for pid in pids), "their own CPUs back"


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to spread over")
def test_a_hog_pinned_to_a_cpu_chooses_before_one_that_may_go_anywhere() -> None:
    """Chosen in turn, a hog free to go anywhere took CPU 0, and one pinned there shared it: CPU 1 had no load."""
    cpus = sorted(os.sched_getaffinity(0))
    with _sleeping_hogs({1: {cpus[0]}}) as (hogs, pids):
        start_load(hogs, 0, 1, 2**62)
        assert [h.buffer.allowed_at_open for h in hogs] == [{cpus[1]}, {cpus[0]}]  # type: ignore[union-attr]
        assert [os.sched_getaffinity(pid) for pid in pids] == [set(cpus), {cpus[0]}], "their own CPUs back"
