"""The scheduler-trace reader without a kernel: real format files parsed, synthetic ring-buffer pages folded into exact aggregates."""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Sequence
from typing import Optional, Union

import pytest
import tracepages as tp
from tracepages import IDLE0, R_PLUS, D, R, Raw, S, X

from runner import histogram
from runner.run import _trace, guard, traceformat, tracing
from runner.run.traceformat import FormatError

A = (100, "trt-a", 120)
B = (200, "trt-b", 120)
RT = (300, "trt-rt", 19)  # SCHED_FIFO 80 as sched_switch reports it: 99 - 80
HOG = (400, "trt-hog", 120)

Events = Sequence[tuple[int, Union[bytes, Raw]]]


def traced(
    cpus: dict[int, Events],
    tids: Sequence[int] = (100, 200, 300),
    window: Optional[tuple[int, int]] = None,
    max_threads: int = 8192,
    long: bool = False,
) -> tracing.TraceData:
    """Feed each CPU's events (CPU by CPU, as a drain reads them) and fold them."""
    r = tp.reader(max_threads)
    r.track(list(tids))
    if window:
        r.window(*window)
    for cpu, events in cpus.items():
        tp.feed(r, cpu, events, long=long)
    r.stop()
    return tracing.native_result(r.result())


# ---- formats ----


def test_real_formats_parse_to_the_offsets_the_kernel_reports():
    switch = tp.FORMATS["switch"]
    assert switch is not None and switch.name == "sched_switch" and switch.id == 372
    f = switch.fields["prev_state"]
    assert (f.offset, f.size, f.signed, f.decl) == (32, 8, True, "long prev_state")
    assert switch.fields["next_comm"].is_char_array and not switch.fields["next_comm"].is_data_loc
    migrate = tp.FORMATS["migrate"]
    assert migrate is not None and migrate.fields["comm"].is_data_loc
    assert traceformat.common_type(switch) == (0, 2)


def test_header_page_gives_the_page_layout():
    h = tp.HEADER
    assert (h.timestamp_offset, h.commit_offset, h.commit_size, h.data_offset, h.data_size) == (0, 8, 8, 16, 4080)
    assert h.page_size == 4096


def test_layouts_follow_the_reader_fields_in_order():
    layouts = traceformat.layouts(tp.FORMATS, _trace.FIELDS)
    kinds = [kind for kind, _ in _trace.FIELDS]
    assert kinds == ["switch", "waking", "wakeup_new", "migrate", "fork", "exec", "exit"]
    switch = layouts[kinds.index("switch")]
    assert switch == (372, ((8, 16, traceformat.FK_CHARS), (24, 4, 1), (28, 4, 1), (32, 8, 1), (40, 16, 2), (56, 4, 1), (60, 4, 1)))
    fork = layouts[kinds.index("fork")]
    assert fork == (366, ((12, 4, 1), (16, 4, traceformat.FK_DATA_LOC), (20, 4, 1)))


def test_a_kind_the_kernel_lacks_is_none_and_a_required_one_is_an_error():
    without_new = {**tp.FORMATS, "wakeup_new": None}
    assert traceformat.layouts(without_new, _trace.FIELDS)[2] is None
    with pytest.raises(FormatError, match="no sched_waking or sched_wakeup event"):
        traceformat.layouts({**tp.FORMATS, "waking": None}, _trace.FIELDS)


def test_sched_wakeup_serves_where_sched_waking_is_absent():
    wakeup = traceformat.parse_format(tp.read("sched_wakeup.format"))
    layouts = traceformat.layouts({**tp.FORMATS, "waking": wakeup}, _trace.FIELDS)
    assert layouts[1] is not None and layouts[1][0] == wakeup.id == 374


def test_a_missing_field_names_the_event_and_its_fields():
    text = tp.read("sched_switch.format").replace("prev_state", "prev_mood")
    broken = traceformat.parse_format(text)
    with pytest.raises(FormatError, match=r"sched_switch: no field 'prev_state' \(fields: common_type, .*prev_mood"):
        traceformat.layouts({**tp.FORMATS, "switch": broken}, _trace.FIELDS)


