"""The kernel's process events: datagrams parsed without a socket, and the filtered subscription against the real kernel."""

from __future__ import annotations

import ctypes
import os
import struct
import subprocess
import threading
import time

import pytest

from runner.run import procevents
from runner.run.procevents import Kind, ProcEvent, ProcEvents, parse, socket_filter


def _message(what: int, at_ns: int, data: bytes, idx: int = procevents.CN_IDX_PROC) -> bytes:
    body = struct.pack("=IIQ", what, 1, at_ns) + data
    cn = struct.pack("=IIIIHH", idx, procevents.CN_VAL_PROC, 0, 0, len(body), 0)
    return struct.pack("=IHHII", 16 + len(cn) + len(body), procevents.NLMSG_DONE, 0, 0, 0) + cn + body


def test_fork_comm_exit_and_the_acknowledgement_are_read_with_the_kernels_timestamp():
    fork = _message(Kind.FORK, 10, struct.pack("=IIII", 1, 1, 502, 500))
    comm = _message(Kind.COMM, 11, struct.pack("=II", 502, 500) + b"ctl_loop".ljust(16, b"\0"))
    gone = _message(Kind.EXIT, 12, struct.pack("=IIII", 502, 500, 0, 15))
    ack = _message(Kind.NONE, 13, struct.pack("=I", 1))
    assert parse(fork + comm) == [ProcEvent(Kind.FORK, 10, 502, 500), ProcEvent(Kind.COMM, 11, 502, 500, "ctl_loop")]
    assert parse(gone) == [ProcEvent(Kind.EXIT, 12, 502, 500)]
    assert parse(ack) == [ProcEvent(Kind.NONE, 13, error=1)]


def test_what_is_not_a_process_event_or_is_cut_short_is_skipped():
    fork = _message(Kind.FORK, 10, struct.pack("=IIII", 1, 1, 502, 500))
    assert parse(_message(Kind.FORK, 10, struct.pack("=IIII", 1, 1, 502, 500), idx=7)) == []  # another connector
    assert parse(_message(0x40, 10, struct.pack("=IIII", 1, 1, 502, 500))) == []  # a kind not read (ptrace)
    assert parse(fork[:-4]) == []  # its netlink length runs past the datagram
    assert parse(_message(Kind.COMM, 11, struct.pack("=II", 502, 500))) == []  # no room for the name
    assert parse(b"\x01\x02") == []


def test_the_socket_filter_keeps_the_jumps_in_range_and_refuses_what_one_program_cannot_hold():
    program = socket_filter(frozenset({100, 200}))
    assert len(program) % 8 == 0
    assert socket_filter(frozenset(range(1, 100)))  # a cell's programs fit
    with pytest.raises(ValueError):
        socket_filter(frozenset(range(1, 300)))


@pytest.fixture
def events():
    listener, why = ProcEvents.open(frozenset({os.getpid()}))
    if listener is None:
        pytest.skip(f"no process events here: {why}")
    yield listener
    listener.close()


def _collect(listener: ProcEvents, seconds: float) -> list[ProcEvent]:
    out: list[ProcEvent] = []
    until = time.monotonic() + seconds
    while time.monotonic() < until:
        out += listener.read(0.05) or []
    return out


def test_the_kernel_sends_this_processs_thread_events_and_filters_out_every_other_process(events):
    before = time.monotonic_ns()
    named = threading.Event()

    def rename() -> None:
        ctypes.CDLL(None).prctl(15, b"pe_renamed", 0, 0, 0)  # PR_SET_NAME: this thread only
        named.set()

    thread = threading.Thread(target=rename)
    thread.start()
    thread.join()
    child = subprocess.run(["sh", "-c", "echo $$"], capture_output=True, text=True, check=True)
    seen = _collect(events, 0.3)
    after = time.monotonic_ns()
    mine = [e for e in seen if e.tgid == os.getpid()]
    kinds = [e.kind for e in mine]
    assert Kind.FORK in kinds and Kind.EXIT in kinds, seen
    assert any(e.kind is Kind.COMM and e.comm == "pe_renamed" for e in mine), seen
    assert all(before <= e.at_ns <= after for e in mine)  # CLOCK_MONOTONIC, the clock the runner stamps with
    assert all(e.tgid == os.getpid() for e in seen), f"another process's event passed the filter ({child.stdout.strip()})"
