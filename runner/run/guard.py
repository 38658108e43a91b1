"""The guard: a tiny process that kills what the runner started if the runner dies without doing it.

Workers die with the runner through PR_SET_PDEATHSIG, but that reaches only direct
children: a background command's own children, or anything a command started in
its process group, would outlive a SIGKILLed runner.  Every process the runner
starts leads a process group of its own; the runner tells the guard about each
group (`+PGID`) and about each it is done with (`-PGID`, before it reaps it) over the
guard's stdin.  When stdin reaches end of file (the runner exited, normally or by
SIGKILL, since the kernel closes its end of the pipe either way), the guard SIGKILLs
every group still on its list and exits.

A group's number is its leader's PID, and a PID is given to another process once its
own is reaped (in seconds, where pid_max is 32768): a worker the zygote reaped mid-cell,
or anything reaped just before the runner died, is still on the list.  So the guard notes
each leader's start time as it hears of it (`/proc/PID/stat`), and at the end kills a
group only while no other process has its number: the leader itself (same start time),
or no process at all (the number then belongs to the group's last members, since the
kernel gives no process a number a group still uses, or to no one).  Group 0 and 1 are
never killed (the guard's own group; init's).

A tracefs instance the runner traces in (runner/run/tracing.py) is registered the
same way (`trace+PATH`, `trace-PATH`): one still registered at end of file has its
tracing turned off and is removed, so a killed runner does not leave the kernel
tracing.  So is the cgroup that holds a program or a background command and all it
starts (`cg+PATH`, `cg-PATH`, runner/run/memcg.py): a process that left its group
with setsid() is still in its cgroup, where the guard kills it before removing it.

The guard has a second: a process it forks as it starts, in a session of its own, that
gets a copy of every line over a pipe of its own from the runner.  When the runner's
end closes it waits for the guard's word that it cleaned up, and, should the guard have
died first (killed with the runner: `pkill -9`, a stop that spares no process of the
runner's), does the guard's work itself.  A watcher is needed: a program's children are
the user's, so no PR_SET_PDEATHSIG of the runner's reaches them, and nothing of the kernel
kills a cgroup when its maker dies.  Should the runner, the guard and its second all be
killed, the next run removes the dead runner's cgroups and what they hold (memcg).

Run as `python -m runner.run.guard`; it imports only the standard library (and
runner.run.child, which starts it, and memcg), ignores the terminal's signals (it has its
own session) and does nothing else.
"""

from __future__ import annotations

import errno
import os
import select
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import IO, Optional, Protocol

from runner.run import memcg
from runner.run.child import child_env, python_module


@dataclass
class Watched:
    """What the guard still has to clean up: process groups and tracefs instances."""

    groups: set[int] = field(default_factory=set)
    instances: set[str] = field(default_factory=set)
    cgroups: set[str] = field(default_factory=set)
    started: dict[int, Optional[int]] = field(default_factory=dict)  # each group's leader's start time when told (None: gone)


