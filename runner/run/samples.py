"""The shared sample buffer written by the native core, read from Python.

Layout (see _probe.c): a 64-byte file header, then per thread a 256-byte header
and `capacity` samples of 56 bytes.  The runner creates the file, the worker maps
it and its threads write into it; the runner reads it while the cell runs (for
progress) and after (for results), even when the worker was killed.
"""

from __future__ import annotations

import csv
import errno
import gzip
import io
import mmap
import os
import struct
from dataclasses import dataclass
from typing import Optional

from runner.results.files import write_atomic
from runner.results.samplesfile import SAMPLE_COLUMNS

FILE_HEADER = 64
SLOT_HEADER = 256
SAMPLE = struct.Struct("<qqqqiiiihhi")
_SLOT = struct.Struct("<iiQiiii4q4qQQqq16Q")
STATES = {0: "created", 1: "ready", 2: "running", 3: "done", 4: "failed"}
assert SAMPLE.size == 56 and _SLOT.size == SLOT_HEADER


@dataclass(frozen=True)
class Sample:
    """One callback: when it was due, when it ran, what happened during it."""

    scheduled_ns: int
    wake_ns: int
    end_ns: int
    burn_wall_ns: int
    nivcsw: int
    nvcsw: int
    minflt: int
    majflt: int
    cpu_start: int
    cpu_end: int
    missed: int

    @property
    def latency_ns(self) -> int:
        return self.wake_ns - self.scheduled_ns


@dataclass(frozen=True)
class SlotData:
    """One thread's header and samples, as the native core left them."""

    tid: int
    state: str
    count: int
    err_sched: int
    err_nice: int
    err_cpus: int
    err_other: int
    start_ru: tuple[int, int, int, int]  # nivcsw, nvcsw, minflt, majflt
    end_ru: tuple[int, int, int, int]
    loops: int
    missed: int
    work_start_ns: int
    work_end_ns: int
    cpus_seen: tuple[int, ...]
    samples: tuple[Sample, ...]

    @property
    def finished(self) -> bool:
        return self.state == "done"

    def totals(self) -> Optional[tuple[int, int, int, int]]:
        """Thread-wide deltas over the work, when the thread got to record them."""
        if not self.finished:
            return None
        return tuple(e - s for e, s in zip(self.end_ru, self.start_ru))  # type: ignore[return-value]


def file_size(nthreads: int, capacity: int) -> int:
    return FILE_HEADER + nthreads * (SLOT_HEADER + capacity * SAMPLE.size)


def slot_offset(index: int, capacity: int) -> int:
    return FILE_HEADER + index * (SLOT_HEADER + capacity * SAMPLE.size)


def create(path: str, nthreads: int, capacity: int) -> None:
    """Create the zero-filled buffer file the worker will map, with its disk space reserved.

    A page of a mapped sparse file that cannot be allocated kills the writer with SIGBUS
    in the middle of the run; reserving the space up front turns a disk too small for the
    run into an ENOSPC before anything starts.
    """
    with open(path, "wb") as handle:
        size = file_size(nthreads, capacity)
        try:
            os.posix_fallocate(handle.fileno(), 0, size)
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                handle.close()
                os.unlink(path)
                raise OSError(exc.errno, exc.strerror, path) from None
            handle.truncate(size)  # a file system that cannot reserve: sparse, as before


def _bits(words: tuple[int, ...]) -> tuple[int, ...]:
    return tuple(w * 64 + b for w, word in enumerate(words) for b in range(64) if word >> b & 1)


def parse_slot(buf: bytes | mmap.mmap, index: int, capacity: int, with_samples: bool = True) -> SlotData:
    """Decode one thread's slot from the buffer."""
    at = slot_offset(index, capacity)
    f = _SLOT.unpack_from(buf, at)
    count = min(f[2], capacity)
    samples: tuple[Sample, ...] = ()
    if with_samples and count:
        base = at + SLOT_HEADER
        samples = tuple(Sample(*SAMPLE.unpack_from(buf, base + i * SAMPLE.size)) for i in range(count))
    return SlotData(
        tid=f[0],
        state=STATES.get(f[1], "unknown"),
        count=count,
        err_sched=f[3],
        err_nice=f[4],
        err_cpus=f[5],
        err_other=f[6],
        start_ru=tuple(f[7:11]),
        end_ru=tuple(f[11:15]),
        loops=f[15],
        missed=f[16],
        work_start_ns=f[17],
        work_end_ns=f[18],
        cpus_seen=_bits(tuple(f[19:35])),
        samples=samples,
    )


def read(path: str, nthreads: int, capacity: int) -> list[SlotData]:
    """Every slot of a buffer file; slots a worker never initialised read as empty.

    The file is sized for the whole planned run (sparse until written), so it is mapped and
    only the samples each slot recorded are decoded: a long run stopped early reads what ran,
    not the gigabytes it had room for.
    """
    size = file_size(nthreads, capacity)
    with open(path, "rb") as handle:
        if os.fstat(handle.fileno()).st_size < size:
            data: bytes | mmap.mmap = handle.read().ljust(size, b"\0")
        else:
            data = mmap.mmap(handle.fileno(), size, prot=mmap.PROT_READ)
    try:
        return [parse_slot(data, i, capacity) for i in range(nthreads)]
    finally:
        if isinstance(data, mmap.mmap):
            data.close()


class Poller:
    """Read-only view of a live buffer, to count callbacks while the cell runs."""

    def __init__(self, path: str, nthreads: int, capacity: int):
        self.nthreads, self.capacity = nthreads, capacity
        fd = os.open(path, os.O_RDONLY)
        try:
            self.map = mmap.mmap(fd, file_size(nthreads, capacity), prot=mmap.PROT_READ)
        finally:
            os.close(fd)

    def counts(self) -> list[int]:
        return [struct.unpack_from("<Q", self.map, slot_offset(i, self.capacity) + 8)[0] for i in range(self.nthreads)]

    def sample(self, index: int, n: int) -> Sample:
        at = slot_offset(index, self.capacity) + SLOT_HEADER + n * SAMPLE.size
        return Sample(*SAMPLE.unpack_from(self.map, at))

    def close(self) -> None:
        self.map.close()


def write_samples(path: str, slots: list[tuple[str, SlotData]]) -> None:
    """Per-callback samples of a cell as gzip'd CSV (one row per callback), written atomically."""
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(list(SAMPLE_COLUMNS))
    for key, slot in slots:
        for seq, s in enumerate(slot.samples):
            out.writerow(
                [
                    key,
                    slot.tid,
                    seq,
                    s.scheduled_ns,
                    s.wake_ns,
                    s.end_ns,
                    s.latency_ns,
                    s.burn_wall_ns,
                    s.nivcsw,
                    s.nvcsw,
                    s.minflt,
                    s.majflt,
                    s.cpu_start,
                    s.cpu_end,
                    s.missed,
                ]
            )
    write_atomic(path, gzip.compress(buf.getvalue().encode("utf-8"), compresslevel=6))
