"""Draining a slot's ring of samples as the native core leaves it: order, wrap-around, overwritten samples counted.

The ring is written here as the native writer would (the sample, then the count), into a
real memfd buffer; no worker runs.
"""

from __future__ import annotations

import mmap
import os
import re
import struct
from collections.abc import Iterator

import pytest

from runner.run import samples
from runner.run.samples import SAMPLE, Sample

CAPACITY = 8


class _Writer:
    """The native side of one slot: samples into the ring, then the published count."""

    def __init__(self, layout: samples.Layout, index: int, fd: int):
        self.layout, self.index = layout, index
        self.map = mmap.mmap(fd, layout.size)
        self.written = 0

    def write(self, n: int) -> None:
        for _ in range(n):
            seq = self.written
            at = self.layout.ring(self.index) + (seq % self.layout.capacity) * self.layout.sample_size
            t = 1000 * seq  # scheduled; woken 7 ns later, done 50 ns later; 1 us period
            SAMPLE.pack_into(self.map, at, t, t + 7, t + 50, 40, seq, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1000, t + 1000)
            self.written += 1
        struct.pack_into("<Q", self.map, self.layout.slot(self.index) + samples.HEADER.fields["count"].offset, self.written)


@pytest.fixture
def ring() -> Iterator[tuple[samples.Buffer, _Writer]]:
    layout = samples.Layout(2, CAPACITY)
    fd = samples.create("ring-test", layout)
    try:
        writer = _Writer(layout, 1, fd)
        yield samples.Buffer(fd, layout), writer
    finally:
        os.close(fd)


def _seqs(taken: list[Sample]) -> list[int]:
    return [s.seq for s in taken]


def test_drain_takes_what_was_written_since_the_last_call_across_the_wrap(ring: tuple[samples.Buffer, _Writer]) -> None:
    reader, writer = ring
    writer.write(5)
    assert _seqs(reader.drain(1)) == [0, 1, 2, 3, 4]
    assert reader.drain(1) == []
    writer.write(6)  # 5..10: the ring wraps after 7
    taken = reader.drain(1)
    assert _seqs(taken) == [5, 6, 7, 8, 9, 10]
    assert all(s.scheduled_ns == 1000 * s.seq and s.release_latency() == 7 and s.slack() == 950 for s in taken)
    assert reader.lost[1] == 0 and reader.drain(0) == []


def test_samples_the_writer_overwrote_are_counted_lost_not_returned(ring: tuple[samples.Buffer, _Writer]) -> None:
    reader, writer = ring
    writer.write(3)
    assert _seqs(reader.drain(1)) == [0, 1, 2]
    writer.write(12)  # 3..14: only the last 8 are still in the ring
    assert _seqs(reader.drain(1, stopped=True)) == list(range(7, 15))
    assert reader.lost[1] == 4
    writer.write(CAPACITY)  # a live writer may be replacing the oldest of a full ring: it is not taken
    assert _seqs(reader.drain(1)) == list(range(16, 23)) and reader.lost[1] == 5


def test_a_drain_of_at_most_n_takes_the_oldest_and_leaves_the_rest(ring: tuple[samples.Buffer, _Writer]) -> None:
    """A runner that fell a ring behind holds a chunk of it at a time (workers.DRAIN_CHUNK), not 20,000 samples at once."""
    reader, writer = ring
    writer.write(7)
    assert _seqs(reader.drain(1, most=3)) == [0, 1, 2]
    assert _seqs(reader.drain(1, most=3)) == [3, 4, 5]
    writer.write(6)  # 7..12: the ring holds 5..12, and a live writer may be replacing 5 (read already)
    assert _seqs(reader.drain(1, most=3)) == [6, 7, 8] and reader.lost[1] == 0
    writer.write(10)  # 13..22: 9..14 overwritten before they were read
    assert _seqs(reader.drain(1, most=3)) == [16, 17, 18] and reader.lost[1] == 7
    assert _seqs(reader.drain(1, stopped=True, most=100)) == [19, 20, 21, 22] and reader.drain(1, most=3) == []


def test_the_buffer_can_be_unmapped_after_a_drain(ring: tuple[samples.Buffer, _Writer]) -> None:
    reader, writer = ring
    writer.write(CAPACITY + 3)
    assert len(reader.drain(1, stopped=True)) == CAPACITY
    reader.map.close()  # no view of the map outlives the drain


def test_the_slot_states_are_the_native_cores_own() -> None:
    """STATES names the numbers of records.h's `enum slot_state`, every one of them: a state added there is named here."""
    source = open(os.path.join(os.path.dirname(samples.__file__), "records.h")).read()
    enum = re.search(r"enum slot_state \{([^}]*)\}", source)
    assert enum is not None
    native = {int(n): name.removeprefix("ST_").lower() for name, n in re.findall(r"(ST_\w+) = (\d+)", enum.group(1))}
    assert native == samples.STATES


@pytest.mark.parametrize(
    ("states", "working"),
    [
        (("done", "done"), False),
        (("done", "created"), False),  # a spawn template no spawn took
        (("failed", "done"), False),
        (("done", "starting"), True),  # being spawned: its thread has not said it is ready yet
        (("ready", "done"), True),
        (("done", "running"), True),
    ],
)
def test_a_buffer_works_while_a_thread_is_at_the_gate_in_its_work_or_being_spawned(
    ring: tuple[samples.Buffer, _Writer], states: tuple[str, str], working: bool
) -> None:
    reader, writer = ring
    number = {name: n for n, name in samples.STATES.items()}
    for index, state in enumerate(states):
        struct.pack_into("<i", writer.map, writer.layout.slot(index) + samples.HEADER.fields["state"].offset, number[state])
    assert reader.working() is working
