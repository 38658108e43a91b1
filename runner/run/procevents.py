"""The kernel's process events (the proc connector): threads created and renamed as it happens, stamped by the kernel.

Listing /proc/PID/task finds a new thread, or a new name, only at the next listing.  The
connector is a netlink multicast of every fork, exec, name change and exit on the machine,
sent as the kernel makes it and stamped with CLOCK_MONOTONIC, so a thread rule can be
applied the moment a matching name appears, and its delay measured from the kernel's
instant instead of from when the runner happened to look.

A socket filter (classic BPF, run by the kernel) passes only the events of the processes
being followed, so a machine that forks thousands of processes a second costs the runner
nothing.  The kernel answers a listen request with an acknowledgement; one that does not
(it ignores listeners outside its initial PID and user namespaces, as in most containers),
or one without the connector, leaves the caller to poll.  A listener that falls behind
loses events (ENOBUFS); `read` says so, and the caller lists /proc again.
"""

from __future__ import annotations

import enum
import errno
import os
import select
import socket
import struct
import sys
import time
from dataclasses import dataclass
from typing import Optional

NETLINK_CONNECTOR = 11
CN_IDX_PROC = 1
CN_VAL_PROC = 1
PROC_CN_MCAST_LISTEN = 1
PROC_CN_MCAST_IGNORE = 2
NLMSG_DONE = 3
RCVBUF_BYTES = 1 << 20  # about 13,000 events: a burst of thread creation does not overflow it
ACK_TIMEOUT_S = 0.25  # a kernel that acknowledges at all does so at once

_NLMSG = struct.Struct("=IHHII")  # len, type, flags, seq, pid
_CN = struct.Struct("=IIIIHH")  # idx, val, seq, ack, len, flags
_HEAD = struct.Struct("=IIQ")  # what, cpu, timestamp_ns
_IDS = struct.Struct("=II")
HEAD_AT = _NLMSG.size + _CN.size  # where a proc_event starts in a message
DATA_AT = HEAD_AT + _HEAD.size  # where its event_data starts


class Kind(enum.IntEnum):
    """`enum what` of the kernel's struct proc_event (linux/cn_proc.h), the kinds this module reads."""

    NONE = 0  # the acknowledgement of a listen request
    FORK = 0x1
    EXEC = 0x2
    COMM = 0x200
    EXIT = 0x80000000


@dataclass(frozen=True)
class ProcEvent:
    """One event: `tid` is the thread it is about (fork: the new one), `tgid` its process."""

    kind: Kind
    at_ns: int  # CLOCK_MONOTONIC, the kernel's
    tid: int = 0
    tgid: int = 0
    comm: str = ""  # COMM: the new name
    error: int = 0  # NONE: the errno of the listen request, 0 when it was taken


def _event(what: int, at_ns: int, data: bytes) -> Optional[ProcEvent]:
    if what == Kind.NONE and len(data) >= 4:
        return ProcEvent(Kind.NONE, at_ns, error=struct.unpack_from("=I", data)[0])
    if what == Kind.FORK and len(data) >= 16:
        tid, tgid = _IDS.unpack_from(data, 8)  # after parent_pid, parent_tgid
        return ProcEvent(Kind.FORK, at_ns, tid, tgid)
    if what == Kind.COMM and len(data) >= 24:
        tid, tgid = _IDS.unpack_from(data)
        return ProcEvent(Kind.COMM, at_ns, tid, tgid, data[8:24].split(b"\0", 1)[0].decode(errors="replace"))
    if what in (Kind.EXEC, Kind.EXIT) and len(data) >= 8:
        tid, tgid = _IDS.unpack_from(data)
        return ProcEvent(Kind(what), at_ns, tid, tgid)
    return None


def parse(datagram: bytes) -> list[ProcEvent]:
    """The events of one datagram (netlink messages carrying connector messages); what is not one is skipped."""
    events = []
    at = 0
    while at + _NLMSG.size <= len(datagram):
        length = _NLMSG.unpack_from(datagram, at)[0]
        if length < _NLMSG.size or at + length > len(datagram):
            break
        message = datagram[at : at + length]
        at += (length + 3) & ~3
        if len(message) < DATA_AT:
            continue
        idx, val, _, _, size, _ = _CN.unpack_from(message, _NLMSG.size)
        if (idx, val) != (CN_IDX_PROC, CN_VAL_PROC):
            continue
        what, _, at_ns = _HEAD.unpack_from(message, HEAD_AT)
        event = _event(what, at_ns, message[DATA_AT : HEAD_AT + size])
        if event is not None:
            events.append(event)
    return events


def _request(op: int, seq: int = 1) -> bytes:
    body = struct.pack("=I", op)
    cn = _CN.pack(CN_IDX_PROC, CN_VAL_PROC, seq, 0, len(body), 0)
    return _NLMSG.pack(_NLMSG.size + len(cn) + len(body), NLMSG_DONE, 0, seq, os.getpid()) + cn + body


# Classic BPF (linux/filter.h): loads from the packet are big-endian, the connector's fields are the host's.
_LD_W_ABS, _JEQ_K, _RET_K = 0x20, 0x15, 0x06
_INSN = struct.Struct("=HBBI")


def _host_word(value: int) -> int:
    """A host-order u32 as a BPF absolute load sees it."""
    return int.from_bytes(value.to_bytes(4, sys.byteorder), "big")