def test_a_field_of_the_wrong_form_is_refused():
    text = tp.read("sched_switch.format").replace(
        "field:pid_t prev_pid;\toffset:24;\tsize:4;", "field:char prev_pid[4];\toffset:24;\tsize:4;"
    )
    with pytest.raises(FormatError, match=r"sched_switch.prev_pid: 'char prev_pid\[4\]'"):
        traceformat.layouts({**tp.FORMATS, "switch": traceformat.parse_format(text)}, _trace.FIELDS)


def test_not_a_format_says_what_is_missing():
    with pytest.raises(FormatError, match=r"x: not an event format \(no name, ID, fields\)"):
        traceformat.parse_format("hello", "x")
    with pytest.raises(FormatError, match="no commit, data field"):
        traceformat.parse_header_page("\tfield: u64 timestamp;\toffset:0;\tsize:8;\tsigned:0;\n")


def test_an_unusable_page_header_is_refused():
    text = tp.read("header_page").replace("size:8;\tsigned:1;", "size:2;\tsigned:1;")
    with pytest.raises(FormatError, match="unusable page header"):
        traceformat.parse_header_page(text)


def test_state_mask_from_the_print_fmt_of_this_kernel_and_of_kernels_before_4_14():
    switch = tp.FORMATS["switch"]
    assert switch is not None
    assert traceformat.switch_state_mask(switch.print_fmt) == 0xFF
    old = 'print fmt: "...", REC->prev_state & (2048-1) ? __print_flags(REC->prev_state & (2048-1), "|", { 1, "S"}) : "R"'
    assert traceformat.switch_state_mask(old) == 2047
    assert traceformat.switch_state_mask("something else") == traceformat.DEFAULT_STATE_MASK


# ---- pages -> aggregates ----


def test_a_wake_up_is_measured_from_waking_to_the_switch_in_across_cpus():
    # the waking is on CPU 1, the switch-in on CPU 0; CPU 0 is read first, as a drain may
    data = traced({0: [(2_000, tp.switch(IDLE0, A, R))], 1: [(1_500, tp.waking(A, 0))]})
    a = data.threads[100]
    assert (a.wakeups, a.latency_min, a.latency_max, a.latency_sum) == (1, 500, 500, 500)
    assert a.latency == ((histogram.index(500), 1),)
    assert a.worst == (tracing.LateWakeup(500, 2_000, 0, 0, "swapper/0", 120),)
    assert a.cpus == (0,) and a.comm == "trt-a"
    assert data.events == 2 and data.lost == 0 and data.out_of_order == 0


def test_a_name_the_kernel_cut_inside_a_character_reads_with_a_replacement_character():
    cut = "trt-" + "\u00e4" * 6  # 16 bytes of UTF-8: the kernel keeps 15, half of the last character
    woken, delayer = (100, cut, 120), (500, "x" + cut, 120)
    data = traced({0: [(1_000, tp.waking(woken, 0)), (1_500, tp.switch(delayer, woken, R))]})
    a = data.threads[100]
    assert a.comm == "trt-" + "\u00e4" * 5 + "\ufffd"
    assert a.worst == (tracing.LateWakeup(500, 1_500, 0, 500, "xtrt-" + "\u00e4" * 5, 120),)


def test_preempted_is_a_switch_out_while_runnable_and_voluntary_any_other():
    events = [
        (1_000, tp.switch(IDLE0, A, R)),
        (2_000, tp.switch(A, B, R_PLUS)),  # preempted by B
        (3_000, tp.switch(B, A, S)),  # B sleeps
        (4_000, tp.switch(A, RT, R)),  # A yields, runnable: counted as a preemption by RT
        (5_000, tp.switch(RT, A, S)),
        (6_000, tp.switch(A, B, D)),  # A blocks
        (7_000, tp.switch(B, IDLE0, X)),  # B exits
    ]
    data = traced({0: events})
    a, b = data.threads[100], data.threads[200]
    assert (a.preemptions, a.voluntary) == (2, 1)
    assert a.preemptors == (tracing.Preemptor(200, "trt-b", 120, 1), tracing.Preemptor(300, "trt-rt", 19, 1))
    assert (b.preemptions, b.voluntary, b.preemptors) == (0, 2, ())
    assert a.run_ns == (2_000 - 1_000) + (4_000 - 3_000) + (6_000 - 5_000)
    assert b.run_ns == (3_000 - 2_000) + (7_000 - 6_000)
    assert data.threads[300].run_ns == 1_000 and data.threads[300].voluntary == 1
    assert a.wakeups == 0, "a switch-in after a preemption is no wake-up"


