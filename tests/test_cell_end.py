"""When the supervising loop watches for the end of the measured work, and how often it looks then.

Once no measured thread works, the trace's last read and the end of the background load no
longer wait for the workers' exits; a program's threads have no slots to say they are done,
so with programs both wait.  The rule is checked here on a cell run's state, without processes;
that the load and the trace still cover a callback running past the end is checked against the
kernel (test_kernel_overload.py, test_kernel_trace.py).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import pytest

from runner.run.samples import Layout
from runner.run.spawn import Worker, _await_released, _CellRun, _read_done, start_margin


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


def test_after_the_end_the_loop_looks_soon_then_less_often() -> None:
    now = time.monotonic_ns()
    watching = _cell_run(tracer=object())
    assert watching._next_wait(now + 10_000_000_000) == pytest.approx(0.2)  # a tick while the window runs
    assert 0.05 < watching._next_wait(now + 100_000_000) <= 0.1  # the end itself
    assert watching._next_wait(now - 100_000) == pytest.approx(0.001, abs=1e-3)  # a millisecond once it passed
    assert watching._next_wait(now - 100_000_000) == pytest.approx(0.05, rel=0.2)  # half the time since, later
    assert _cell_run()._next_wait(now - 100_000) == pytest.approx(0.2)  # nothing awaited: the exits wake the loop


class _Output:
    """A worker's stdout as the runner reads it: the read end of a pipe, written by the test."""

    def __init__(self) -> None:
        read, self.write_fd = os.pipe()
        self.stdout = open(read)  # closed by the fixture

    def say(self, *lines: str) -> None:
        os.write(self.write_fd, "".join(line + "\n" for line in lines).encode())

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.write_fd)


@pytest.fixture
def outputs() -> Iterator[list[_Output]]:
    made = [_Output() for _ in range(3)]
    yield made
    for o in made:
        o.close()
        o.stdout.close()


def _worker(output: _Output) -> Worker:
    w = Worker("proc", {}, Layout(1, 0), [], True, "/dev/null")
    w.popen = SimpleNamespace(stdout=output.stdout, pid=1)  # type: ignore[assignment]
    return w


def test_hogs_wait_for_every_release_but_never_past_the_start(outputs: list[_Output]) -> None:
    released, failed, silent = (_worker(o) for o in outputs)
    outputs[0].say('{"released": true}')
    outputs[1].say('{"done": true, "stopped": true, "late_ns": 5}')  # ended before its release: kept for `done`
    began = time.monotonic_ns()
    _await_released([released, failed, silent], began + 50_000_000)
    waited = time.monotonic_ns() - began
    assert 50_000_000 <= waited < 1_000_000_000, "the silent worker is waited for up to the start, not longer"
    assert released.early == [] and silent.early == [] and len(failed.early) == 1
    outputs[1].close()
    _read_done(failed)
    assert failed.done and failed.late_ns == 5
    outputs[0].say('{"done": true, "late_ns": 0}')
    outputs[0].close()
    _read_done(released)
    assert released.done and released.late_ns == 0


def test_once_every_worker_is_released_the_hogs_go_at_once(outputs: list[_Output]) -> None:
    workers = [_worker(o) for o in outputs]
    for o in outputs:
        o.say('{"released": true}')
    began = time.monotonic_ns()
    _await_released(workers, began + 5_000_000_000)
    assert time.monotonic_ns() - began < 1_000_000_000
    outputs[2].close()  # a worker gone without a word is not waited for either
    _await_released([workers[2]], time.monotonic_ns() + 5_000_000_000)
    assert time.monotonic_ns() - began < 2_000_000_000


def test_the_start_margin_grows_with_processes_and_threads() -> None:
    assert start_margin(1, 2) == pytest.approx(0.00355)  # fifo80: a worker of a main thread and one callback
    assert start_margin(16, 1024) == pytest.approx(0.0366)  # measured: the last released 7 to 20 ms after `go`
    assert start_margin(64, 8192) == 0.060
