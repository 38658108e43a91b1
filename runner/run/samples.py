"""The shared sample buffer written by the native core, read from Python.

Layout (see records.h, version 7): a 128-byte file header (with the start gate), then per thread a 512-byte
header of totals and running figures, four log-linear histograms (latency, slack,
negative slack, callback wall time; see runner/histogram.py), a ring of 112-byte
samples (each followed by a 16-byte wait per lock slot, in a worker whose programs lock
mutexes), and for programs (`kind: phases`) the figures of each event (with its
histogram; one more for the chain latency) and of each phase.  The runner creates the buffer as a memfd (RAM that no writeback ever
write-protects, gone with the runner), the worker maps it and its threads write
into it; the runner drains the ring to disk while the cell runs and reads the
figures after, even when the worker was killed.  Nothing here grows with the run.
Every record is read by field name from the native core's own table (runner/run/records.py).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
import mmap
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import NamedTuple, Optional

from runner import histogram as hg
from runner.histogram import Histogram
from runner.run import _probe, records
from runner.run.records import EVENT_STATS, PHASE_STATS
from runner.run.records import SLOT_HEADER as HEADER

FILE_HEADER = _probe.FILE_HEADER
SLOT_HEADER = HEADER.size
HIST_SETS = _probe.HIST_SETS
SAMPLE = records.SAMPLE.struct
LOCK_WAIT = records.LOCK_WAIT.struct  # wait ns, holder gid (-1: never contended), times taken, times contended
STATES = {0: "created", 1: "ready", 2: "running", 3: "done", 4: "failed", 5: "starting"}  # records.h's enum slot_state
_WORKING = (1, 2, 5)  # ready, running, and a spawned thread being created
EV_HDR = EVENT_STATS.size
PHASE_BYTES = PHASE_STATS.size


@dataclass(frozen=True)
class LockWait:
    """One activation's wait for one mutex: summed over its locks of it, with who held it when the longest began."""

    wait_ns: int
    holder: int  # the holder's gid (the cell's thread number) when the longest contended wait began; -1: none seen
    taken: int
    contended: int


class Sample(NamedTuple):
    """One callback: the release it served, when it ran, what happened during it.

    A named tuple, not a dataclass: a large cell's rings are drained by the thousand
    every tick, and a tuple is made from the native record in one step (a frozen
    dataclass of these fields took 6.5 us each, its own setattr per field).
    """

    scheduled_ns: int
    wake_ns: int
    end_ns: int
    burn_wall_ns: int
    seq: int
    nivcsw: int
    nvcsw: int
    minflt: int
    majflt: int
    cpu_start: int
    cpu_end: int
    missed: int
    lock_wait_ns: int = 0  # programs: blocked acquiring mutexes during this activation
    cond_wait_ns: int = 0  # programs: blocked in wait on a condition variable
    barrier_wait_ns: int = 0  # programs: blocked at barriers
    origin_ns: int = 0  # programs: the timer release that started this activation's chain; 0: none
    period_ns: int = 0  # the grid's step to its release: the period of the timer event that released it; 0: released by a resume
    next_ns: int = 0  # the release after it on its grid (a program's next timer event may step by another period); 0: none
    locks: tuple[LockWait, ...] = ()  # programs: its wait for each mutex the thread locks, by lock slot

    def chain_ns(self) -> Optional[int]:
        """From the chain's first release to this activation's end (programs in a chain); None outside a chain."""
        return self.end_ns - self.origin_ns if self.origin_ns > 0 else None

    def release_latency(self) -> int:
        """From the oldest release this wake-up answered (the first of those skipped, if any) to the wake-up."""
        return self.wake_ns - self.scheduled_ns + self.missed * self.period_ns

    def slack(self) -> Optional[int]:
        """From the end of the callback to its next release; negative when it overran; None without one (released by a resume)."""
        return self.next_ns - self.end_ns if self.next_ns > 0 else None


records.require_order(records.LOCK_WAIT, [f.name for f in dataclasses.fields(LockWait)])
records.require_order(records.SAMPLE, [n for n in Sample._fields if n != "locks"])  # the ring's samples are made in one step