def test_preemptors_most_frequent_first_and_at_most_32_then_other():
    events: list[tuple[int, Union[bytes, Raw]]] = []
    ts = 1_000
    # 40 distinct preemptors; preemptor 1000 + k preempts A k + 1 times for k < 3, others once
    for k in range(40):
        for _ in range(k + 1 if k < 3 else 1):
            other = (1000 + k, f"p{k}", 120)
            events += [(ts, tp.switch(other, A, S)), (ts + 10, tp.switch(A, other, R_PLUS))]
            ts += 100
    a = traced({0: events}).threads[100]
    assert a.preemptions == 43
    assert len(a.preemptors) == 32 and a.other_preemptors == 8
    assert [p.tid for p in a.preemptors[:3]] == [1002, 1001, 1000] and [p.times for p in a.preemptors[:3]] == [3, 2, 1]
    assert [p.tid for p in a.preemptors[3:]] == list(range(1003, 1032)), "ties in tid order"
    assert sum(p.times for p in a.preemptors) + a.other_preemptors == a.preemptions


def test_worst_keeps_the_64_largest_largest_first_and_the_histogram_all():
    events: list[tuple[int, Union[bytes, Raw]]] = []
    ts = 1_000_000
    latencies = [(i * 37) % 101 + 1 for i in range(101)]  # 1..101 in a scrambled order
    for lat in latencies:
        events += [(ts, tp.waking(A)), (ts + lat, tp.switch(HOG, A, R_PLUS)), (ts + 200, tp.switch(A, HOG, S))]
        ts += 1_000
    a = traced({0: events}, tids=(100,)).threads[100]
    assert a.wakeups == 101 and (a.latency_min, a.latency_max) == (1, 101) and a.latency_sum == sum(latencies)
    assert [w.latency_ns for w in a.worst] == list(range(101, 37, -1))
    assert all(w.delayer_tid == 400 and w.delayer_comm == "trt-hog" for w in a.worst)
    counts = dict(a.latency)
    assert sum(counts.values()) == 101 and all(counts[histogram.index(v)] == 1 for v in latencies)


def test_a_run_from_its_wake_up_to_its_sleep_keeps_its_preemptions_and_who_held_the_cpu_longest():
    events = [
        (1_000, tp.waking(A)),
        (1_100, tp.switch(IDLE0, A, R)),  # the run starts
        (2_000, tp.switch(A, HOG, R_PLUS)),  # HOG holds it 3 us
        (5_000, tp.switch(HOG, A, R_PLUS)),
        (6_000, tp.switch(A, B, R_PLUS)),  # B holds it 1 us
        (7_000, tp.switch(B, A, S)),
        (7_500, tp.switch(A, HOG, R_PLUS)),  # HOG again, 2 us
        (9_500, tp.switch(HOG, A, R_PLUS)),
        (10_000, tp.switch(A, HOG, S)),  # the run ends: A sleeps
        (20_000, tp.waking(A)),
        (20_100, tp.switch(HOG, A, R_PLUS)),  # a run with no preemption is not kept
        (21_000, tp.switch(A, HOG, S)),
    ]
    a = traced({0: events}).threads[100]
    assert a.runs == (tracing.PreemptedRun(1_100, 10_000, 6_000, 3, 400, "trt-hog", 120, 2, 5_000),)


def test_the_16_most_preempted_runs_most_first_and_none_whose_end_or_return_went_unseen():
    events: list[tuple[int, Union[bytes, Raw]]] = []
    ts = 1_000_000
    held = [(i * 7) % 23 + 1 for i in range(23)]  # 1..23 us, scrambled
    for h in held:
        events += [
            (ts, tp.waking(A)),
            (ts + 10, tp.switch(IDLE0, A, R)),
            (ts + 100, tp.switch(A, HOG, R_PLUS)),
            (ts + 100 + h * 1_000, tp.switch(HOG, A, R_PLUS)),
            (ts + 200 + h * 1_000, tp.switch(A, IDLE0, S)),
        ]
        ts += 100_000
    # A run cut by a new wake-up (its sleep unseen) and one still preempted at the end are not kept.
    events += [(ts, tp.waking(A)), (ts + 10, tp.switch(IDLE0, A, R)), (ts + 100, tp.switch(A, HOG, R_PLUS))]
    events += [(ts + 90_000, tp.waking(A)), (ts + 99_000, tp.switch(HOG, A, R_PLUS))]
    a = traced({0: events}).threads[100]
    assert [r.preempted_ns for r in a.runs] == [h * 1_000 for h in range(23, 7, -1)]
    assert all((r.preemptions, r.taker_tid, r.taker_count, r.taker_ns) == (1, 400, 1, r.preempted_ns) for r in a.runs)


