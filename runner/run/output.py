"""A program's standard output or error kept up to a limit, the rest counted and dropped, the program never held up.

Handed a file, a program that logs at full speed (or loops printing) for an hour-long cell
fills the disk, and then the run's own results cannot be written.  RLIMIT_FSIZE would bound
the file but fail the program's writes (EFBIG, SIGXFSZ), which changes what it does.  So the
program writes to a pipe, and a thread of the runner reads it in large chunks: the first
`limit` bytes go to the file, the rest are read and discarded, and every byte is counted.
Every write of the program succeeds, beyond the limit too, at the pace of a pipe.

The thread is the runner's, in the runner's process: its GIL is not the program's.  The pipe
is widened to PIPE_BYTES where the kernel lets it, so a program is held up only should the
runner not take its turn for as long as the program needs to write that much.  On the 2-CPU
VM it drained `head -c 4G /dev/zero` at 4 GB/s, and at 0.4 GB/s while another thread of the
runner spun in Python (the reader then waits for the GIL at each read); the same program wrote
0.3 GB/s to a file on that VM's disk.  The last TAIL_BYTES read
are kept in memory, dropped or not, so a program that fails says its last words even when
its file was full long before.
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import threading
import time
from typing import Optional

from runner.run.rawcell import OutputCount
from runner.safefs import open_write

CHUNK = 1 << 20  # bytes read at once: a whole widened pipe in one call
PIPE_BYTES = 1 << 20  # the pipe's capacity asked of the kernel (the default most machines allow unprivileged: pipe-max-size)
TAIL_BYTES = 8192  # the last bytes read, kept for the failure message's last lines
FINISH_WAIT_S = 1.0  # at the cell's end, how long to wait for the pipe's end of file (every writer gone)
STALL_WAIT_S = 5.0  # then, woken, how long the reader may take to write what the pipe still held


class CappedOutput:
    """A pipe for a program's stdout or stderr, drained by a thread into `path` up to `limit` bytes; the rest counted.

    Use: `write_fd` goes to the program; `close_write_end` once it holds its copy (else the
    pipe never reaches its end of file); `finish` at the cell's end, after the program (and
    what it started) was stopped.
    """

    def __init__(self, path: str, limit: int) -> None:
        if limit < 0:
            raise ValueError(f"an output limit is 0 bytes or more, not {limit}")
        self.path, self.limit = path, limit
        self.written = self.kept = 0
        self.error = ""
        self._tail = b""
        self._eof = False
        fds: list[int] = []
        try:
            fds.append(open_write(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644))  # never through a link
            fds += os.pipe()  # both ends close-on-exec: the program's copy is the one dup2 puts on 1 or 2
            fds += os.pipe()  # to wake the reader at the cell's end, should the pipe not reach its end of file
        except BaseException:
            for fd in fds:
                os.close(fd)
            raise
        self._file, self._read, self.write_fd, self._wake_read, self._wake_write = fds
        try:
            fcntl.fcntl(self._read, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:
            pass  # above pipe-max-size, or the user's pipe quota spent: the default 64 KiB, drained all the same
        self._thread = threading.Thread(target=self._run, name=f"output {os.path.basename(path)}", daemon=True)
        self._thread.start()

    def close_write_end(self) -> None:
        """Close the runner's copy of the write end, once the program holds its own: its exit is then the pipe's end of file."""
        if self.write_fd >= 0:
            os.close(self.write_fd)
            self.write_fd = -1

    def finish(self, deadline: Optional[float] = None) -> OutputCount:
        """Wait (until `deadline`, time.monotonic(); FINISH_WAIT_S from now without) for the end of file, then stop reading.

        Every process that holds the write end is normally gone by now (the program's group and
        cgroup were killed); one that is not (a daemon of a program the runner could not give a
        cgroup) must not hang the cell: what the pipe holds then is read, and the reader stops.
        """
        self.close_write_end()
        if deadline is None:
            deadline = time.monotonic() + FINISH_WAIT_S
        self._thread.join(max(0.0, deadline - time.monotonic()))
        held_open = self._thread.is_alive()
        if held_open:
            os.write(self._wake_write, b"x")
            self._thread.join(STALL_WAIT_S)
        if self._thread.is_alive():  # stuck in a write to its file (a hung network file system): the cell ends without it
            self.error = self.error or f"writing {os.path.basename(self.path)} stalled; the runner went on without the rest"
            # its descriptors stay open while it may still use them: a number closed here could be another file's next
            return OutputCount(self.written, self.kept, self.limit, self.error, False, self._tail)
        for fd in (self._read, self._wake_read, self._wake_write, self._file):
            if fd >= 0:
                os.close(fd)
        self._read = self._wake_read = self._wake_write = self._file = -1
        return OutputCount(self.written, self.kept, self.limit, self.error, held_open and not self._eof, self._tail)

    def _run(self) -> None:
        """Read until the end of file (or the wake-up, then what the pipe holds), keeping the first `limit` bytes."""
        buffer = bytearray(CHUNK)
        view = memoryview(buffer)
        poller = select.poll()
        poller.register(self._read, select.POLLIN)
        poller.register(self._wake_read, select.POLLIN)
        budget: Optional[int] = None  # once woken: bytes still to read, what the pipe can hold
        while budget is None or budget > 0:
            if budget is None and any(fd == self._wake_read for fd, _ in poller.poll()):
                budget = _pipe_size(self._read)
                os.set_blocking(self._read, False)
            try:
                n = os.readv(self._read, [view[: CHUNK if budget is None else min(CHUNK, budget)]])
            except BlockingIOError:
                return
            except OSError as exc:  # not expected of a pipe: said, and the cell's end closes it (the program then gets EPIPE)
                self.error = self.error or f"reading the pipe failed: {exc.strerror}"
                return
            if not n:
                self._eof = True
                return
            if budget is not None:
                budget -= n
            self._take(view[:n])

    def _take(self, data: memoryview) -> None:
        """Count `data`, write what the limit leaves room for, and keep its end as the tail."""
        n = len(data)
        self.written += n
        room = self.limit - self.kept if self._file >= 0 and not self.error else 0
        if room > 0:
            part = data[:room]
            try:
                while part:
                    done = os.write(self._file, part)
                    self.kept += done
                    part = part[done:]
            except OSError as exc:
                self.error = "the disk is full" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else f"its write failed: {exc.strerror}"
        self._tail = (self._tail + bytes(data[-TAIL_BYTES:]))[-TAIL_BYTES:]


def _pipe_size(fd: int) -> int:
    """The pipe's capacity: what it holds at most, so what a reader woken at the end still has to read."""
    try:
        return fcntl.fcntl(fd, fcntl.F_GETPIPE_SZ)
    except OSError:
        return PIPE_BYTES
