"""The native records declared once (records.h): Python reads each field by name from the table the C code exports.

Pure: no thread is started; the one record the C code writes here is written by `Group` at setup and `adopt`.
"""

from __future__ import annotations

import mmap
import os
import re
import struct
import threading
from typing import Any

import pytest

from runner.run import _probe, records, samples
from runner.run.records import Record
from runner.run.samples import Layout
from runner.run.wiring import _EVENT_TYPES, work_tuple
from runner.scenario.model import EventKind, PeriodicWork


def test_the_native_table_names_the_five_records_of_the_buffer_and_the_interposers_six() -> None:
    table = _probe.records()
    assert set(table) == {"slot_header", "sample", "lock_wait", "event_stats", "phase_stats"} | {
        f"roscb_{name}"
        for name in ("file", "proc", "slot", "callback", "publish", "meta")  # runner/run/roscb.h
    }
    assert table["slot_header"][0] == _probe.SLOT_HEADER and table["sample"][0] == _probe.SAMPLE_SIZE
    assert table["lock_wait"][0] == _probe.LOCK_WAIT_SIZE
    assert table["event_stats"][0] == _probe.EV_HDR and table["phase_stats"][0] == _probe.PHASE_BYTES
    assert dict((name, offset) for name, offset, _, _ in table["slot_header"][1])["gate_ns"] == _probe.SLOT_GATE_AT


@pytest.mark.parametrize("name", sorted(_probe.records()))
def test_the_python_view_of_a_record_is_the_c_table(name: str) -> None:
    """Names unique, offsets increasing, each field where the one before it ends, its format as long as its C type."""
    size, fields = _probe.records()[name]
    record = records.RECORDS[name]
    assert record.size == size and record.names == tuple(f[0] for f in fields)
    assert len(set(record.names)) == len(record.names)
    end = 0
    for field, offset, nbytes, fmt in fields:
        assert offset == end, f"{name}.{field}: at {offset}, the field before it ends at {end}"
        assert struct.calcsize("<" + fmt) == nbytes, f"{name}.{field}: format {fmt!r} is not {nbytes} bytes"
        view = record.fields[field]
        assert (view.offset, view.size, view.format) == (offset, nbytes, fmt)
        end = offset + nbytes
    assert record.struct.size == end <= size  # the rest is the record's reserved tail


