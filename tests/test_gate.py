"""The start gate in a worker's shared buffer: the runner opens it, or cancels it, for every thread of the process at once.

Each thread waits at the gate itself, at its own policy, and notes when it passed it; these
tests drive a Group of this process through a second mapping of its buffer, as the runner
does through its own.  Sleeping and short periodic work at SCHED_OTHER: no rights needed.
"""

from __future__ import annotations

import mmap
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

from runner.run import _probe, kernel, samples
from runner.run.wiring import work_tuple
from runner.scenario.model import PeriodicWork, SleepWork


@contextmanager
def _group(nthreads: int, name: str) -> Iterator[tuple[_probe.Group, samples.Buffer]]:
    """A group of `nthreads` slots (the main one adopted: a 1 ms periodic callback, the others asleep) and the runner's view."""
    layout = samples.Layout(nthreads, 64)
    fd = samples.create(name, layout)
    try:
        group = _probe.Group(mmap.mmap(fd, layout.size), nthreads, 64, kernel.online_cpus())
        runner_view = samples.Buffer(fd, layout)
    finally:
        os.close(fd)
    group.adopt(0, name, work_tuple(PeriodicWork.parse({"period": "1ms"})))
    for index in range(1, nthreads):
        group.spawn(index, f"{name}-{index}", work_tuple(SleepWork()), None, None, None, None, False, None, False)
    assert group.wait_ready(5.0)
    try:
        yield group, runner_view
    finally:
        _probe.set_name("pytest")
        runner_view.close()


def test_the_runners_gate_releases_every_thread_which_notes_when_it_passed() -> None:
    with _group(4, "gate-open") as (group, view):
        assert view.gate_passed() == [0, 0, 0, 0], "shut: nobody passed"
        start = time.monotonic_ns() + 20_000_000
        assert view.open_gate(start, start + 30_000_000)
        assert not view.open_gate(start, start + 30_000_000), "open already"
        assert not view.cancel_gate(), "an open gate is not cancelled"
        assert group.run_main(0) is True
        group.join()
        passed = view.gate_passed()
        assert all(0 < t < start for t in passed), f"every thread passed before the start, 20 ms after the gate opened: {passed}"
        slots = view.slots()
        assert slots[0].loops >= 20 and all(s.state == "done" for s in slots), "the main thread ran its 30 ms of 1 ms callbacks"
        assert all(s.work_start_ns >= start for s in slots[1:]), "the sleepers began at the start, not at the gate"


def test_a_cancelled_gate_sends_every_thread_away_without_working() -> None:
    with _group(3, "gate-cancel") as (group, view):
        assert view.cancel_gate()
        assert view.cancel_gate(), "cancelled already: still cancelled"
        assert not view.open_gate(time.monotonic_ns(), time.monotonic_ns() + 1_000_000), "a cancelled gate does not open"
        assert group.run_main(0) is False, "the main thread says nothing ran"
        group.join()
        slots = view.slots()
        assert [(s.state, s.loops, s.work_start_ns) for s in slots] == [("done", 0, 0)] * 3
        assert view.gate_passed() == [0, 0, 0]


def test_a_group_dropped_before_its_gate_opened_lets_its_parked_threads_leave() -> None:
    layout = samples.Layout(3, 0, histograms=False)
    fd = samples.create("gate-drop", layout)
    try:
        group = _probe.Group(mmap.mmap(fd, layout.size), 3, 0, kernel.online_cpus(), False)
        view = samples.Buffer(fd, layout)
    finally:
        os.close(fd)
    try:
        for index in range(3):
            group.spawn(index, f"gate-drop-{index}", work_tuple(SleepWork()), None, None, None, None, False, None, False)
        assert group.wait_ready(5.0)
        began = time.monotonic()
        del group  # joins its threads: they must not wait on at a gate nobody will open
        assert time.monotonic() - began < 2.0
        assert [s.state for s in view.slots()] == ["done"] * 3
        assert not view.open_gate(time.monotonic_ns(), time.monotonic_ns()), "the group cancelled it on its way out"
    finally:
        _probe.set_name("pytest")
        view.close()