def start_time(pid: int) -> Optional[int]:
    """When the process (or thread) `pid` started, in clock ticks since boot; None when no task has that PID."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as handle:
            return int(handle.read().rsplit(b")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def ours(pgid: int, started: Optional[int]) -> bool:
    """Whether group `pgid` is still the one whose leader started at `started`: no other process holds its number."""
    now = start_time(pgid)
    return now is None or now == started


def follow(commands: IO[str]) -> Watched:
    """Follow `+PGID` / `-PGID`, `trace+PATH` / `trace-PATH` and `cg+PATH` / `cg-PATH` lines until end of file; return what is left."""
    left = Watched()
    for line in commands:
        line = line.strip()
        if line.startswith(("trace+", "trace-")) and len(line) > 6:
            if line[5] == "+":
                left.instances.add(line[6:])
            else:
                left.instances.discard(line[6:])
        elif line.startswith(("cg+", "cg-")) and len(line) > 3:
            if line[2] == "+":
                left.cgroups.add(line[3:])
            else:
                left.cgroups.discard(line[3:])
        elif len(line) > 1 and line[1:].isascii() and line[1:].isdecimal() and int(line[1:]) > 1:
            pgid = int(line[1:])
            if line[0] == "+":
                left.groups.add(pgid)
                left.started[pgid] = start_time(pgid)
            elif line[0] == "-":
                left.groups.discard(pgid)
                left.started.pop(pgid, None)
    return left


def serve(commands: IO[str]) -> set[int]:
    """Follow the lines until end of file; return the groups still alive."""
    return follow(commands).groups


def remove_instance(path: str, wait_s: float = 0.0) -> bool:
    """Turn tracing off in the tracefs instance `path` and remove it; whether it is gone.

    Only `.../instances/runner-*` is touched.  A dead runner's files close while it
    exits, possibly after the guard saw its pipe close: removal (EBUSY while a trace
    file is open) is retried for `wait_s`.
    """
    if os.path.basename(os.path.dirname(path)) != "instances" or not os.path.basename(path).startswith("runner-"):
        return False
    try:
        fd = os.open(os.path.join(path, "tracing_on"), os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)  # never created, never a link
        try:
            os.write(fd, b"0")
        finally:
            os.close(fd)
    except OSError:
        pass
    until = time.monotonic() + wait_s
    while True:
        try:
            os.rmdir(path)
            return True
        except FileNotFoundError:
            return True
        except OSError as error:
            if error.errno != errno.EBUSY or time.monotonic() >= until:
                return False
        time.sleep(0.02)


SECOND_FD = "RUNNER_GUARD_SECOND"  # the environment variable naming the descriptor of the second's copy of the lines
CLEAR = b"clear\n"  # the guard's word to its second: what the runner left is cleaned up
READY = b"ready\n"  # the guard's word to the runner: its second is started
READY_WAIT_S = 5.0  # how long the runner waits for it, before it starts programs and background commands (Guard.ready)


def main() -> int:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGTSTP):
        signal.signal(sig, signal.SIG_IGN)
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # the second is reaped by the kernel, whenever it ends
    clear = _start_second(os.environ.get(SECOND_FD, ""))
    try:
        os.write(1, READY)  # the second is there (or never will be): the runner may start what it watches
        os.close(1)
    except OSError:
        pass
    clean(follow(sys.stdin))
    if clear is not None:
        try:
            os.write(clear, CLEAR)
        except OSError:
            pass  # the second is gone: nothing waits for the word
    return 0


def _start_second(fd: str) -> Optional[int]:
    """Fork the second, which follows the lines on descriptor `fd`; the descriptor to give it the word on (None: no second)."""
    if not fd.isdecimal():
        return None
    lines = int(fd)
    clear_read, clear_write = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        for each in (lines, clear_read, clear_write):
            os.close(each)
        return None
    if pid == 0:
        try:
            os.setsid()  # a kill of the guard's process group leaves it
            devnull = os.open(os.devnull, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
            os.dup2(devnull, 0)  # the guard's stdin: held here, the runner's writes would never fail once the guard died
            os.dup2(devnull, 1)  # its stdout: held here, the runner would not see the guard's end while it waits for its word
            os.close(clear_write)  # the guard's end: its death is the end of file here
            with os.fdopen(lines, encoding="utf-8", errors="replace") as copy:
                second(copy, clear_read)
        finally:
            os._exit(0)
    os.close(lines)  # the second's alone: its death is the runner's EPIPE
    os.close(clear_read)
    return clear_write


def second(lines: IO[str], clear: int) -> None:
    """The second's life: follow the runner's lines to their end, then clean up unless the guard says it has."""
    left = follow(lines)
    word = b""
    while chunk := os.read(clear, len(CLEAR)):  # the guard's word, then the end of file its exit makes (or its death, alone)
        word += chunk
    if word != CLEAR:
        clean(left)


def clean(left: Watched) -> None:
    """Stop tracing in the instances left, kill the process groups and the cgroups' tasks, remove the cgroups and instances."""
    # Tracing stops first, so what the kill below does is not recorded; an instance the dead runner's files
    # still hold (EBUSY) is removed after the kill, which waits for nothing.
    busy = [path for path in sorted(left.instances) if not remove_instance(path)]
    for pgid in sorted(left.groups):
        if not ours(pgid, left.started.get(pgid)):
            continue  # its number is another process's now: the group it stood for has no member left
        try:
            os.killpg(pgid, signal.SIGKILL)
        except OSError:
            pass
    for folder in sorted(left.cgroups):
        if os.path.basename(folder).startswith("runner-"):  # only what a runner made
            memcg.kill_all(folder)
            memcg.remove(folder)
    for path in busy:
        remove_instance(path, wait_s=2.0)


