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
from types import SimpleNamespace
from typing import Any

import pytest

from runner.run import samples, spawn
from runner.run.samples import Layout
from runner.run.spawn import _CellRun, _load_late, start_margin

_WORK_START_AT = 112  # a slot header's work_start_ns, as the native core lays it out (after loops and missed)


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
    assert start_margin(3, 10) == pytest.approx(0.01162)  # fifo80: a worker of ten slots and two hogs
    assert start_margin(16, 1024) == pytest.approx(0.030288)  # measured: the last released 7 to 20 ms after `go`
    assert start_margin(64, 8192) == 0.060


def test_a_hogs_load_is_late_by_its_last_thread_to_begin_and_a_thread_that_never_began_is_not_counted() -> None:
    layout = Layout(3, 0, histograms=False)
    fd = samples.create("hog-test", layout)
    try:
        writable = mmap.mmap(fd, layout.size)
        t0 = 5_000_000_000
        for index, began in enumerate((t0 - 3_000_000, t0 + 400_000, 0)):  # in time, late, never
            struct.pack_into("<q", writable, layout.slot(index) + _WORK_START_AT, began)
        buffer = samples.Buffer(fd, layout)
        assert _load_late(buffer, t0) == 400_000
        assert _load_late(buffer, t0 + 1_000_000) < 0, "a load that began before the start is in time"
        struct.pack_into("<q", writable, layout.slot(1) + _WORK_START_AT, 0)
        struct.pack_into("<q", writable, layout.slot(0) + _WORK_START_AT, 0)
        assert _load_late(buffer, t0) == 0, "a hog that never began is a dead hog, said elsewhere"
        buffer.map.close()
        writable.close()
    finally:
        os.close(fd)