def test_events_lost_end_the_run_under_way_unkept():
    r = tp.reader()
    r.track([100])
    r.feed(0, tp.pages([(1_000, tp.waking(A)), (1_100, tp.switch(IDLE0, A, R)), (1_200, tp.switch(A, HOG, R_PLUS))]))
    r.feed(0, tp.page(90_000, tp.data_event(0, tp.switch(HOG, A, R_PLUS)), missed=7))
    r.feed(0, tp.page(95_000, tp.data_event(0, tp.switch(A, IDLE0, S))))
    r.stop()
    assert tracing.native_result(r.result()).threads[100].runs == (), "88.8 us preempted across a gap would be a guess"


@pytest.mark.parametrize("value", [0, 1, 255, 256, 257, 1_000, 131_071, 131_072, 123_456_789, (1 << 40) - 1, (1 << 40) + 5])
def test_the_histogram_buckets_are_those_of_runner_histogram(value):
    events = [(10, tp.waking(A)), (10 + value, tp.switch(IDLE0, A, R))]
    a = traced({0: events}).threads[100]
    assert [i for i, _ in a.latency] == [histogram.index(value)]
    assert a.latency_max == value, "a delta beyond 27 bits went through a TIME_EXTEND"


def test_a_window_counts_only_the_events_inside_it_and_cuts_run_time():
    events = [
        (1_000, tp.waking(A)),
        (1_100, tp.switch(IDLE0, A, R)),  # before the window: no wake-up counted
        (2_000, tp.switch(A, IDLE0, S)),  # inside: voluntary
        (3_000, tp.waking(A)),
        (3_300, tp.switch(IDLE0, A, R)),  # inside
        (5_000, tp.switch(A, B, R_PLUS)),  # inside
        (6_000, tp.switch(B, A, S)),
        (9_000, tp.switch(A, IDLE0, S)),  # after
    ]
    a = traced({0: events}, window=(1_500, 7_000)).threads[100]
    assert (a.wakeups, a.latency_max, a.preemptions, a.voluntary) == (1, 300, 1, 1)
    assert a.run_ns == (2_000 - 1_500) + (5_000 - 3_300) + (7_000 - 6_000)


def test_a_run_that_ends_after_the_window_is_not_kept():
    """What a thread does once its measured work is over (a worker's epilogue) is not its last callback's."""
    events = [
        (3_000, tp.waking(A)),
        (3_300, tp.switch(IDLE0, A, R)),
        (4_000, tp.switch(A, HOG, R_PLUS)),
        (5_000, tp.switch(HOG, A, R_PLUS)),
        (5_500, tp.switch(A, IDLE0, S)),  # ends inside the window: kept
        (6_000, tp.waking(A)),
        (6_100, tp.switch(IDLE0, A, R)),
        (6_500, tp.switch(A, HOG, R_PLUS)),
        (6_900, tp.switch(HOG, A, R_PLUS)),
        (9_000, tp.switch(A, IDLE0, S)),  # ends after it
    ]
    a = traced({0: events}, window=(1_500, 7_000)).threads[100]
    assert [(r.start_ns, r.end_ns) for r in a.runs] == [(3_300, 5_500)]
    assert a.preemptions == 2, "both preemptions were inside the window and count for the thread"


def test_a_window_set_after_events_outside_it_were_counted_says_so():
    r = tp.reader()
    r.track([100])
    tp.feed(r, 0, [(1_000, tp.switch(IDLE0, A, R)), (5_000, tp.switch(A, IDLE0, S))])
    r.stop()  # applied: 1_000 .. 5_000 counted under the open window
    r.window(2_000, 4_500)
    data = tracing.native_result(r.result())
    assert r.result()["window_late_ns"] == (2_000 - 1_000) + (5_000 - 4_500)
    assert data.notes == (
        "the window was set after 1.5 µs of events outside it had been counted "
        "(set its start before it begins, its end at most 10 ms after it passes)",
    )
    fresh = tp.reader()
    fresh.window(2_000, 4_500)
    assert fresh.result()["window_late_ns"] == 0