class Watcher(Protocol):
    """What a process starter tells the guard: the process groups and cgroups to kill should the runner die.

    The Guard is the one the runner uses; benches and tests hand in stand-ins.
    """

    def watch(self, pgid: int) -> None: ...

    def forget(self, pgid: int) -> None: ...

    def watch_cgroup(self, path: str) -> None: ...

    def forget_cgroup(self, path: str) -> None: ...


class Guard:
    """The runner's handle on its guard process."""

    def __init__(self) -> None:
        self.proc: Optional[subprocess.Popen[str]] = None
        self._second = -1  # the write end of the second's copy of the lines
        self._lock = threading.Lock()
        copy_read, copy_write = os.pipe()
        try:
            self.proc = subprocess.Popen(
                python_module("runner.run.guard"),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
                start_new_session=True,
                close_fds=True,
                pass_fds=(copy_read,),
                cwd="/",
                env=child_env(**{SECOND_FD: str(copy_read)}),
            )
            self._second, copy_write = copy_write, -1
        except OSError:
            self.proc = None  # without a guard, PDEATHSIG still covers the workers
        finally:
            for fd in (copy_read, copy_write):
                if fd >= 0:
                    os.close(fd)

    def ready(self) -> None:
        """Wait (READY_WAIT_S at most, once) until the guard has started its second.

        Called before the runner starts what only the guard or its second can stop (programs and
        background commands, whose children no PR_SET_PDEATHSIG reaches): a runner and guard killed
        together before the second was there would leave those to no one.  The guard starts as the
        run prepares, so by then the wait is over: on the loaded 2-CPU VM the second was there 150
        to 240 ms after the guard's start, and the wait before a run's first program took 0 ms.
        """
        with self._lock:
            if self.proc is None or self.proc.stdout is None or self.proc.stdout.closed:
                return
            poller = select.poll()
            poller.register(self.proc.stdout.fileno(), select.POLLIN)
            poller.poll(READY_WAIT_S * 1000)  # its word, or its end: either way there is nothing more to wait for
            self.proc.stdout.close()

    def _send(self, line: str) -> None:
        with self._lock:  # the run's threads (trace set-up and removal, the zygote's end) tell it things too: whole lines
            if self.proc is not None and self.proc.stdin is not None:
                try:
                    self.proc.stdin.write(line + "\n")
                    self.proc.stdin.flush()
                except (OSError, ValueError):
                    self.proc = None
            if self._second >= 0:
                try:
                    os.write(self._second, (line + "\n").encode())  # a line is far below PIPE_BUF: written whole, at once
                except OSError:  # the second is gone: the guard alone
                    os.close(self._second)
                    self._second = -1

    def watch(self, pgid: int) -> None:
        """Kill process group `pgid` should the runner die before it reaps it."""
        self._send(f"+{pgid}")

    def forget(self, pgid: int) -> None:
        """`pgid` was reaped: its number may be reused, so the guard must not kill it."""
        self._send(f"-{pgid}")

    def watch_trace(self, path: str) -> None:
        """Turn tracing off in the tracefs instance `path` and remove it should the runner die first."""
        self._send(f"trace+{path}")

    def forget_trace(self, path: str) -> None:
        """The instance `path` was removed."""
        self._send(f"trace-{path}")

    def watch_cgroup(self, path: str) -> None:
        """Kill every task in the cgroup `path` and remove it should the runner die first."""
        self._send(f"cg+{path}")

    def forget_cgroup(self, path: str) -> None:
        """The cgroup `path` was emptied and removed."""
        self._send(f"cg-{path}")

    def close(self) -> None:
        """Stop the guard and its second (what they still watch is killed: nothing, after an orderly stop)."""
        with self._lock:
            if self._second >= 0:
                os.close(self._second)
                self._second = -1
        if self.proc is not None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.close()
                self.proc.wait(timeout=5)
            except (OSError, ValueError, subprocess.TimeoutExpired):
                pass
            self.proc = None


if __name__ == "__main__":
    raise SystemExit(main())
