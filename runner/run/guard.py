"""The guard: a tiny process that kills what the runner started if the runner dies without doing it.

Workers die with the runner through PR_SET_PDEATHSIG, but that reaches only direct
children: a background command's own children, or anything a command started in
its process group, would outlive a SIGKILLed runner.  Every process the runner
starts leads a process group of its own; the runner tells the guard about each
group (`+PGID`) and about each it has reaped (`-PGID`) over the guard's stdin.
When stdin reaches end of file (the runner exited, normally or by SIGKILL, since
the kernel closes its end of the pipe either way), the guard SIGKILLs every group
still on its list and exits.

A tracefs instance the runner traces in (runner/run/tracing.py) is registered the
same way (`trace+PATH`, `trace-PATH`): one still registered at end of file has its
tracing turned off and is removed, so a killed runner does not leave the kernel
tracing.  So is the cgroup that holds a program or a background command and all it
starts (`cg+PATH`, `cg-PATH`, runner/run/memcg.py): a process that left its group
with setsid() is still in its cgroup, where the guard kills it before removing it.

Run as `python -m runner.run.guard`; it imports only the standard library (and
runner.run.child, which starts it), ignores the terminal's signals (it has its own
session) and does nothing else.
"""

from __future__ import annotations

import errno
import os
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
        elif len(line) > 1 and line[1:].isdecimal():
            pgid = int(line[1:])
            if line[0] == "+":
                left.groups.add(pgid)
            elif line[0] == "-":
                left.groups.discard(pgid)
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


def main() -> int:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGTSTP):
        signal.signal(sig, signal.SIG_IGN)
    left = follow(sys.stdin)
    # Tracing stops first, so what the kill below does is not recorded; an instance the dead runner's files
    # still hold (EBUSY) is removed after the kill, which waits for nothing.
    busy = [path for path in sorted(left.instances) if not remove_instance(path)]
    for pgid in sorted(left.groups):
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
    return 0


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
        self._lock = threading.Lock()
        try:
            self.proc = subprocess.Popen(
                python_module("runner.run.guard"),
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                text=True,
                start_new_session=True,
                close_fds=True,
                cwd="/",
                env=child_env(),
            )
        except OSError:
            self.proc = None  # without a guard, PDEATHSIG still covers the workers

    def _send(self, line: str) -> None:
        with self._lock:  # the run's threads (trace set-up and removal, the zygote's end) tell it things too: whole lines
            if self.proc is None or self.proc.stdin is None:
                return
            try:
                self.proc.stdin.write(line + "\n")
                self.proc.stdin.flush()
            except (OSError, ValueError):
                self.proc = None

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
        """Stop the guard (what it still watches is killed: nothing, after an orderly stop)."""
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
