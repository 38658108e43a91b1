"""A program's output kept up to its limit: the reader against writers in this process, through real pipes.

The writers are threads here, so each check is exact and quick; what matters is what the
program sees (every write taken, at once, however much it writes) and what the file holds.
"""

from __future__ import annotations

import os
import threading
import time

import pytest

from runner.run.output import CappedOutput
from runner.run.rawcell import OutputCount

MiB = 1 << 20


def _pattern(n: int) -> bytes:
    """`n` bytes that say where they are: a slice in the wrong place, or from the wrong end, does not match."""
    return b"".join(b"%09d\n" % i for i in range(n // 10 + 1))[:n]


def _write(fd: int, data: bytes, chunk: int = 64 << 10) -> threading.Thread:
    """Write `data` to `fd` from a thread, as a program writes its stdout, and close it (the program's exit)."""

    def run() -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view[:chunk]) :]
        os.close(fd)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def _program(out: CappedOutput) -> int:
    """The program's copy of the write end; the runner's own closed, as after the fork."""
    fd = os.dup(out.write_fd)
    out.close_write_end()
    return fd


def test_the_first_bytes_up_to_the_limit_are_kept_and_the_rest_counted(tmp_path):
    path = str(tmp_path / "p.stdout")
    data = _pattern(3 * MiB + 12345)
    out = CappedOutput(path, MiB)
    writer = _write(_program(out), data, chunk=7777)
    writer.join(10)
    count = out.finish()
    assert not writer.is_alive()
    with open(path, "rb") as handle:
        assert handle.read() == data[:MiB]
    assert (count.written, count.kept, count.dropped, count.limit) == (len(data), MiB, len(data) - MiB, MiB)
    assert count.tail == data[-len(count.tail) :] and len(count.tail) == 8192  # the last words, though past the limit
    assert count.error == "" and not count.held_open


def test_output_under_the_limit_is_kept_whole_and_0_bytes_keeps_none(tmp_path):
    data = _pattern(100_000)
    for limit, kept in ((MiB, len(data)), (0, 0)):
        path = str(tmp_path / f"{limit}.stdout")
        out = CappedOutput(path, limit)
        _write(_program(out), data).join(10)
        assert out.finish() == OutputCount(len(data), kept, limit, tail=data[-8192:])
        assert os.path.getsize(path) == kept


def test_a_writer_far_past_the_limit_is_never_held_up(tmp_path):
    """256 MiB through a 64 KiB limit: a reader that stopped draining at the limit would block the writer at once."""
    out = CappedOutput(str(tmp_path / "p.stdout"), 64 << 10)
    block = b"y" * MiB
    fd = _program(out)
    started = time.monotonic()

    def run() -> None:
        for _ in range(256):
            os.write(fd, block)
        os.close(fd)

    writer = threading.Thread(target=run, daemon=True)
    writer.start()
    writer.join(30)
    took = time.monotonic() - started
    assert not writer.is_alive(), "the writer was held up: its pipe was not drained past the limit"
    count = out.finish()
    assert (count.written, count.kept) == (256 * MiB, 64 << 10)
    print(f"256 MiB through the reader in {took:.2f}s: {256 / took:.0f} MiB/s")


def test_a_full_disk_keeps_what_it_took_says_why_and_still_drains(tmp_path):
    out = CappedOutput(str(tmp_path / "p.stdout"), MiB)
    full = os.open("/dev/full", os.O_WRONLY)  # its file, on a disk that is full: every write ENOSPC
    os.dup2(full, out._file)
    os.close(full)
    data = _pattern(4 * MiB)
    writer = _write(_program(out), data)
    writer.join(10)
    count = out.finish()
    assert not writer.is_alive()
    assert (count.written, count.kept, count.dropped) == (len(data), 0, len(data))
    assert count.error == "the disk is full"


def test_a_process_that_keeps_the_pipe_open_past_the_end_does_not_hang_the_cell(tmp_path):
    """A daemon of the program, left alive (no cgroup), holds the write end: the reader stops at the deadline all the same."""
    path = str(tmp_path / "p.stdout")
    out = CappedOutput(path, MiB)
    daemon = _program(out)
    try:
        os.write(daemon, b"before the end\n")
        started = time.monotonic()
        count = out.finish(time.monotonic() + 0.2)
        assert time.monotonic() - started < 5
        assert count.held_open and count.written == 15 and count.kept == 15
        with pytest.raises(BrokenPipeError):  # what the daemon writes after goes nowhere, and says so to it
            os.write(daemon, b"after")
    finally:
        os.close(daemon)


def test_a_file_whose_writes_stall_does_not_hang_the_cell(tmp_path, monkeypatch):
    """A hung network file system holds the reader in a write to its file: the cell ends without it, and says so."""
    from runner.run import output

    path = str(tmp_path / "p.stdout")
    stuck = threading.Event()
    release = threading.Event()
    real_write = os.write

    def write(fd: int, data: bytes) -> int:
        if fd == out._file:
            stuck.set()
            release.wait(30)
        return real_write(fd, data)

    monkeypatch.setattr(output, "STALL_WAIT_S", 0.2)
    out = CappedOutput(path, MiB)
    monkeypatch.setattr(output.os, "write", write)
    program = _program(out)
    try:
        real_write(program, b"a line\n")
        assert stuck.wait(5), "the reader reached its file"
        began = time.monotonic()
        count = out.finish(time.monotonic() + 0.2)
        assert time.monotonic() - began < 5, "the cell went on"
        assert "p.stdout stalled" in count.error and count.written == 7
    finally:
        release.set()
        os.close(program)
        out._thread.join(5)