def test_the_latest_waking_counts_and_one_that_found_it_running_is_dropped():
    events = [
        (1_000, tp.switch(IDLE0, A, R)),
        (1_500, tp.waking(A)),  # A still runs (the kernel traces waking, then finds it on its run queue)
        (2_000, tp.switch(A, B, R_PLUS)),  # so it is switched out runnable: no wake-up pending
        (3_000, tp.switch(B, A, S)),  # back after a preemption: no wake-up
        (3_500, tp.switch(A, IDLE0, S)),
        (4_000, tp.waking(A)),
        (4_600, tp.switch(IDLE0, A, R)),
    ]
    a = traced({0: events}).threads[100]
    assert (a.wakeups, a.latency_max) == (1, 600)


def test_a_waking_before_the_switch_out_it_races_with_counts():
    # the wakee is still going to sleep on CPU 0 when CPU 1 traces its waking
    events0 = [(1_000, tp.switch(IDLE0, A, R)), (2_050, tp.switch(A, IDLE0, S)), (2_400, tp.switch(IDLE0, A, R))]
    a = traced({0: events0, 1: [(2_000, tp.waking(A, 0))]}).threads[100]
    assert (a.wakeups, a.latency_max) == (1, 400)


def test_a_switch_in_the_kernel_did_not_trace_drops_the_wake_up_and_is_counted():
    events = [
        (1_000, tp.switch(A, IDLE0, S)),
        (2_000, tp.waking(A)),
        # the switch from idle to A at 2_100 is not in the trace (as on CPU 1 of the development VM)
        (3_000, tp.switch(A, IDLE0, S)),
        (9_000, tp.switch(IDLE0, A, R)),  # with no waking before it: no wake-up, not one of 7 us
        (9_500, tp.switch(A, IDLE0, S)),
        (9_600, tp.waking(A)),
        (9_700, tp.switch(IDLE0, A, R)),
    ]
    data = traced({0: events})
    a = data.threads[100]
    assert (a.wakeups, a.latency_max, a.unseen_switch_ins, a.voluntary) == (1, 100, 1, 3)
    assert data.unseen_switch_ins == 1


def test_the_first_switch_out_of_a_thread_running_when_the_trace_began_is_no_unseen_switch_in():
    data = traced({0: [(1_000, tp.switch(A, IDLE0, S))]})
    assert data.threads[100].unseen_switch_ins == 0 and data.threads[100].voluntary == 1


def test_wakeup_new_starts_a_wake_up_and_a_fork_follows_the_child():
    child = (101, "trt-child", 120)
    events = [
        (1_000, tp.switch(IDLE0, A, R)),
        (1_100, tp.fork(A, child)),
        (1_200, tp.waking(child, kind="wakeup_new")),
        (1_300, tp.switch(A, child, R_PLUS)),
        (2_000, tp.exit_(child)),
        (2_100, tp.switch(child, A, X)),
    ]
    data = traced({0: events}, tids=(100,))
    c = data.threads[101]
    assert (c.wakeups, c.latency_max, c.voluntary, c.run_ns, c.exited, c.comm) == (1, 100, 1, 800, True, "trt-child")


def test_a_fork_of_an_untracked_parent_is_not_followed():
    events = [(1_000, tp.switch(IDLE0, HOG, R)), (1_100, tp.fork(HOG, (401, "x", 120))), (1_200, tp.switch(HOG, A, R_PLUS))]
    data = traced({0: events}, tids=(100,))
    assert set(data.threads) == {100}


def test_migrations_and_the_cpus_a_thread_ran_on():
    events0 = [(1_000, tp.switch(IDLE0, A, R)), (2_000, tp.switch(A, IDLE0, S))]
    events1 = [(2_500, tp.migrate(A, 0, 1)), (3_000, tp.switch((0, "swapper/1", 120), A, R)), (4_000, tp.migrate(B, 1, 0))]
    data = traced({0: events0, 1: events1})
    a = data.threads[100]
    assert (a.migrations, a.cpu_changes, a.cpus) == (1, 1, (0, 1))
    assert data.threads[200].migrations == 1