def socket_filter(tgids: frozenset[int]) -> bytes:
    """A program that keeps acknowledgements and the FORK, COMM and EXIT events of threads of `tgids`, and drops the rest.

    Fork events carry the new thread's process in child_tgid; comm and exit events in
    process_tgid.  Exec events are dropped: a followed program's threads are its own.
    """
    code: list[tuple[int, int, int, int]] = []
    accept: list[int] = []  # jumps to patch to the accepting return
    ids = sorted(tgids)

    def match_tgid(offset: int) -> None:
        code.append((_LD_W_ABS, 0, 0, offset))
        for pid in ids:
            accept.append(len(code))
            code.append((_JEQ_K, 0, 0, _host_word(pid)))
        code.append((_RET_K, 0, 0, 0))

    code.append((_LD_W_ABS, 0, 0, HEAD_AT))
    accept.append(len(code))
    code.append((_JEQ_K, 0, 0, _host_word(Kind.NONE)))
    fork_at = len(code)
    code.append((_JEQ_K, 0, 0, _host_word(Kind.FORK)))
    for_others = len(code)
    code.append((_JEQ_K, 0, 0, _host_word(Kind.COMM)))
    exit_at = len(code)
    code.append((_JEQ_K, 0, 0, _host_word(Kind.EXIT)))
    code.append((_RET_K, 0, 0, 0))
    fork_body = len(code)
    match_tgid(DATA_AT + 12)
    other_body = len(code)
    match_tgid(DATA_AT + 4)
    keep = len(code)
    code.append((_RET_K, 0, 0, 0xFFFFFFFF))

    def jump(at: int, to: int, when_true: bool) -> None:
        op, jt, jf, k = code[at]
        offset = to - at - 1
        code[at] = (op, offset if when_true else jt, jf if when_true else offset, k)

    # a mismatch falls through to the next test: only the true branches jump
    jump(fork_at, fork_body, True)
    jump(for_others, other_body, True)
    jump(exit_at, other_body, True)
    for at in accept:
        jump(at, keep, True)
    if any(not 0 <= jt <= 255 for _, jt, _, _ in code):
        raise ValueError("too many processes for one socket filter")
    return b"".join(_INSN.pack(*insn) for insn in code)


class ProcEvents:
    """A listening connector socket; `open` makes one or says why it cannot."""

    def __init__(self, sock: socket.socket):
        self._sock = sock

    @classmethod
    def open(cls, tgids: frozenset[int]) -> tuple[Optional[ProcEvents], str]:
        """Listen to the events of `tgids`' threads; (None, why not in words) when the kernel will not send them."""
        try:
            sock = socket.socket(socket.AF_NETLINK, socket.SOCK_DGRAM, NETLINK_CONNECTOR)
        except OSError as missing:
            return None, f"the kernel has no process events connector ({missing.strerror})"
        try:
            _buffer(sock)
            _attach(sock, socket_filter(tgids))
            sock.bind((0, CN_IDX_PROC))
            sock.send(_request(PROC_CN_MCAST_LISTEN))
            acknowledged = _acknowledgement(sock)
        except (OSError, ValueError) as failure:
            sock.close()
            return None, f"the process events connector refused to listen ({failure})"
        if acknowledged is None:
            sock.close()
            return None, "the kernel did not acknowledge a listen to its process events (it sends them only outside containers)"
        if acknowledged:
            sock.close()
            return None, f"the kernel refused to send process events ({os.strerror(acknowledged)})"
        return cls(sock), ""

    def fileno(self) -> int:
        return self._sock.fileno()

    def read(self, timeout_s: float) -> Optional[list[ProcEvent]]:
        """The events that arrived within `timeout_s` (at most one datagram's); None when some were lost."""
        ready, _, _ = select.select([self._sock], [], [], timeout_s)
        if not ready:
            return []
        try:
            return parse(self._sock.recv(65536))
        except OSError as error:
            if error.errno == errno.ENOBUFS:
                return None
            raise

    def close(self) -> None:
        try:
            self._sock.send(_request(PROC_CN_MCAST_IGNORE))
        except OSError:
            pass
        self._sock.close()


def _attach(sock: socket.socket, program: bytes) -> None:
    """SO_ATTACH_FILTER: a struct sock_fprog pointing at the program, which the kernel copies."""
    import ctypes

    buffer = ctypes.create_string_buffer(program, len(program))
    fprog = struct.pack("HP", len(program) // _INSN.size, ctypes.addressof(buffer))
    sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_ATTACH_FILTER", 26), fprog)


def _buffer(sock: socket.socket) -> None:
    """A receive buffer of RCVBUF_BYTES: forced past rmem_max where the runner may (CAP_NET_ADMIN), else as large as allowed."""
    force = getattr(socket, "SO_RCVBUFFORCE", 33)
    try:
        sock.setsockopt(socket.SOL_SOCKET, force, RCVBUF_BYTES)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)


def _acknowledgement(sock: socket.socket) -> Optional[int]:
    """The errno the kernel acknowledged the listen request with; None when it sent none."""
    until = time.monotonic() + ACK_TIMEOUT_S
    while (left := until - time.monotonic()) > 0:
        ready, _, _ = select.select([sock], [], [], left)
        if not ready:
            break
        for event in parse(sock.recv(65536)):
            if event.kind is Kind.NONE:
                return event.error
    return None
