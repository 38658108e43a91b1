"""How a cell's processes are told to stop and how their ends are named: real processes, no measured work.

A worker that never got its `go`, a command run through sudo whose group the runner may not
signal, a process killed by a real-time signal, a dead zygote's socket: each once turned a
cell's end into an internal error, a wait of the whole grace period, or a busy loop.
"""

from __future__ import annotations

import contextlib
import select
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import pytest
from test_cell_end import _cell_run

from runner.run import kernel, spawn, workers
from runner.run.child import signal_name
from runner.run.workers import Exits, kill_group_or_process


@contextlib.contextmanager
def _sleeping(**popen: Any) -> Iterator[subprocess.Popen[bytes]]:
    """A process that sleeps 30 s, killed and reaped on the way out."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], **popen)
    try:
        yield proc
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize(
    ("number", "name"),
    [(9, "SIGKILL"), (15, "SIGTERM"), (signal.SIGRTMIN, "SIGRTMIN"), (signal.SIGRTMIN + 1, "SIGRTMIN+1"), (200, "signal 200")],
)
def test_every_signal_a_process_can_die_of_has_a_name(number: int, name: str) -> None:
    assert signal_name(number) == name


def test_a_group_the_runner_may_not_signal_falls_back_to_its_leader(monkeypatch: pytest.MonkeyPatch) -> None:
    sent: list[tuple[int, int]] = []

    def refused(pid: int, sig: int) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(workers.os, "killpg", refused)
    monkeypatch.setattr(workers.os, "kill", lambda pid, sig: sent.append((pid, sig)))
    kill_group_or_process(4242, signal.SIGTERM)
    assert sent == [(4242, signal.SIGTERM)]
    monkeypatch.setattr(workers.os, "kill", refused)
    kill_group_or_process(4242, signal.SIGTERM)  # refused there too: left to the command's cgroup, never raised


def test_the_end_of_the_load_spares_a_command_reaped_already(monkeypatch: pytest.MonkeyPatch) -> None:
    signalled: list[int] = []
    monkeypatch.setattr(spawn, "kill_group_or_process", lambda pid, sig=signal.SIGKILL: signalled.append(pid))
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()  # its pid may be another process's by now
    with _sleeping(start_new_session=True) as running:
        _cell_run(commands=[done, running])._end_load()
        assert signalled == [running.pid]


def test_a_dead_zygotes_socket_stops_waking_the_loop() -> None:
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    with _sleeping() as sleeper:
        exits = Exits([sleeper.pid])
        try:
            exits.zygote_fd = ours.fileno()
            exits.poller.register(ours.fileno(), select.POLLIN)
            theirs.close()  # the zygote died: its socket hangs up, and would at every poll
            exits.wait(5.0)
            assert exits.zygote_fd == -1
            assert exits.poller.poll(0) == [], "something still wakes the loop though the sleeper lives"
        finally:
            exits.close()
            ours.close()


def test_a_process_named_in_bytes_that_are_not_utf8_is_read_listed_and_shown() -> None:
    """comm is any 15 bytes a process sets (a UTF-8 name cut mid-character): once an internal error, a dead monitor."""
    named = subprocess.Popen(
        # flushed: a pipe is block-buffered unless PYTHONUNBUFFERED is set, which an ordinary user's shell does not set
        [sys.executable, "-c", "import ctypes; ctypes.CDLL(None).prctl(15, b'bad\\xff\\xfename', 0, 0, 0); print(flush=True); input()"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert named.stdout is not None and select.select([named.stdout], [], [], 10)[0], "not named within 10 s"  # never a hang
        assert named.stdout.readline() == "\n"  # named by now
        assert kernel.thread_comm(named.pid, named.pid) == "bad\ufffd\ufffdname"
        assert kernel.find_pids("bad") == []  # every process on the machine listed, this one too
        assert kernel.thread_counters(named.pid, named.pid) is not None
        assert [row.comm for row in kernel.thread_rows(named.pid)] == ["bad\ufffd\ufffdname"]
    finally:
        named.kill()
        named.wait()
