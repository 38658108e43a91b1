"""Workers forked from a warm process: a cell's processes start in milliseconds, not an interpreter's start each.

A fresh `python -m runner.run.worker` takes 30-40 ms to start and import before it reads
its spec, and a cell starts one per process instance and per hog, all at once, on the
same CPUs: 16 of them on 2 CPUs cost a quarter of a second before the first callback.
The zygote is started once per run, imports the worker, and then only forks: each
child sets itself up as the worker's own start would (a session of its own, its
pipes on 0, 1 and 2, the descriptors it was given at 3, 4, ..., `/` as its folder,
default signals) and runs `worker.main()`.

The zygote is the workers' parent, so it reaps them and reports each exit status to
the runner, having killed what was left in the worker's process group first: that number is
a worker's only while its zombie holds it, so the runner never signals the group of a worker
the zygote reported (runner/run/workers.py `exit_code`); `ZygoteChild` offers what the runner uses of a `subprocess.Popen`
(pid, stdin, stdout, poll, wait, returncode).  A worker dies with the zygote
(PR_SET_PDEATHSIG, checked against the zygote's pid), and the zygote with the runner
(the same, plus the guard, which kills every process group it was told of).  The
runner falls back to starting workers itself when the zygote cannot start or dies.

Run as `python -m runner.run.zygote FD` (FD: its end of a SOCK_SEQPACKET socket pair).
Messages are JSON, one per datagram: `{"spawn": N}` with N descriptors attached
(stdin, stdout, stderr, then those to pass) gets `{"pid": P}` or `{"error": "..."}`;
`{"exit": P, "status": S}` follows when a child ends (S as os.waitpid gives it).
"""

from __future__ import annotations

import array
import fcntl
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
import traceback
from collections.abc import Sequence
from typing import IO, TYPE_CHECKING, Any, Optional

from runner.run.child import child_env, python_module, signal_name

if TYPE_CHECKING:
    from runner.run.guard import Watcher

_MAX_FDS = 8
_READY_TIMEOUT_S = 10.0


class ZygoteError(OSError):
    """The zygote could not fork a worker (it died, or the kernel refused)."""


class ZygoteChild:
    """A worker the zygote forked, as the runner sees it: the part of subprocess.Popen the runner uses."""

    def __init__(self, zygote: Zygote, pid: int, stdin: IO[str], stdout: IO[str]) -> None:
        self._zygote = zygote
        self.pid = pid
        self.stdin: Optional[IO[str]] = stdin
        self.stdout: Optional[IO[str]] = stdout
        self.returncode: Optional[int] = None

    def poll(self) -> Optional[int]:
        """Its exit code (negative: the signal that ended it), or None while it runs."""
        if self.returncode is None:
            self._zygote.pump(0.0)
            self._take()
        return self.returncode

    def wait(self, timeout: Optional[float] = None) -> int:
        """Wait for its exit; subprocess.TimeoutExpired after `timeout` seconds, as Popen.wait."""
        until = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            left = None if until is None else until - time.monotonic()
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(f"worker {self.pid}", timeout or 0.0)
            self._zygote.pump(left)
        assert self.returncode is not None
        return self.returncode

    def _take(self) -> None:
        status = self._zygote.statuses.pop(self.pid, None)
        if status is not None:
            self.returncode = os.waitstatus_to_exitcode(status)
        elif self._zygote.sock is None:  # the zygote died: PR_SET_PDEATHSIG killed its children with it
            self.returncode = -signal.SIGKILL