def test_time_extend_and_an_absolute_time_stamp():
    body = (
        tp.data_event(0, tp.waking(A))
        + tp.time_extend(5 << 27)  # + 5 * 2^27 ns
        + tp.data_event(7, tp.switch(IDLE0, A, R))
        + tp.time_stamp(1 << 40)  # the clock is set to 2^40
        + tp.data_event(3, tp.switch(A, IDLE0, S))
    )
    r = tp.reader()
    r.track([100])
    r.feed(0, tp.page(1_000, body))
    r.stop()
    a = tracing.native_result(r.result()).threads[100]
    assert a.latency_max == (5 << 27) + 7
    assert a.worst[0].at_ns == 1_000 + (5 << 27) + 7
    assert a.run_ns == (1 << 40) + 3 - (1_000 + (5 << 27) + 7)


def test_padding_is_skipped_without_its_delta_and_ends_the_page_when_its_delta_is_0():
    body = (
        tp.data_event(0, tp.waking(A))
        + tp.padding(40, delta=999)  # a discarded event: its delta does not move the clock
        + tp.data_event(50, tp.switch(IDLE0, A, R))
        + tp.rest_of_page()
        + tp.data_event(5, tp.switch(A, B, R_PLUS))  # after the rest-of-page padding: never read
    )
    r = tp.reader()
    r.track([100, 200])
    r.feed(0, tp.page(1_000, body))
    r.stop()
    data = tracing.native_result(r.result())
    assert data.threads[100].latency_max == 50 and data.threads[100].preemptions == 0
    assert data.events == 2


def test_long_events_with_their_length_in_array0():
    events = [(1_000, tp.waking(A)), (1_250, tp.switch(IDLE0, A, R))]
    assert traced({0: events}, long=True).threads[100].latency_max == 250


def test_events_spread_over_many_pages():
    events: list[tuple[int, Union[bytes, Raw]]] = []
    ts = 1_000
    for _ in range(500):  # 1000 events of 68 and 40 bytes: about 14 pages
        events += [(ts, tp.waking(A)), (ts + 20, tp.switch(IDLE0, A, R)), (ts + 50, tp.switch(A, IDLE0, S))]
        ts += 100
    payload = tp.pages(events)
    assert len(payload) // tp.HEADER.page_size > 10
    a = traced({0: events}).threads[100]
    assert (a.wakeups, a.voluntary, a.run_ns, a.latency_max) == (500, 500, 500 * 30, 20)


def test_a_missed_events_page_counts_the_loss_and_no_latency_spans_it():
    r = tp.reader()
    r.track([100])
    r.feed(0, tp.pages([(1_000, tp.switch(A, IDLE0, S)), (1_100, tp.waking(A))]))  # the switch-in is lost
    r.feed(0, tp.page(90_000, tp.data_event(0, tp.switch(IDLE0, A, R)), missed=7))
    r.feed(0, tp.page(95_000, tp.data_event(0, tp.switch(A, IDLE0, S)), missed=3, stored=False))
    r.stop()
    result = r.result()
    data = tracing.native_result(result)
    assert data.lost == 7 and result["missed_pages"] == 2
    assert data.threads[100].wakeups == 0, "a wake-up measured across the gap would be 88.9 us of nothing"
    assert tracing.native_result(result, stats_lost=12).lost == 12, "the kernel's own count when it is larger"


def test_threads_beyond_the_table_are_counted_untracked():
    events = [(1_000, tp.switch(IDLE0, A, R)), (2_000, tp.switch(A, B, R_PLUS)), (3_000, tp.switch(B, RT, R_PLUS)), (3_100, tp.waking(RT))]
    data = traced({0: events}, tids=(100, 200, 300), max_threads=2)
    assert set(data.threads) == {100, 200}
    assert data.untracked == 2, "RT's switch-in and its waking"
    assert data.threads[200].preemptors == (tracing.Preemptor(300, "trt-rt", 19, 1),), "still named as a preemptor"


def test_an_unknown_event_id_is_parsed_and_ignored():
    fmt = tp.FORMATS["switch"]
    assert fmt is not None
    stray = bytearray(tp.switch(IDLE0, A, R))
    struct.pack_into("<H", stray, 0, 9999)
    data = traced({0: [(1_000, bytes(stray)), (2_000, tp.switch(IDLE0, B, R))]})
    assert data.events == 2 and set(data.threads) == {200}


