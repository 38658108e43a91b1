"""The guard: a tiny process that kills what the runner started if the runner dies without doing it.

Workers die with the runner through PR_SET_PDEATHSIG, but that reaches only direct
children: a background command's own children, or anything a command started in
its process group, would outlive a SIGKILLed runner.  Every process the runner
starts leads a process group of its own; the runner tells the guard about each
group (`+PGID`) and about each it has reaped (`-PGID`) over the guard's stdin.
When stdin reaches end of file (the runner exited, normally or by SIGKILL, since
the kernel closes its end of the pipe either way), the guard SIGKILLs every group
still on its list and exits.

Run as `python -m runner.run.guard`; it imports only the standard library (and
runner.run.child, which starts it), ignores the terminal's signals (it has its own
session) and does nothing else.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from typing import IO, Optional

from runner.run.child import child_env, python_module


def serve(commands: IO[str]) -> set[int]:
    """Follow `+PGID` / `-PGID` lines until end of file; return the groups still alive."""
    groups: set[int] = set()
    for line in commands:
        line = line.strip()
        if len(line) > 1 and line[1:].isdigit():
            pgid = int(line[1:])
            if line[0] == "+":
                groups.add(pgid)
            elif line[0] == "-":
                groups.discard(pgid)
    return groups


def main() -> int:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGTSTP):
        signal.signal(sig, signal.SIG_IGN)
    for pgid in sorted(serve(sys.stdin)):
        try:
            os.killpg(pgid, signal.SIGKILL)
        except OSError:
            pass
    return 0


class Guard:
    """The runner's handle on its guard process."""

    def __init__(self) -> None:
        self.proc: Optional[subprocess.Popen[str]] = None
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
