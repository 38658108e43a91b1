"""Workers forked by the zygote: started as a fresh interpreter would have been, reaped, reported, and never left behind.

The workers here sleep (SCHED_OTHER, no rights needed) and are named `zyg-*`.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import time
from collections.abc import Iterator
from typing import Any

import pytest
from kernelrun import needs_tracing

from runner.run import kernel, samples, tracing
from runner.run.gate import gate_late
from runner.run.wiring import work_tuple
from runner.run.workers import Worker, read_done
from runner.run.zygote import Zygote, ZygoteChild, ZygoteError
from runner.scenario.model import SleepWork


class _Guard:
    """The guard's interface, recording instead of watching."""

    def __init__(self) -> None:
        self.watched: list[int] = []

    def watch(self, pgid: int) -> None:
        self.watched.append(pgid)

    def forget(self, pgid: int) -> None:
        pass


@pytest.fixture
def zygote() -> Iterator[Zygote]:
    z = Zygote.start()
    if z is None:
        pytest.skip("this kernel has no pidfds")
    yield z
    z.close()


def sleeper(tmp_path: Any, name: str) -> Worker:
    spec = {
        "comm": name,
        "capacity": 0,
        "all_cpus": kernel.online_cpus(),
        "histograms": False,
        "memory": {},
        "main": {"name": name, "apply": "before_threads", "sched": None, "cpus": None, "work": work_tuple(SleepWork())},
        "threads": [],
    }
    return Worker(f"process {name}[0]", spec, samples.Layout(1, 0, histograms=False), [], True, str(tmp_path / f"{name}.log"))


def ready(w: Worker) -> dict[str, Any]:
    assert w.popen is not None and w.popen.stdout is not None
    found, _, _ = select.select([w.popen.stdout], [], [], 10)
    assert found, "the worker did not report ready within 10 s"
    import json

    return dict(json.loads(w.popen.stdout.readline()))


def stat_fields(pid: int) -> list[str]:
    with open(f"/proc/{pid}/stat") as handle:
        return handle.read().rsplit(")", 1)[1].split()


def test_a_forked_worker_starts_as_a_fresh_one_would(tmp_path, zygote):
    w = sleeper(tmp_path, "zyg-fresh")
    guard = _Guard()
    w.start(guard, zygote=zygote)
    try:
        assert isinstance(w.popen, ZygoteChild)
        msg = ready(w)
        assert msg["ready"] and msg["pid"] == w.pid
        fields = stat_fields(w.pid)  # state, ppid, pgrp, session, ...
        assert int(fields[1]) == zygote.proc.pid, "the zygote is its parent, and reaps it"
        assert int(fields[2]) == w.pid and int(fields[3]) == w.pid, "a session and process group of its own"
        assert guard.watched == [w.pid], "the guard kills its group should the runner die"
        assert os.readlink(f"/proc/{w.pid}/cwd") == "/"
        with open(f"/proc/{w.pid}/comm") as handle:
            assert handle.read().strip() == "zyg-fresh"
        assert zygote.sock is not None
        theirs = {os.readlink(f"/proc/{zygote.proc.pid}/fd/{fd}") for fd in os.listdir(f"/proc/{zygote.proc.pid}/fd")}
        sockets = {link for link in theirs if link.startswith("socket:")}
        mine = {os.readlink(f"/proc/{w.pid}/fd/{fd}") for fd in os.listdir(f"/proc/{w.pid}/fd")}
        assert not sockets & mine, "no descriptor of the zygote's leaks into a worker"
        assert [link for link in mine if "memfd:runner-zyg-fresh" in link], "its samples buffer reached it (fd 3)"
        start = time.monotonic_ns() + 20_000_000
        assert w.buffer is not None and w.buffer.open_gate(start, start + 40_000_000)
        assert w.popen.wait(timeout=10) == 0
        read_done(w)
        assert w.done and gate_late(w.buffer, start) < 0, "released before the common start: no lateness to report"
        assert w.exit_reason() is None
    finally:
        w.signal(signal.SIGKILL)