def test_the_reader_refuses_layouts_it_cannot_read():
    layouts = list(traceformat.layouts(tp.FORMATS, _trace.FIELDS))
    layouts[0] = (372, ((8, 16, 2),))
    with pytest.raises(ValueError, match="switch: 7 fields expected, got 1"):
        _trace.Reader(4096, (0, 8, 8, 16), (0, 2), layouts, 0xFF)
    good = traceformat.layouts(tp.FORMATS, _trace.FIELDS)
    for header in [(0, 4, 8, 16), (0, 8, 3, 16), (0, 8, 8, 4096)]:  # commit over the timestamp, a 3-byte commit, no data
        with pytest.raises(ValueError, match="unusable page header"):
            _trace.Reader(4096, header, (0, 2), good, 0xFF)


def test_a_truncated_page_is_malformed_not_a_crash():
    body = tp.data_event(0, tp.waking(A)) + tp.data_event(5, tp.switch(IDLE0, A, R))
    full = tp.page(1_000, body)
    r = tp.reader()
    r.track([100])
    r.feed(0, full[: tp.HEADER.data_offset + 44])  # the commit says more than there is: one event and a piece
    r.stop()
    result = r.result()
    assert result["malformed"] >= 1 and result["events"] == 1


# ---- tracefs helpers and the guard ----


def test_tracefs_mounts_the_usual_places_first():
    mounts = "none /mnt/t tracefs rw 0 0\ntracefs /sys/kernel/debug/tracing tracefs rw 0 0\nproc /proc proc rw 0 0\n"
    mounts += "tracefs /sys/kernel/tracing tracefs rw 0 0\n"
    assert tracing.tracefs_mounts(mounts) == ["/sys/kernel/tracing", "/sys/kernel/debug/tracing", "/mnt/t"]


def test_without_tracefs_mounted_or_mountable_the_reason_is_in_words(monkeypatch):
    files = {"/proc/mounts": "proc /proc proc rw 0 0\n", "/proc/filesystems": "nodev\ttracefs\n"}
    monkeypatch.setattr(tracing, "_read_or", lambda path, default: files.get(path, default))
    monkeypatch.setattr(tracing, "_mount", lambda *a: 1)  # EPERM
    found = tracing.open_trace([1])
    assert found == tracing.TraceUnavailable("tracefs is not mounted and mounting it needs CAP_SYS_ADMIN (EPERM)")
    files["/proc/filesystems"] = "nodev\tproc\n"
    assert "this kernel has no tracefs" in tracing.find_tracefs().reason  # type: ignore[union-attr]


def test_stats_lost_sums_overrun_commit_overrun_and_dropped():
    text = "entries: 10\noverrun: 3\ncommit overrun: 1\nbytes: 100\noldest event ts: 1.0\nnow ts: 2.0\ndropped events: 5\nread events: 9\n"
    assert tracing.stats_lost(text) == 9


def _hold_folder(path: str) -> int:
    """`tracing._hold` for a folder standing in for tracefs (it has no tracing_on to hold)."""
    return os.open(path, os.O_RDONLY)


def test_an_instance_is_told_to_the_guard_before_it_exists(tmp_path, monkeypatch):
    """A runner SIGKILLed between making an instance and telling its guard once left the instance tracing."""
    (tmp_path / "instances").mkdir()
    monkeypatch.setattr(tracing, "_hold", _hold_folder)

    class Told:
        def __init__(self) -> None:
            self.watched: list[tuple[str, bool]] = []
            self.forgotten: list[str] = []

        def watch_trace(self, path: str) -> None:
            self.watched.append((path, os.path.exists(path)))

        def forget_trace(self, path: str) -> None:
            self.forgotten.append(path)

    told = Told()
    held: list[int] = []
    path = tracing._new_instance(str(tmp_path), told, held)  # type: ignore[arg-type]
    assert os.path.isdir(path) and told.watched == [(path, False)] and told.forgotten == []
    assert len(held) == 1, "held from the moment it exists"
    os.close(held[0])


def test_a_folder_that_is_not_a_tracefs_instance_is_refused_not_retried(tmp_path):
    (tmp_path / "instances").mkdir()
    with pytest.raises(FileNotFoundError):
        tracing._new_instance(str(tmp_path), None, [])
    assert os.listdir(tmp_path / "instances") == []


