"""Hold /dev/cpu_dma_latency for a run, as cyclictest does, so deep CPU idle states do not add wake-up latency.

The device is the kernel's CPU latency QoS: while a process holds it open with a value
written (a 32-bit int, in microseconds), no CPU enters an idle state whose exit takes
longer; closing it withdraws the request.  Reading 4 bytes gives the value in force, the
lowest any holder asks for, which is what the runner records beside what it asked for.

Holding it needs write access to the device (root, as a rule).  When it cannot be held
the run goes on and the results say why: it is a condition of the measurement, not a
reason to stop.
"""

from __future__ import annotations

import contextlib
import errno
import os
import struct
from collections.abc import Iterator
from typing import Optional

from runner.results.document import DMA_LATENCY_NO_LIMIT_US, DmaLatency

DEVICE = "/dev/cpu_dma_latency"
MAX_US = DMA_LATENCY_NO_LIMIT_US  # PM_QOS_CPU_LATENCY_DEFAULT_VALUE: the largest value, "no limit"
_VALUE = struct.Struct("=i")  # the kernel's s32, in this machine's byte order


@contextlib.contextmanager
def hold(request_us: Optional[int], device: str = DEVICE) -> Iterator[DmaLatency]:
    """Hold `device` at `request_us` until the block ends; yield what was held (or why not) for the results.

    `request_us` None leaves the device alone (`--no-dma-latency`): the record then says what it
    reads, which another program may be holding.  Never raises for the device: a missing device,
    EACCES or a refused value become the record's note.
    """
    if request_us is None:
        yield DmaLatency(requested_us=None, reads_us=read_value(device), note="left alone (--no-dma-latency)")
        return
    try:
        fd = os.open(device, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)  # workers must not inherit it; never through a link
    except OSError as exc:
        yield DmaLatency(requested_us=request_us, reads_us=read_value(device), note=_why(exc, device, "open"))
        return
    try:
        try:
            written = os.write(fd, _VALUE.pack(request_us))
        except OSError as exc:
            yield DmaLatency(requested_us=request_us, reads_us=_read_fd(fd), note=_why(exc, device, f"write {request_us} to"))
            return
        if written != _VALUE.size:
            yield DmaLatency(requested_us=request_us, reads_us=_read_fd(fd), note=f"{device} took {written} of 4 bytes; not held")
            return
        yield DmaLatency(requested_us=request_us, held=True, reads_us=_read_fd(fd))
    finally:
        os.close(fd)


def read_value(device: str = DEVICE) -> Optional[int]:
    """The latency in force, in us, as the device reads (opening it alone asks for nothing); None when unreadable."""
    try:
        fd = os.open(device, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        return _read_fd(fd)
    finally:
        os.close(fd)


def _read_fd(fd: int) -> Optional[int]:
    try:
        data = os.pread(fd, _VALUE.size, 0)
    except OSError:
        return None
    return _VALUE.unpack(data)[0] if len(data) == _VALUE.size else None


def _why(exc: OSError, device: str, action: str) -> str:
    """Why the device could not be held, in words a user can act on."""
    reason = exc.strerror or str(exc)
    if exc.errno == errno.ENOENT:
        return f"{device} does not exist (a container without the device, or a kernel without CPU idle support); not held"
    if exc.errno == errno.ELOOP:
        return f"{device} is a symbolic link, which the runner never writes through (the device is not); not held"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return f"cannot {action} {device}: {reason} (it needs root or write access to the device); not held"
    return f"cannot {action} {device}: {reason}; not held"