@dataclass(frozen=True)
class CallbackStats:
    """A periodic thread's running figures, as the native core keeps them (ns; counts)."""

    releases: int = 0  # releases answered: callbacks plus the releases they skipped
    overruns: int = 0
    above_bound: int = 0
    lat_mean: float = 0.0
    lat_m2: float = 0.0
    slack_mean: float = 0.0
    slack_m2: float = 0.0
    nivcsw_sum: int = 0
    nivcsw_max: int = 0
    with_nivcsw: int = 0
    minflt_sum: int = 0
    minflt_max: int = 0
    minflt_first: int = -1
    first_wake_ns: int = 0
    last_end_ns: int = 0
    nvcsw_sum: int = 0
    majflt_sum: int = 0
    missed_consecutive_max: int = 0  # the most releases missed in a row (the native core's count: those at the end too)
    latency: Optional[Histogram] = None
    slack: Optional[Histogram] = None
    wall: Optional[Histogram] = None


@dataclass(frozen=True)
class EventStats:
    """One event of a program as the native core counted it: how often it ran and what it took (ns).

    The value per event is what the event is about: the wait of a lock, a condition, a
    barrier; the wake-up latency of a timer or of a resume; the wall time of anything else.
    The extra entry after a program's last event holds its chain latency.
    """

    count: int = 0
    total: int = 0
    mean: float = 0.0
    m2: float = 0.0
    contended: int = 0  # lock: acquisitions that had to wait
    holders: tuple[tuple[int, int, int], ...] = ()  # lock: (gid of the holder, contentions, wait ns) on contention
    other_holders: int = 0
    dropped: int = 0  # spawn: spawns that found every instance taken, or that the kernel refused; resume: lost (pending: drop)
    cut: int = 0  # under way when the run ended (or the runner stopped it): not in count or figures
    histogram: Optional[Histogram] = None


@dataclass(frozen=True)
class PhaseStats:
    """One phase of a program: passes, time and rusage in it, CPUs, and its settings as the kernel reported them on entry."""

    passes: int = 0
    time_ns: int = 0
    ru: tuple[int, int, int, int] = (0, 0, 0, 0)  # nivcsw, nvcsw, minflt, majflt
    cpus_seen: tuple[int, ...] = ()
    entered: int = 0
    policy: int = 0
    priority: int = 0
    nice: int = 0
    errors: tuple[int, int, int] = (0, 0, 0)  # errno of sched, nice, cpus applied on entry
    read_back: bool = False
    deadline: tuple[int, int, int] = (0, 0, 0)  # runtime, deadline, period ns (SCHED_DEADLINE)
    affinity: tuple[int, ...] = ()


@dataclass(frozen=True)
class SlotData:
    """One thread's header and figures, as the native core left them."""

    tid: int
    state: str
    count: int  # samples written to the ring, all told
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
    stats: CallbackStats = field(default_factory=CallbackStats)
    events: tuple[EventStats, ...] = ()  # programs: per event, then the chain latency
    phases: tuple[PhaseStats, ...] = ()
    cur_phase: int = -1  # where a program stood when the slot was read
    cur_event: int = -1
    blocked_since_ns: int = 0
    timer_due_ns: int = 0  # programs: the first release of the timer it last followed that it had not served; 0: it reached none

    @property
    def finished(self) -> bool:
        return self.state == "done"

    def totals(self) -> Optional[tuple[int, int, int, int]]:
        """Thread-wide deltas over the work, when the thread got to record them."""
        if not self.finished:
            return None
        return tuple(e - s for e, s in zip(self.end_ru, self.start_ru))  # type: ignore[return-value]


def stats_of(samples: list[Sample], bound: int = 0) -> CallbackStats:
    """What the native core computes from these callbacks, computed in Python: for fakes and cross-checks."""
    if not samples:
        return CallbackStats()
    releases, above_bound, lat_mean, lat_m2, latency = _latencies(samples, bound)
    slacks = [v for v in (s.slack() for s in samples) if v is not None]
    slack_mean, slack_m2 = _welford(slacks)
    return CallbackStats(
        releases=releases,
        overruns=sum(1 for v in slacks if v < 0),
        above_bound=above_bound,
        lat_mean=lat_mean,
        lat_m2=lat_m2,
        slack_mean=slack_mean,
        slack_m2=slack_m2,
        nivcsw_sum=sum(s.nivcsw for s in samples),
        nivcsw_max=max(s.nivcsw for s in samples),
        with_nivcsw=sum(1 for s in samples if s.nivcsw),
        minflt_sum=sum(s.minflt for s in samples),
        minflt_max=max(s.minflt for s in samples),
        minflt_first=samples[0].minflt,
        first_wake_ns=samples[0].wake_ns,
        last_end_ns=samples[-1].end_ns,
        nvcsw_sum=sum(s.nvcsw for s in samples),
        majflt_sum=sum(s.majflt for s in samples),
        missed_consecutive_max=max(s.missed for s in samples),
        latency=latency,
        slack=hg.from_values(slacks),
        wall=hg.from_values(s.end_ns - s.wake_ns for s in samples),
    )