def test_guard_follows_trace_instances_beside_process_groups():
    lines = io.StringIO("+100\ntrace+/t/instances/runner-1-0\ntrace+/t/instances/runner-1-1\n-100\ntrace-/t/instances/runner-1-0\ntrace+\n")
    left = guard.follow(lines)
    assert left.groups == set() and left.instances == {"/t/instances/runner-1-1"}


def test_guard_removes_only_runner_instances(tmp_path):
    other = tmp_path / "instances" / "mine"
    other.mkdir(parents=True)
    assert not guard.remove_instance(str(other)) and other.exists()
    ours = tmp_path / "instances" / "runner-1-0"
    ours.mkdir()
    (ours / "tracing_on").write_text("1")
    assert not guard.remove_instance(str(ours)), "a plain folder with a file is not empty (tracefs removes its own)"
    assert (ours / "tracing_on").read_text() == "0", "tracing is turned off first"
    (ours / "tracing_on").unlink()
    assert guard.remove_instance(str(ours)) and not ours.exists()


def test_a_migrate_instance_that_cannot_be_made_is_not_left_with_the_guard(tmp_path, monkeypatch):
    """A failed mkdir of the migrate instance once left its path with the guard, to be removed by it one day."""
    (tmp_path / "instances").mkdir()
    (tmp_path / "events" / "sched" / "sched_migrate_task").mkdir(parents=True)
    monkeypatch.setattr(tracing, "find_tracefs", lambda: tracing.TracefsRoot(str(tmp_path), False))
    monkeypatch.setattr(tracing, "_hold", _hold_folder)
    made = os.mkdir

    def mkdir(path: str, *args: object) -> None:
        if str(path).endswith("-migrate"):
            raise PermissionError(1, "Operation not permitted", path)
        made(path, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "mkdir", mkdir)

    class Told:
        def __init__(self) -> None:
            self.held: set[str] = set()

        def watch_trace(self, path: str) -> None:
            self.held.add(path)

        def forget_trace(self, path: str) -> None:
            self.held.discard(path)

    told = Told()
    why = tracing.TraceInstances(guard=told)._set_up()  # type: ignore[arg-type]
    assert isinstance(why, tracing.TraceUnavailable) and "-migrate" in why.reason
    assert told.held == set(), "every path told to the guard is taken back"
    assert os.listdir(tmp_path / "instances") == [], "the first instance is removed too"


def test_the_guard_kills_before_it_waits_for_a_busy_trace_instance(monkeypatch):
    """A dead runner's program once outlived it by up to 2 s: the guard waited out a busy instance before any kill."""
    done: list[str] = []

    def remove(path: str, wait_s: float = 0.0) -> bool:
        done.append(f"remove {path} wait={wait_s}")
        return wait_s > 0  # busy until waited for

    monkeypatch.setattr(guard, "remove_instance", remove)
    monkeypatch.setattr(guard.os, "killpg", lambda pgid, sig: done.append(f"kill {pgid}"))
    monkeypatch.setattr(guard.sys, "stdin", io.StringIO("+100\ntrace+/t/instances/runner-1-0\n"))
    monkeypatch.setattr(guard.signal, "signal", lambda *args: None)  # the guard ignores Ctrl-C; this test process must not
    assert guard.main() == 0
    assert done == ["remove /t/instances/runner-1-0 wait=0.0", "kill 100", "remove /t/instances/runner-1-0 wait=2.0"]


def test_a_full_histogram_bucket_halves_them_all_and_keeps_their_proportions() -> None:
    """A thread woken every 10 us fills a bucket in half a day; it used to stop counting there, and the percentiles
    of a long run skewed towards the buckets still counting, unsaid."""
    from array import array

    from runner.run import _trace

    counts = array("I", [0] * _trace.BUCKETS)
    counts[5], counts[7], counts[9] = 2**32 - 1, 2**31, 1
    _trace.hist_add(counts, 5)
    assert (counts[5], counts[7], counts[9]) == (2**31 + 1, 2**30, 1)  # halved, rounded up: no bucket empties
    _trace.hist_add(counts, 9)
    assert counts[9] == 2 and sum(counts) == 2**31 + 1 + 2**30 + 2