def _known(record: Record) -> dict[str, Any]:
    """A distinct value for every field of a record (an array's one per element), each fitting its type."""
    out: dict[str, Any] = {}
    for i, (name, f) in enumerate(record.fields.items()):
        values = [100 + 10 * i + k for k in range(f.size // struct.calcsize("<" + f.format.lstrip("0123456789")))]
        if f.format[-1] == "d":
            values = [v + 0.5 for v in values]
        if f.format[-1] == "B":  # a byte array (a name): its many elements distinct, each a byte
            values = [v % 256 for v in values]
        out[name] = tuple(values) if isinstance(f.index, slice) else values[0]
    return out


def _write(buf: bytearray, at: int, values: dict[str, Any], name: str) -> None:
    """Write values at the offsets and formats of the C table itself, not through the Record under test."""
    for field, offset, _, fmt in _probe.records()[name][1]:
        value = values[field]
        struct.pack_into("<" + fmt, buf, at + offset, *(value if isinstance(value, tuple) else (value,)))


@pytest.mark.parametrize("name", sorted(_probe.records()))
def test_a_record_built_from_known_values_reads_back_by_name(name: str) -> None:
    record = records.RECORDS[name]
    values = _known(record)
    buf = bytearray(8 + record.size)
    _write(buf, 8, values, name)
    assert record.unpack(buf, 8) == values
    assert all(record.get(buf, 8, field) == value for field, value in values.items())
    assert record.pack(values) == bytes(buf[8:])


def test_a_slot_read_by_the_runner_puts_every_field_of_the_c_records_where_it_belongs() -> None:
    """parse_slot takes each figure from the field of its name: two fields swapped in C or here would show."""
    layout = Layout(nthreads=1, capacity=0, histograms=False, events=1, phases=1)
    buf = bytearray(layout.size)
    head, event, phase = (_known(records.RECORDS[n]) for n in ("slot_header", "event_stats", "phase_stats"))
    head["state"] = 3  # done
    event["count"] = 0  # no histogram to read
    _write(buf, layout.slot(0), head, "slot_header")
    _write(buf, layout.event(0, 0), event, "event_stats")
    _write(buf, layout.phase(0, 0), phase, "phase_stats")
    slot = samples.parse_slot(bytes(buf), 0, layout)
    same = ["tid", "count", "err_sched", "err_nice", "err_cpus", "err_other", "start_ru", "end_ru", "loops", "missed"]
    same += ["work_start_ns", "work_end_ns", "cur_phase", "cur_event", "blocked_since_ns", "timer_due_ns"]
    assert {k: getattr(slot, k) for k in same} == {k: head[k] for k in same}
    assert slot.state == "done" and slot.cpus_seen == samples._bits(head["cpus_seen"])
    stats = ["releases", "overruns", "above_bound", "lat_mean", "lat_m2", "slack_mean", "slack_m2", "nivcsw_sum", "nivcsw_max"]
    stats += ["with_nivcsw", "minflt_sum", "minflt_max", "minflt_first", "first_wake_ns", "last_end_ns", "nvcsw_sum", "majflt_sum"]
    assert {k: getattr(slot.stats, k) for k in stats} == {k: head[k] for k in stats}
    (ev,) = slot.events
    assert (ev.total, ev.mean, ev.m2, ev.contended, ev.other_holders, ev.dropped, ev.cut) == tuple(
        event[k] for k in ("sum", "mean", "m2", "contended", "other_holders", "dropped", "cut")
    )
    assert ev.holders == tuple(zip(event["holder"], event["holder_count"], event["holder_wait"]))
    (ph,) = slot.phases
    assert (ph.passes, ph.time_ns, ph.ru, ph.entered, ph.policy, ph.priority, ph.nice) == tuple(
        phase[k] for k in ("passes", "time_ns", "ru", "entered", "policy", "priority", "nice")
    )
    assert ph.errors == (phase["err_sched"], phase["err_nice"], phase["err_cpus"]) and ph.read_back is True
    assert ph.deadline == (phase["dl_runtime"], phase["dl_deadline"], phase["dl_period"])
    assert ph.cpus_seen == samples._bits(phase["cpus_seen"]) and ph.affinity == samples._bits(phase["affinity"])


def test_a_slot_header_the_c_code_wrote_reads_back_by_name() -> None:
    """The native Group writes a slot at setup and adopt (its tid, its state, minflt_first -1): read by name, they are these."""
    layout = Layout(nthreads=1, capacity=4)
    fd = samples.create("records-test", layout)
    try:
        buf = mmap.mmap(fd, layout.size)
        group = _probe.Group(buf, 1, 4, list(os.sched_getaffinity(0)))
        group.adopt(0, "records-test", work_tuple(PeriodicWork.parse({"period": "1ms"})))
        slot = samples.parse_slot(buf, 0, layout)
        assert (slot.tid, slot.state, slot.stats.minflt_first, slot.loops) == (threading.get_native_id(), "ready", -1, 0)
        assert samples.HEADER.get(buf, layout.slot(0), "tid") == threading.get_native_id()
        del group
        buf.close()
    finally:
        os.close(fd)


def test_the_sample_and_lock_wait_classes_follow_their_records() -> None:
    """The ring's samples are made positionally in one step, so their classes must name the C fields in C's order."""
    assert [n for n in samples.Sample._fields if n != "locks"] == list(records.SAMPLE.names)
    assert [f for f in samples.LockWait.__dataclass_fields__] == list(records.LOCK_WAIT.names)
    # and read with iter_unpack at the record's own stride: neither has a reserved tail
    assert (samples.SAMPLE.size, samples.LOCK_WAIT.size) == (records.SAMPLE.size, records.LOCK_WAIT.size)
    with pytest.raises(ImportError, match="native record sample"):
        records.require_order(records.SAMPLE, ("wake_ns", "scheduled_ns", *records.SAMPLE.names[2:]))


@pytest.mark.parametrize(
    ("fields", "problem"),
    [
        ((("a", 0, 8, "q"), ("a", 8, 8, "q")), "repeats a name"),
        ((("a", 0, 8, "q"), ("b", 4, 8, "q")), "overlaps"),
        ((("a", 0, 4, "q"),), "is 4 bytes in C"),
        ((("a", 0, 8, "q"), ("b", 8, 16, "2q")), "after its 16 bytes"),
    ],
)
def test_a_table_that_does_not_describe_a_record_is_refused(fields: tuple[tuple[str, int, int, str], ...], problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        Record("r", 16, fields)


def test_a_gap_the_compiler_left_is_skipped_not_read() -> None:
    record = Record("r", 16, (("a", 0, 4, "i"), ("b", 8, 8, "q")))
    assert record.unpack(struct.pack("<i4xq", 7, -9)) == {"a": 7, "b": -9}
    assert Record("one", 8, (("a", 0, 8, "2i"),)).unpack(struct.pack("<ii", 3, 4)) == {"a": (3, 4)}
    assert Record("one", 8, (("a", 0, 8, "q"),)).unpack(struct.pack("<q", 5)) == {"a": 5}


def test_every_event_kind_has_its_own_native_code_below_ev_count() -> None:
    """One to one: each EventKind of the scenario model maps to a distinct code of the C enum, and every code has a kind."""
    assert set(_EVENT_TYPES) == set(EventKind)
    codes = list(_EVENT_TYPES.values())
    assert all(0 < code < _probe.EV_COUNT for code in codes)
    assert len(set(codes)) == len(codes) == _probe.EV_COUNT - 1
    assert sorted(_probe.EVENT_KINDS.values()) == list(range(1, _probe.EV_COUNT))
    assert all(getattr(_probe, f"EV_{name}") == code for name, code in _probe.EVENT_KINDS.items())


def test_a_program_with_an_event_code_at_ev_count_is_refused() -> None:
    layout = Layout(nthreads=1, capacity=4, events=2, phases=1)
    buf = mmap.mmap(-1, layout.size)
    group = _probe.Group(buf, 1, 4, list(os.sched_getaffinity(0)), True, 2, 1)
    for code, ok in ((_probe.EV_COUNT - 1, True), (_probe.EV_COUNT, False), (0, False)):
        arg = 1 << 20 if code == _probe.EV_IORUN else 1000
        program = (0, 0, 1, 1 << 20, ((1, 0, 1, None),), ((code, -1, -1, 0, arg),))
        work = (_probe.WORK_PROGRAM, 0, 0, False, 0, 0, False, 0, _probe.RING_ALL, program)
        if ok:
            group.adopt(0, "records-test", work)
        else:
            with pytest.raises(ValueError, match=f"type {code}"):
                group.adopt(0, "records-test", work)
    del group
    buf.close()


def test_the_measured_loop_is_compiled_without_python() -> None:
    """interp.c and the headers it includes never see Python.h: a call into Python there fails the build."""
    folder = os.path.dirname(samples.__file__)
    for name in ("interp.c", "interp.h", "records.h", "records.c", "histogram.h"):
        with open(os.path.join(folder, name), encoding="utf-8") as handle:
            assert not re.search(r"#\s*include\s*[<\"]Python\.h", handle.read()), name