def slot_of(
    samples: list[Sample],
    *,
    tid: int = 1,
    state: str = "done",
    start_ru: tuple[int, int, int, int] = (0, 0, 0, 0),
    end_ru: tuple[int, int, int, int] = (0, 0, 0, 0),
    cpus_seen: tuple[int, ...] = (),
    work_start_ns: int = 0,
    work_end_ns: int = 0,
    bound: int = 0,
) -> SlotData:
    """The slot the native core would have left after these callbacks: for fakes of the shell and for tests."""
    return SlotData(
        tid=tid,
        state=state,
        count=len(samples),
        err_sched=0,
        err_nice=0,
        err_cpus=0,
        err_other=0,
        start_ru=start_ru,
        end_ru=end_ru,
        loops=len(samples),
        missed=sum(s.missed for s in samples),
        work_start_ns=work_start_ns,
        work_end_ns=work_end_ns,
        cpus_seen=tuple(sorted(set(cpus_seen) | {c for s in samples for c in (s.cpu_start, s.cpu_end)})),
        stats=stats_of(samples, bound),
    )


EXPANDED = 1 << 16  # latencies counted one by one up to this many; beyond, each callback's as one run


def _latencies(samples: list[Sample], bound: int) -> tuple[int, int, float, float, Optional[hg.Histogram]]:
    """The releases, those above `bound`, mean, M2 and histogram of the latencies of these callbacks: one after m missed
    releases has m + 1, its release's and those it missed, a period apart.

    Beyond EXPANDED in all (a ROS 2 timer of a program's, whose period the runner did not choose, a million releases
    behind), each callback's are one arithmetic run: its mean and M2 in closed form (merged as Chan et al. do) and its
    histogram a bucket at a time, so the memory and time do not grow with the releases it missed.
    """
    if sum(s.missed + 1 for s in samples) <= EXPANDED:
        values = [s.wake_ns - s.scheduled_ns + k * s.period_ns for s in samples for k in range(s.missed, -1, -1)]
        mean, m2 = _welford(values)
        return len(values), sum(1 for v in values if bound > 0 and v > bound), mean, m2, hg.from_values(values)
    counter = hg.Counter()
    n, above, mean, m2 = 0, 0, 0.0, 0.0
    for s in samples:
        first, step, count = s.wake_ns - s.scheduled_ns, max(0, s.period_ns), s.missed + 1
        counter.add_run(first, step, count)
        if bound > 0:
            above += count - min(count, max(0, (bound - first) // step + 1)) if step else (count if first > bound else 0)
        delta = first + step * (count - 1) / 2 - mean
        total = n + count
        mean += delta * count / total
        m2 += step * step * (count**3 - count) / 12 + delta * delta * n * count / total
        n = total
    return n, above, mean, m2, counter.histogram()


def _welford(values: list[int]) -> tuple[float, float]:
    mean = m2 = 0.0
    for n, v in enumerate(values, start=1):
        delta = v - mean
        mean += delta / n
        m2 += delta * (v - mean)
    return mean, m2


@dataclass(frozen=True)
class Layout:
    """Where things are in a buffer of `nthreads` slots with rings of `capacity` samples."""

    nthreads: int
    capacity: int
    histograms: bool = True
    events: int = 0  # event stats per slot: the longest program's events plus one (its chain latency)
    phases: int = 0  # phase stats per slot
    locks: int = 0  # lock slots after each sample: the most mutexes one program keeps apart

    # Worked out once: the ring of every slot is found a few times a tick, in cells of a thousand threads.
    @functools.cached_property
    def sample_size(self) -> int:
        return SAMPLE.size + self.locks * LOCK_WAIT.size

    @functools.cached_property
    def hist_bytes(self) -> int:
        return HIST_SETS * hg.BUCKETS * 8 if self.histograms else 0

    @property
    def event_bytes(self) -> int:
        return EV_HDR + hg.BUCKETS * 8

    @functools.cached_property
    def stride(self) -> int:
        return SLOT_HEADER + self.hist_bytes + self.capacity * self.sample_size + self.events * self.event_bytes + self.phases * PHASE_BYTES

    @property
    def size(self) -> int:
        return FILE_HEADER + self.nthreads * self.stride

    def slot(self, index: int) -> int:
        return FILE_HEADER + index * self.stride

    def ring(self, index: int) -> int:
        return self.slot(index) + SLOT_HEADER + self.hist_bytes

    def event(self, index: int, event: int) -> int:
        return self.ring(index) + self.capacity * self.sample_size + event * self.event_bytes

    def phase(self, index: int, phase: int) -> int:
        return self.event(index, self.events) + phase * PHASE_BYTES


def create(name: str, layout: Layout) -> int:
    """A zero-filled memfd for the buffer, its memory reserved now; returns the descriptor (the caller closes it).

    Reserving up front turns a machine too small for the buffer into an error before
    anything starts, instead of a SIGBUS in the middle of the run.
    """
    fd = os.memfd_create(f"runner-{name}", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, layout.size)
        try:
            os.posix_fallocate(fd, 0, layout.size)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot reserve {layout.size} bytes for the sample buffer: {exc.strerror}") from None
    except BaseException:
        os.close(fd)
        raise
    return fd


def _bits(words: tuple[int, ...]) -> tuple[int, ...]:
    """The numbers of the bits set in a CPU mask of 64-bit words, ascending (one step per bit set, not per bit)."""
    out = []
    for w, word in enumerate(words):
        while word:
            lowest = word & -word
            out.append(w * 64 + lowest.bit_length() - 1)
            word ^= lowest
    return tuple(out)


def _hist(
    buf: bytes | mmap.mmap, at: int, which: int, negated: bool = False, span: Optional[tuple[int, int]] = None
) -> list[tuple[int, int, int]]:
    """The rows of a slot's histogram `which`, read in place by the native core (`negated`: it counts negations).

    `span`: the least and greatest value it can hold (of the negations, when `negated`); the
    native core then reads only their buckets.  Only for a finished thread: its exact minimum
    and maximum were written before its counters, and it wrote nothing after.
    """
    offset = at + SLOT_HEADER + which * hg.BUCKETS * 8
    if span is None:
        return _probe.buckets(buf, offset, negated)
    if span[0] > span[1]:
        return []
    return _probe.buckets(buf, offset, negated, hg.index(span[0]), hg.index(span[1]))


def _event(buf: bytes | mmap.mmap, at: int) -> EventStats:
    f = EVENT_STATS.unpack(buf, at)
    histogram = None
    if f["count"]:
        histogram = hg.of_buckets(_probe.buckets(buf, at + EV_HDR), f["min"], f["max"])
    return EventStats(
        count=f["count"],
        total=f["sum"],
        mean=f["mean"],
        m2=f["m2"],
        contended=f["contended"],
        holders=tuple((g, c, w) for g, c, w in zip(f["holder"], f["holder_count"], f["holder_wait"]) if g >= 0 and c),
        other_holders=f["other_holders"],
        dropped=f["dropped"],
        cut=f["cut"],
        histogram=histogram,
    )


def _phase(buf: bytes | mmap.mmap, at: int) -> PhaseStats:
    f = PHASE_STATS.unpack(buf, at)
    return PhaseStats(
        passes=f["passes"],
        time_ns=f["time_ns"],
        ru=f["ru"],
        cpus_seen=_bits(f["cpus_seen"]),
        entered=f["entered"],
        policy=f["policy"],
        priority=f["priority"],
        nice=f["nice"],
        errors=(f["err_sched"], f["err_nice"], f["err_cpus"]),
        read_back=bool(f["read_back"]),
        deadline=(f["dl_runtime"], f["dl_deadline"], f["dl_period"]),
        affinity=_bits(f["affinity"]),
    )


# The running figures the slot header keeps under CallbackStats' own names (the histograms are read apart).
_STATS_IN_HEADER = tuple(f.name for f in dataclasses.fields(CallbackStats) if f.name in HEADER.fields)


def parse_slot(buf: bytes | mmap.mmap, index: int, layout: Layout) -> SlotData:
    """Decode one thread's slot from the buffer: header, running figures and histograms."""
    at = layout.slot(index)
    f = HEADER.unpack(buf, at)
    lat_min, lat_max, wall_min, wall_max = f["lat_min"], f["lat_max"], f["wall_min"], f["wall_max"]
    slack_min, slack_max = f["slack_min"], f["slack_max"]
    latency = slack = wall = None
    if layout.histograms and f["loops"]:
        done = STATES.get(f["state"]) == "done"  # a thread cut short may have counted a value before its minimum or maximum
        latency = hg.of_buckets(_hist(buf, at, 0, span=(lat_min, lat_max) if done else None), lat_min, lat_max)
        late = (max(1, -slack_max), -slack_min) if done else None  # the negations of the slack below 0
        early = (max(0, slack_min), slack_max) if done else None
        slack = hg.of_buckets(_hist(buf, at, 2, negated=True, span=late) + _hist(buf, at, 1, span=early), slack_min, slack_max)
        wall = hg.of_buckets(_hist(buf, at, 3, span=(wall_min, wall_max) if done else None), wall_min, wall_max)
    stats = CallbackStats(**{name: f[name] for name in _STATS_IN_HEADER}, latency=latency, slack=slack, wall=wall)
    return SlotData(
        tid=f["tid"],
        state=STATES.get(f["state"], "unknown"),
        count=f["count"],
        err_sched=f["err_sched"],
        err_nice=f["err_nice"],
        err_cpus=f["err_cpus"],
        err_other=f["err_other"],
        start_ru=f["start_ru"],
        end_ru=f["end_ru"],
        loops=f["loops"],
        missed=f["missed"],
        work_start_ns=f["work_start_ns"],
        work_end_ns=f["work_end_ns"],
        cpus_seen=_bits(f["cpus_seen"]),
        stats=stats,
        events=tuple(_event(buf, layout.event(index, e)) for e in range(layout.events)),
        phases=tuple(_phase(buf, layout.phase(index, k)) for k in range(layout.phases)),
        cur_phase=f["cur_phase"],
        cur_event=f["cur_event"],
        blocked_since_ns=f["blocked_since_ns"],
        timer_due_ns=f["timer_due_ns"],
    )


class Buffer:
    """The runner's view of a worker's buffer (a memfd): live counts, ring draining, the figures at the end, and the
    start gate, the one thing it writes (through a small writable mapping of the file header)."""

    def __init__(self, fd: int, layout: Layout):
        self.layout = layout
        self.map = mmap.mmap(fd, layout.size, prot=mmap.PROT_READ)
        self.header = mmap.mmap(fd, FILE_HEADER)
        self.taken = [0] * layout.nthreads  # ring position read so far, per slot
        self.lost = [0] * layout.nthreads  # samples overwritten before they could be read

    def open_gate(self, start_ns: int, end_ns: int) -> bool:
        """Release every thread of the worker at once, to start at `start_ns` and stop at `end_ns`; False if it was cancelled."""
        return _probe.open_gate(self.header, start_ns, end_ns)

    def cancel_gate(self) -> bool:
        """Send the worker's threads away without working (the cell will not start); False if the gate was open already."""
        return _probe.cancel_gate(self.header)

    def work_started(self) -> list[int]:
        """When each thread began its work (CLOCK_MONOTONIC ns; 0: not yet)."""
        return [HEADER.get(self.map, self.layout.slot(i), "work_start_ns") for i in range(self.layout.nthreads)]

    def gate_passed(self) -> list[int]:
        """When each thread passed the start gate (CLOCK_MONOTONIC ns; 0: not yet, or spawned mid-run)."""
        return [HEADER.get(self.map, self.layout.slot(i), "gate_ns") for i in range(self.layout.nthreads)]

    def loops(self) -> list[int]:
        """Callbacks (or spin slices) so far, per slot."""
        return [HEADER.get(self.map, self.layout.slot(i), "loops") for i in range(self.layout.nthreads)]

    def working(self) -> bool:
        """Whether a thread is at the gate, in its work or being spawned: one never spawned, finished or failed is not."""
        return any(HEADER.get(self.map, self.layout.slot(i), "state") in _WORKING for i in range(self.layout.nthreads))

    def written(self, index: int) -> int:
        return int(HEADER.get(self.map, self.layout.slot(index), "count"))

    def sample(self, index: int, n: int) -> Sample:
        """Sample number n of a slot's ring (the caller makes sure it has not been overwritten yet)."""
        return self._at(self.layout.ring(index) + (n % self.layout.capacity) * self.layout.sample_size)

    def _at(self, at: int) -> Sample:
        if not self.layout.locks:
            return Sample(*SAMPLE.unpack_from(self.map, at))
        at_lock = at + SAMPLE.size
        locks = tuple(LockWait(*LOCK_WAIT.unpack_from(self.map, at_lock + k * LOCK_WAIT.size)) for k in range(self.layout.locks))
        return Sample(*(SAMPLE.unpack_from(self.map, at) + (locks,)))

    def drain(self, index: int, stopped: bool = False, most: Optional[int] = None) -> list[Sample]:
        """The samples written since the last call, in order; those the writer overwrote meanwhile are counted in `lost`.

        `stopped`: the writer has exited, so no sample is being replaced while this reads.  `most`: the
        oldest that many at most, the rest left for the next call, so a runner that fell a ring behind
        holds a chunk of it at a time, not the ring (20,000 samples of 100-us callbacks, some 20 MB as rows).
        """
        cap = self.layout.capacity
        if cap == 0:
            return []
        end = self.written(index)
        # Sample n is being replaced once the writer reaches n + capacity, before it publishes that count.
        start = max(self.taken[index], end - cap + (0 if stopped else 1))
        if most is not None:
            end = min(end, start + most)
        base, size = self.layout.ring(index), self.layout.sample_size
        if self.layout.locks:
            out = [self._at(base + (n % cap) * size) for n in range(start, end)]
        else:  # the common case: the ring's one or two runs unpacked whole, no call per sample
            out = []
            n = start
            while n < end:
                run = min(end - n, cap - n % cap)  # up to the ring's end, where it wraps
                at = base + (n % cap) * size
                with memoryview(self.map) as whole, whole[at : at + run * size] as part:  # released: the map can be closed
                    out += itertools.starmap(Sample, SAMPLE.iter_unpack(part))
                n += run
        overwritten = self.written(index) - cap + (0 if stopped else 1)  # and while this read
        if overwritten > start:
            cut = min(overwritten, end)
            out = out[cut - start :]
            start = cut
        self.lost[index] += start - self.taken[index]
        self.taken[index] = end
        return out

    def slots(self) -> list[SlotData]:
        return [parse_slot(self.map, i, self.layout) for i in range(self.layout.nthreads)]

    def close(self) -> None:
        self.map.close()
        self.header.close()


NO_HOLDERS: Mapping[int, str] = MappingProxyType({})  # no thread names: a cell whose threads lock no mutex


def lock_waits(sample: Sample, mutexes: Sequence[str], holders: Mapping[int, str]) -> Optional[str]:
    """An activation's waits by mutex as the samples file's `lock_waits` cell: JSON, `{"data": {"wait_ns": 6570000,
    "taken": 1, "contended": 1, "held_by": "pi[0]/low #1"}}` (`held_by`: the holder's key when the longest
    contended wait began; null when none was seen); None when the activation locked none of them."""
    out = {
        name: {"wait_ns": w.wait_ns, "taken": w.taken, "contended": w.contended, "held_by": holders.get(w.holder)}
        for name, w in zip(mutexes, sample.locks)
        if w.taken
    }
    return json.dumps(out, separators=(",", ":")) if out else None


def rows(
    key: str, tid: int, taken: list[Sample], mutexes: Sequence[str] = (), holders: Mapping[int, str] = NO_HOLDERS
) -> list[tuple[object, ...]]:
    """Samples as rows of the samples file, in SAMPLE_COLUMNS order (latency from the oldest release answered).

    `mutexes` names the thread's lock slots, `holders` the cell's threads by gid (for `lock_waits`)."""
    return [
        (
            key,
            tid,
            s.seq,
            s.scheduled_ns,
            s.wake_ns,
            s.end_ns,
            s.release_latency(),
            s.slack(),
            s.burn_wall_ns,
            s.nivcsw,
            s.nvcsw,
            s.minflt,
            s.majflt,
            s.cpu_start,
            s.cpu_end,
            s.missed,
            s.lock_wait_ns,
            s.cond_wait_ns,
            s.barrier_wait_ns,
            s.chain_ns(),
            s.period_ns,
            lock_waits(s, mutexes, holders) if mutexes else None,
        )
        for s in taken
    ]
