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
import time
from collections.abc import Iterator
from typing import Any

import pytest
from test_cell_end import _cell_run

from runner.run import commands, kernel, workers
from runner.run.child import signal_name
from runner.run.commands import BackgroundCommands, Command
from runner.run.rawcell import BackgroundProcess
from runner.run.workers import Exits, kill_group_or_process
from runner.scenario.model import Command as CommandSpec


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
    monkeypatch.setattr(commands, "kill_group_or_process", lambda pid, sig=signal.SIGKILL: signalled.append(pid))
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()  # its pid may be another process's by now
    with _sleeping(start_new_session=True) as running:
        held = BackgroundCommands("/nonexistent", None)  # type: ignore[arg-type]  # no guard: these were started here
        held.started = [Command(CommandSpec.parse({"argv": ["sleep"]}), n, popen) for n, popen in enumerate((done, running))]
        _cell_run(commands=held)._end_load()
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


class _Watcher:
    """The guard's part a command sees: what it was told to watch, and to forget."""

    def __init__(self) -> None:
        self.pids: list[int] = []
        self.cgroups: list[str] = []
        self.forgotten: list[str] = []

    def watch(self, pid: int) -> None:
        self.pids.append(pid)

    def watch_cgroup(self, folder: str) -> None:
        self.cgroups.append(folder)

    def forget_cgroup(self, folder: str) -> None:
        self.forgotten.append(folder)


def test_a_background_command_is_one_object_from_its_start_to_what_it_wrote(tmp_path: Any) -> None:
    """Its process, its cgroup (where the machine lets the runner make one), its log and its count go together; the first
    command that cannot start stops the rest, and the results name each as the scenario wrote it."""
    guard = _Watcher()
    held = BackgroundCommands(str(tmp_path), guard)  # type: ignore[arg-type]
    specs = [
        CommandSpec.parse({"argv": ["sh", "-c", "echo loaded; exec sleep 30"], "name": "load"}),
        # by path: with a folder on PATH this user may not read, a lookup ends in EACCES, not ENOENT
        CommandSpec.parse({"argv": ["/nonexistent/no-such-program-of-the-runner"]}),
        CommandSpec.parse({"argv": ["sleep", "30"]}),
    ]
    try:
        reason = held.start(specs)
        assert reason == "background command '/nonexistent/no-such-program-of-the-runner' could not start: No such file or directory"
        (command,) = held.started
        assert guard.pids == [command.pid] and guard.cgroups == ([command.group.folder] if command.group else [])
        assert list(held.incidents("now")) == [], "it runs"
        log, until = tmp_path / "command-0.log", time.monotonic() + 10.0
        while log.read_bytes() != b"loaded\n" and time.monotonic() < until:  # its echo, before the cell's end stops it
            time.sleep(0.01)
        held.end()
        assert workers.exited_within(command.popen, 5.0), "the cell's end stops it, SIGTERM to its group"
        ((label, incident),) = held.incidents("1.0s into the cell")
        assert label == "command sh[0]" and "(pid" in incident and "killed by SIGTERM 1.0s into the cell" in incident
        held.remove_groups()
        assert guard.forgotten == guard.cgroups and command.group is None
        held.finish_outputs(time.monotonic() + 5.0)
        assert command.count is not None and command.count.written == len(b"loaded\n") and command.output is None
        assert log.read_bytes() == b"loaded\n"
        assert command.background() == BackgroundProcess(
            "command", "load", command.pid, ("sh", "-c", "echo loaded; exec sleep 30"), "command-0.log", command.count
        ), "as the scenario wrote it, without the shell that put it in its cgroup"
    finally:
        for c in held:
            c.popen.kill()
            c.popen.wait()