class Zygote:
    """The runner's handle on its zygote process."""

    def __init__(self, proc: subprocess.Popen[bytes], sock: socket.socket) -> None:
        self.proc = proc
        self.sock: Optional[socket.socket] = sock
        self.statuses: dict[int, int] = {}  # exit statuses the zygote reported, by pid, until their child takes them
        self.failure = ""  # why it stopped serving, in words
        self.closed = False  # ended and reaped: a second close() does nothing

    @classmethod
    def start(cls, guard: Optional[Watcher] = None) -> Optional[Zygote]:
        """Start the zygote (it gets ready while the run prepares); None where this kernel has no pidfds."""
        if not hasattr(os, "pidfd_open"):
            return None
        try:
            os.close(os.pidfd_open(os.getpid()))
        except OSError:
            return None  # before Linux 5.3: the zygote waits on its children's pidfds
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            proc = subprocess.Popen(
                [*python_module("runner.run.zygote"), str(theirs.fileno())],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                pass_fds=(theirs.fileno(),),
                start_new_session=True,
                close_fds=True,
                cwd="/",
                env=child_env(RUNNER_PARENT_PID=str(os.getpid())),
            )
        except OSError:
            ours.close()
            return None
        finally:
            theirs.close()
        if guard is not None:
            guard.watch(proc.pid)
        return cls(proc, ours)

    def spawn(self, stdin: int, stdout: int, stderr: int, pass_fds: Sequence[int]) -> int:
        """Fork a worker with these descriptors (passed ones land at 3, 4, ... in order); its pid. Raises ZygoteError."""
        if self.sock is None:
            raise ZygoteError(f"the zygote is gone: {self.failure}")
        fds = [stdin, stdout, stderr, *pass_fds]
        try:
            self.sock.sendmsg([json.dumps({"spawn": len(fds)}).encode()], [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", fds))])
        except OSError as error:
            self._lost(f"cannot reach the zygote: {error.strerror or error}")
            raise ZygoteError(self.failure) from None
        until = time.monotonic() + _READY_TIMEOUT_S
        while self.sock is not None:
            message = self._receive(max(0.0, until - time.monotonic()))
            if message is None:
                if time.monotonic() >= until:
                    self._lost(f"the zygote did not answer within {_READY_TIMEOUT_S:g}s")
                continue
            if "pid" in message:
                return int(message["pid"])
            if "error" in message:
                raise ZygoteError(f"the zygote could not fork: {message['error']}")
        raise ZygoteError(self.failure)

    def pump(self, timeout: Optional[float]) -> None:
        """Take the exit statuses the zygote has sent (waiting up to `timeout` s for one; None: until one comes)."""
        while self.sock is not None and self._receive(timeout) is not None:
            timeout = 0.0

    def _receive(self, timeout: Optional[float]) -> Optional[dict[str, Any]]:
        """One message (exit statuses are filed on the way), or None when none came in time."""
        assert self.sock is not None
        ready, _, _ = select.select([self.sock], [], [], timeout)
        if not ready:
            return None
        try:
            data = self.sock.recv(4096)
        except OSError as error:
            self._lost(f"the zygote's socket failed: {error.strerror or error}")
            return None
        if not data:
            self._lost(f"the zygote exited ({self._exit_words()})")
            return None
        message: dict[str, Any] = json.loads(data)
        if "exit" in message:
            self.statuses[int(message["exit"])] = int(message["status"])
        return message

    def _exit_words(self) -> str:
        try:
            code = self.proc.wait(timeout=1)
        except subprocess.TimeoutExpired:
            return "still running"
        return f"killed by {signal_name(-code)}" if code < 0 else f"code {code}"

    def _lost(self, why: str) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None
            self.failure = why

    def close(self, guard: Optional[Watcher] = None) -> None:
        """End the zygote (its end of the socket reaches end of file) and reap it."""
        if self.sock is not None:
            self.sock.close()
            self.sock = None
            self.failure = "closed"
        if self.closed:
            return
        try:
            self.proc.wait(timeout=2)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if guard is not None:
            guard.forget(self.proc.pid)
        self.closed = True


# ---- the zygote process ----


def serve(sock: socket.socket) -> int:
    """Fork a worker for each request, report each child's exit, until the runner closes its end."""
    from runner.run import _probe, worker  # noqa: F401  (imported here, once: what every child then finds loaded)

    children: dict[int, int] = {}  # pidfd -> pid
    poller = select.poll()
    poller.register(sock, select.POLLIN)
    while True:
        for fd, _ in poller.poll():
            if fd == sock.fileno():
                data, ancdata, _, _ = sock.recvmsg(4096, socket.CMSG_SPACE(_MAX_FDS * 4))
                if not data:
                    return 0
                fds = _received_fds(ancdata)
                try:
                    reply = _fork(sock, fds, children, poller)
                finally:
                    for each in fds:
                        os.close(each)
                sock.send(json.dumps(reply).encode())
            else:
                pid = children.pop(fd)
                poller.unregister(fd)
                os.close(fd)
                try:  # its group, while its zombie still holds the number: once reaped, the number may be anyone's
                    os.killpg(pid, signal.SIGKILL)
                except OSError:
                    pass
                _, status = os.waitpid(pid, 0)
                sock.send(json.dumps({"exit": pid, "status": status}).encode())


def _received_fds(ancdata: list[tuple[int, int, bytes]]) -> list[int]:
    fds = array.array("i")
    for level, kind, data in ancdata:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            fds.frombytes(data[: len(data) - len(data) % fds.itemsize])
    return list(fds)


def _fork(sock: socket.socket, fds: list[int], children: dict[int, int], poller: select.poll) -> dict[str, Any]:
    if len(fds) < 3:
        return {"error": f"a spawn needs stdin, stdout and stderr; {len(fds)} descriptors came"}
    zygote = os.getpid()
    try:
        pid = os.fork()
    except OSError as error:
        return {"error": error.strerror or str(error)}
    if pid == 0:
        _become_worker(zygote, fds)  # never returns
    pidfd = os.pidfd_open(pid)  # our child, not reaped yet: its pidfd can always be had
    children[pidfd] = pid
    poller.register(pidfd, select.POLLIN)
    return {"pid": pid}


def _become_worker(zygote: int, fds: list[int]) -> None:
    """In the forked child: the process a fresh `python -m runner.run.worker` would have been; exits, never returns."""
    code = 70
    try:
        os.setsid()
        high = [fcntl.fcntl(fd, fcntl.F_DUPFD, len(fds)) for fd in fds]  # above every target: no dup2 below overwrites one
        for target, fd in enumerate(high):
            os.dup2(fd, target)
        os.closerange(len(fds), os.sysconf("SC_OPEN_MAX"))
        os.chdir("/")
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        # sys.stdin, stdout and stderr now read and write the new 0, 1 and 2: the zygote never used them, so
        # they hold nothing buffered of its own
        os.environ["RUNNER_PARENT_PID"] = str(zygote)
        from runner.run import worker

        code = worker.main()
        sys.stdout.flush()
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else 1
    except BaseException:
        traceback.print_exc()
    finally:
        try:
            sys.stderr.flush()
        finally:
            os._exit(code)


def main() -> int:
    from runner.run import _probe

    _probe.set_pdeathsig(signal.SIGKILL)  # no zygote outlives the runner
    if os.environ.get("RUNNER_PARENT_PID") not in (None, str(os.getppid())):
        return 3  # the runner died before the line above took effect
    for sig in (signal.SIGINT, signal.SIGTSTP, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)  # its own session has no terminal; the runner ends it by closing the socket
    sock = socket.socket(fileno=int(sys.argv[1]))
    try:
        return serve(sock)
    finally:
        sock.close()


if __name__ == "__main__":
    raise SystemExit(main())