def test_a_worker_whose_cell_never_starts_leaves_at_once_when_the_runner_hangs_up(tmp_path, zygote):
    """At its gate a stop signal is only noted: the runner cancels the gate, and the worker leaves without working."""
    w = sleeper(tmp_path, "zyg-hangup")
    w.start(_Guard(), zygote=zygote)
    try:
        ready(w)
        began = time.monotonic()
        w.hang_up()
        assert w.popen is not None and w.popen.wait(timeout=10) == 0
        assert time.monotonic() - began < 1.0, "not after a grace period"
        read_done(w)
        assert not w.done, "no thread worked: nothing done to report"
        assert w.buffer is not None and [s.loops for s in w.buffer.slots()] == [0]
        w.hang_up()  # twice: nothing left to close, nothing raised
    finally:
        w.signal(signal.SIGKILL)


def test_exit_codes_and_signals_reach_the_runner(tmp_path, zygote):
    devnull = os.open(os.devnull, os.O_RDWR)
    try:
        pid = zygote.spawn(devnull, devnull, devnull, [])  # no spec on stdin: the worker exits 2
    finally:
        os.close(devnull)
    child = ZygoteChild(zygote, pid, open(os.devnull, "w"), open(os.devnull))
    assert child.wait(timeout=10) == 2
    w = sleeper(tmp_path, "zyg-killed")
    w.start(_Guard(), zygote=zygote)
    ready(w)
    assert w.popen is not None and w.popen.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        w.popen.wait(timeout=0.05)
    w.signal(signal.SIGKILL)
    assert w.popen.wait(timeout=10) == -signal.SIGKILL
    assert "killed by SIGKILL" in (w.exit_reason() or "")


def test_workers_die_with_the_zygote_and_later_ones_start_without_it(tmp_path, zygote):
    w = sleeper(tmp_path, "zyg-orphan")
    w.start(_Guard(), zygote=zygote)
    ready(w)
    zygote.proc.kill()
    assert w.popen is not None and w.popen.wait(timeout=10) == -signal.SIGKILL, "PR_SET_PDEATHSIG ends it with the zygote"
    deadline = time.monotonic() + 10
    while os.path.exists(f"/proc/{w.pid}") and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not os.path.exists(f"/proc/{w.pid}")
    assert zygote.sock is None and "SIGKILL" in zygote.failure
    with pytest.raises(ZygoteError):
        zygote.spawn(0, 1, 2, [])
    later = sleeper(tmp_path, "zyg-later")
    later.start(_Guard(), zygote=zygote)
    try:
        assert isinstance(later.popen, subprocess.Popen), "without a zygote the runner starts the worker itself"
        assert ready(later)["ready"]
    finally:
        later.signal(signal.SIGKILL)
        assert later.popen is not None
        later.popen.wait(timeout=10)


@pytest.mark.kernel
@needs_tracing
def test_the_trace_follows_the_zygotes_workers_without_writing_their_pids(tmp_path, zygote):
    if isinstance(tracing.find_tracefs(), tracing.TraceUnavailable):
        pytest.skip("no tracefs")
    traces = tracing.TraceInstances(buffer_kb=256)
    try:
        traces.prepare(seed=[zygote.proc.pid])
        filtered = os.path.join(traces.paths[0], "set_event_pid")

        def listed() -> set[int]:
            with open(filtered) as handle:
                return {int(word) for word in handle.read().split()}

        assert listed() == {zygote.proc.pid}
        w = sleeper(tmp_path, "zyg-traced")
        w.start(_Guard(), zygote=zygote)
        ready(w)
        assert w.pid in listed(), "the kernel adds a seeded process's child as it forks it (event-fork)"
        tracer = traces.open([w.pid])
        assert isinstance(tracer, tracing.Tracer)
        tracer.stop()
        w.signal(signal.SIGKILL)
        assert w.popen is not None
        w.popen.wait(timeout=10)
        deadline = time.monotonic() + 2
        while w.pid in listed() and time.monotonic() < deadline:  # when its task is freed, an RCU grace period after its exit
            time.sleep(0.01)
        assert listed() == {zygote.proc.pid}, "and removes it as it exits"
        again = traces.open([zygote.proc.pid])
        assert isinstance(again, tracing.Tracer), "the instances serve the next trace"
        again.stop()
    finally:
        traces.close()
    assert not os.path.exists(traces.paths[0])


def test_a_process_that_leads_no_group_yet_is_still_signalled():
    """A stop in the instant between a worker's fork and its setsid() once missed it: killpg found no such group."""
    from runner.run.workers import kill_group_or_process

    child = subprocess.Popen(["sleep", "30"])  # in our group: it leads none
    kill_group_or_process(child.pid)
    assert child.wait(timeout=5) == -signal.SIGKILL
