"""A ROS 2 program's callbacks from hand-built interposer records (runner/run/callbacks.py): names, grid, ages, chains, words."""

from __future__ import annotations

from dataclasses import replace

import pytest
from roscbbuild import BASE, MS, REALTIME, Node, capture, shuffled

from runner.run.callbacks import ProgramCapture, cell_callbacks, matching, pretty_symbol
from runner.run.roscbdata import ClockType, Meta, MetaKind, ProcessFlag, RosCapture, RosThread

END = BASE + 1000 * MS
LAMBDA = "MinimalPublisher::MinimalPublisher()::{lambda()#1}"


def one(*processes, end: int = END, **kw):  # type: ignore[no-untyped-def]
    results, infos = cell_callbacks([ProgramCapture("prog", capture(*processes, **kw), end)], BASE)
    return results, infos["prog"]


def timer_node(first: int = BASE + 10 * MS, period: int = 10 * MS, symbol: str = LAMBDA) -> Node:
    n = Node()
    n.node(0x10, "minimal_publisher")
    n.timer(0x10, 0x20, 0x30, period, first, symbol)
    return n


def test_the_seed_callback_is_named_node_slash_symbol() -> None:
    n = timer_node()
    n.run(0x30, BASE + 10 * MS + 50_000)
    (cb,), info = one(n.process())
    assert cb.name == f"minimal_publisher/{LAMBDA}"
    assert (cb.kind, cb.node, cb.period_ns, cb.clock) == ("timer", "minimal_publisher", 10 * MS, "steady")
    assert info.seen and info.callbacks == 1 and info.instances == 1


@pytest.mark.parametrize(
    "symbol, pretty",
    [
        (LAMBDA, LAMBDA),
        (
            "std::_Bind<void (MinimalSubscriber::*(MinimalSubscriber*, std::_Placeholder<1>))(std::shared_ptr<const String>)>",
            "void (MinimalSubscriber::?)(std::shared_ptr<const String>)",
        ),
        (
            "void (*)(std::unique_ptr<Msg, std::default_delete<Msg> >, std::allocator<void>)",
            "void (*)(std::unique_ptr<Msg>)",
        ),
        ("", ""),
    ],
)
def test_symbols_are_prettified_as_tracetools_analysis_does(symbol: str, pretty: str) -> None:
    assert pretty_symbol(symbol) == pretty


def test_a_callback_without_a_symbol_is_named_by_kind_and_detail() -> None:
    n = Node()
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 500 * MS, BASE + 500 * MS, symbol="")
    n.node(0x11, "listener", "/robot")
    n.subscription(0x11, 0x40, 0x41, 0x42, 0x43, "/chatter")
    n.run(0x30, BASE + 500 * MS + 1000)
    n.run(0x43, BASE + 600 * MS, src_ts=BASE + 599 * MS + REALTIME, age_ns=MS, take_handle=0x41)
    results, _ = one(n.process())
    assert [r.name for r in results] == ["robot/listener/subscription /chatter", "talker/timer 500ms"]
    assert results[0].topic == "/chatter" and results[0].kind == "subscription"


def test_two_callbacks_of_one_name_are_numbered() -> None:
    n = Node()
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 10 * MS, BASE + 10 * MS, "f()")
    n.timer(0x10, 0x21, 0x31, 10 * MS, BASE + 10 * MS, "f()")
    n.run(0x30, BASE + 10 * MS)
    n.run(0x31, BASE + 10 * MS + 5000)
    results, _ = one(n.process())
    assert sorted(r.name for r in results) == ["talker/f()", "talker/f() #2"]


def test_init_events_out_of_order_resolve_the_same() -> None:
    n = timer_node()
    n.run(0x30, BASE + 10 * MS)
    (a,), _ = one(n.process())
    (b,), _ = one(shuffled(n.process()))
    assert (a.name, a.period_ns) == (b.name, b.period_ns)


def test_intra_process_callback_registered_before_its_subscription_exists() -> None:
    """SubscriptionIntraProcess registers its callback first; rclcpp_subscription_init comes after (notes §1.3)."""
    n = Node()
    n.node(0x10, "listener")
    n.meta(MetaKind.SUBCB, a=0x42, b=0x43)
    n.meta(MetaKind.SUB, a=0x40, b=0x10, c=0x41, d=10, s1="/chatter")
    n.meta(MetaKind.SUBOBJ, a=0x40, b=0x42)
    n.run(0x43, BASE + 10 * MS, intra=True)
    (cb,), _ = one(n.process())
    assert cb.name == "listener/subscription /chatter"
    assert any("intra-process" in note for note in cb.notes)


def test_an_address_reused_by_a_later_callback_is_another_callback() -> None:
    n = Node()
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 10 * MS, BASE + 10 * MS, "first()")
    n.run(0x30, BASE + 10 * MS)
    n.timer(0x10, 0x20, 0x30, 20 * MS, BASE + 200 * MS, "second()", clock=ClockType.STEADY)
    object.__setattr__(n.metas[-4], "t_ns", BASE + 100 * MS)  # the second timer is made mid-run, at the same addresses
    for m in n.metas[-3:]:
        object.__setattr__(m, "t_ns", BASE + 100 * MS + 1)
    n.run(0x30, BASE + 200 * MS)
    results, _ = one(n.process())
    assert sorted((r.name, r.period_ns, r.figures.callbacks) for r in results) == [
        ("talker/first()", 10 * MS, 1),
        ("talker/second()", 20 * MS, 1),
    ]


def test_a_late_timer_callback_skips_releases_and_they_are_missed() -> None:
    """rcl's skip rule: a callback 3.5 periods late serves the latest release; the three before it are missed,
    and their latency counts from the oldest one, as the runner's periodic threads count it."""
    first, period = BASE + 10 * MS, 10 * MS
    n = timer_node(first, period)
    n.run(0x30, first + 100_000)  # release 0, 0.1 ms late
    n.run(0x30, first + period + 35 * MS)  # released at release 1, starts 35 ms later: serves release 4, skipped 1..3
    n.run(0x30, first + 5 * period + 200_000)  # release 5
    (cb,), _ = one(n.process(), end=first + 6 * period)
    f = cb.figures
    assert f.callbacks == 3
    assert f.missed_releases == 3  # 1, 2, 3
    assert f.releases == 6
    assert f.missed_consecutive_max == 3
    assert f.latency_ns is not None
    assert f.latency_ns.max == 35 * MS  # release 1 to the start that served it
    assert f.latency_ns.count == 6  # every release answered, the skipped ones too
    assert cb.slowest[0].tid == 100


def test_releases_after_the_last_callback_are_not_missed_but_said() -> None:
    """No tracepoint says when a timer is cancelled (a one-shot timer cancels itself): its releases end with its callbacks."""
    first, period = BASE + 10 * MS, 10 * MS
    n = timer_node(first, period)
    n.run(0x30, first)
    (cb,), _ = one(n.process(), end=first + 10 * period)
    assert (cb.figures.callbacks, cb.figures.releases, cb.figures.missed_releases) == (1, 1, 0)
    assert any("the 9 releases after it to the end of the cell had no callback" in x for x in cb.notes)


def test_a_forked_child_runs_callbacks_its_parent_registered() -> None:
    parent = timer_node()
    parent.run(0x30, BASE + 10 * MS)
    child = Node(pid=101, tid=101)
    child.run(0x30, BASE + 20 * MS)
    forked = replace(child.process(), ppid=100, flags=frozenset({ProcessFlag.FORKED}), first_hook_ns=BASE + 15 * MS)
    results, _ = one(parent.process(), forked)
    assert sorted((r.name, tuple(r.pids)) for r in results) == [
        (f"minimal_publisher/{LAMBDA}", (100,)),
        (f"minimal_publisher/{LAMBDA} #2", (101,)),  # two callbacks of one name
    ]


def test_an_overrun_is_a_callback_past_its_next_release() -> None:
    first, period = BASE + 10 * MS, 10 * MS
    n = timer_node(first, period)
    n.run(0x30, first, wall=12 * MS)
    n.run(0x30, first + 12 * MS, wall=MS)  # serves release 1, late 2 ms
    (cb,), _ = one(n.process(), end=first + 2 * period)
    assert cb.figures.overruns == 1
    assert cb.figures.slack_ns is not None and cb.figures.slack_ns.min == -2 * MS
    assert cb.figures.latency_ns is not None and cb.figures.latency_ns.max == 2 * MS


def test_an_exact_release_from_the_record_wins_over_the_grid() -> None:
    n = timer_node(first=0)
    n.run(0x30, BASE + 10 * MS + 300_000, release_ns=BASE + 10 * MS)
    n.run(0x30, BASE + 40 * MS + 100_000, release_ns=BASE + 40 * MS)
    (cb,), _ = one(n.process(), end=BASE + 50 * MS)
    assert cb.figures.missed_releases == 2
    assert cb.figures.latency_ns is not None and cb.figures.latency_ns.min == 100_000


def test_per_callback_involuntary_switches_are_the_seed_figure() -> None:
    n = timer_node()
    for k, switches in enumerate([0, 3, 1, 0]):
        n.run(0x30, BASE + (k + 1) * 10 * MS, nivcsw=switches, minflt=2 if k == 0 else 0)
    (cb,), _ = one(n.process())
    inv = cb.figures.involuntary
    assert (inv.total, inv.per_callback_mean, inv.per_callback_max, inv.callbacks_with_any) == (4, 1.0, 3, 2)
    assert cb.figures.faults.minor_first_callback == 2 and cb.figures.faults.minor_after_first == 0


def test_a_subscription_has_message_ages_and_no_release_grid() -> None:
    n = Node()
    n.node(0x10, "listener")
    n.subscription(0x10, 0x40, 0x41, 0x42, 0x43, "/chatter", "cb(msg)")
    for k, age in enumerate([100_000, 200_000, 5 * MS]):
        n.run(0x43, BASE + (k + 1) * 10 * MS, src_ts=1, age_ns=age, take_handle=0x41)
    (cb,), _ = one(n.process())
    f = cb.figures
    assert f.latency_ns is None and f.slack_ns is None and f.missed_releases == 0 and f.overruns is None
    assert f.message_age_ns is not None
    assert (f.message_age_ns.min, f.message_age_ns.max, f.message_age_ns.count) == (100_000, 5 * MS, 3)
    assert f.callback_wall_ns is not None and f.callbacks == 3


def _chain(exact: bool, stamp_delay: int = 0) -> tuple[Node, Node, int]:
    talker, listener = Node(pid=100, tid=100), Node(pid=200, tid=201)
    talker.node(0x10, "talker")
    talker.timer(0x10, 0x20, 0x30, 10 * MS, BASE + 10 * MS, "Talker::tick()")
    talker.publisher(0x10, 0x50, 0x51, "/chatter")
    listener.node(0x10, "listener")  # the same addresses in another process: another node
    listener.subscription(0x10, 0x40, 0x41, 0x42, 0x43, "/chatter", "Listener::on(msg)")
    release = BASE + 10 * MS
    tick = talker.run(0x30, release + 50_000, wall=200_000)
    src = talker.publish(0x51, tick, release + 100_000, exact=exact, stamp_delay=stamp_delay)
    talker.publish(0x51, tick, release + 150_000, exact=exact)  # a second message nobody takes
    listener.run(0x43, release + 400_000, wall=100_000, src_ts=src, age_ns=300_000, take_handle=0x41)
    return talker, listener, release


@pytest.mark.parametrize("exact, delay", [(True, 0), (False, 20_000), (False, -5_000)])
def test_a_chain_across_two_processes_runs_from_the_timer_release(exact: bool, delay: int) -> None:
    talker, listener, _ = _chain(exact, delay)
    results, infos = cell_callbacks(
        [ProgramCapture("talker", capture(talker.process()), END), ProgramCapture("listener", capture(listener.process()), END)], BASE
    )
    by = {r.name: r for r in results}
    reached = by["listener/Listener::on(msg)"]
    assert reached.figures.chain_ns is not None
    assert reached.figures.chain_ns.max == 500_000  # the timer's release to the end of the listener's callback
    assert by["talker/Talker::tick()"].figures.chain_ns is None
    assert infos["talker"].publishes == 2 and infos["talker"].publishes_unmatched == 1
    assert any("1 of 2 messages it published on /chatter were taken by no callback" in n for n in infos["talker"].notes)
    assert any("approximately" in n for n in reached.notes) is (not exact)


def test_two_humble_publishes_close_together_are_taken_once_each_by_one_subscription() -> None:
    """Two timers publish on one topic microseconds apart, each message stamped just before its hook: the nearest
    publish of each take, but one subscription never takes one publish twice."""
    talker, listener = Node(pid=100, tid=100), Node(pid=200, tid=201)
    talker.node(0x10, "talker")
    talker.timer(0x10, 0x20, 0x30, 10 * MS, BASE + 10 * MS, "a()")
    talker.timer(0x10, 0x21, 0x31, 10 * MS, BASE + 10 * MS, "b()")
    talker.publisher(0x10, 0x50, 0x51, "/chatter")
    listener.node(0x10, "listener")
    listener.subscription(0x10, 0x40, 0x41, 0x42, 0x43, "/chatter", "on(msg)")
    release = BASE + 10 * MS
    a = talker.run(0x30, release + 1_000, wall=20_000, tid=101)
    b = talker.run(0x31, release + 2_000, wall=20_000, tid=102)
    src_a = talker.publish(0x51, a, release + 10_000, exact=False, stamp_delay=-3_000)
    src_b = talker.publish(0x51, b, release + 11_000, exact=False, stamp_delay=-3_000)
    for src in (src_a, src_b):
        listener.run(0x43, release + 100_000, wall=10_000, src_ts=src, age_ns=1, take_handle=0x41)
    results, infos = cell_callbacks(
        [ProgramCapture("talker", capture(talker.process()), END), ProgramCapture("listener", capture(listener.process()), END)], BASE
    )
    assert infos["talker"].publishes_unmatched == 0
    reached = next(r for r in results if r.kind == "subscription")
    assert reached.figures.chain_ns is not None and reached.figures.chain_ns.count == 2


def test_a_humble_take_too_far_from_any_publish_is_not_linked() -> None:
    talker, listener, _ = _chain(False, 2 * MS)
    results, _ = cell_callbacks(
        [ProgramCapture("talker", capture(talker.process()), END), ProgramCapture("listener", capture(listener.process()), END)], BASE
    )
    assert all(r.figures.chain_ns is None for r in results)


@pytest.mark.parametrize(
    "cap, words",
    [
        (RosCapture(loaded=False), "not loaded into it (a statically linked or 32-bit program"),
        (RosCapture(loaded=True, libraries=()), "loaded no ROS 2 library"),
        (RosCapture(loaded=True, libraries=("librclcpp.so",)), "loaded librclcpp but reached no tracing hook"),
        (RosCapture(error="bad version 9"), "could not be read: bad version 9"),
        (RosCapture(loaded=True, processes_refused=2), "2 processes of it found every process block"),
        (RosCapture(loaded=True, threads_refused=1), "1 thread of it found every thread slot"),
    ],
)
def test_an_empty_capture_says_why_in_words(cap: RosCapture, words: str) -> None:
    results, infos = cell_callbacks([ProgramCapture("prog", cap, END)], BASE)
    assert not results and not infos["prog"].seen
    assert any(words in n for n in infos["prog"].notes), infos["prog"].notes


def test_tracetools_disabled_is_recognised() -> None:
    n = Node()
    n.node(0x10, "talker")
    n.meta(MetaKind.TIMER, a=0x20, d=10 * MS, e=BASE)
    n.meta(MetaKind.TIMERNODE, a=0x20, b=0x10)
    _, info = one(n.process())
    assert any("built with TRACETOOLS_DISABLED: callbacks compiled out" in note for note in info.notes)


def test_shadowed_lost_and_dropped_are_said() -> None:
    n = timer_node()
    n.run(0x30, BASE + 10 * MS)
    threads = (RosThread(tid=100, comm="node", written=900, lost=40, lost_other=2),)
    p = n.process(threads, flags=frozenset({ProcessFlag.SHADOWED}), shadowed_by="/opt/caret/libcaret.so", strings_dropped=3)
    _, info = one(p)
    text = " | ".join(info.notes)
    assert "/opt/caret/libcaret.so defines ros_trace_callback_start ahead of the runner's library (SHADOWED)" in text
    assert "40 records were overwritten" in text and "2 records could not be written" in text
    assert "3 names, topics or symbols did not fit" in text
    assert info.lost == 42


def test_a_callback_open_at_the_end_and_unterminated_instances_are_said() -> None:
    n = timer_node()
    n.run(0x30, BASE + 10 * MS, unterminated=True)
    threads = (RosThread(tid=100, comm="node", written=1, lost=0, open_cb=0x30, open_since_ns=END - 2500 * MS),)
    (cb,), info = one(n.process(threads))
    assert any(f"callback minimal_publisher/{LAMBDA} on thread node (100) was running for 2.50 s at the end" in x for x in info.notes)
    assert any("1 instance never ended" in x for x in cb.notes)


def test_a_sim_time_timer_has_no_grid_and_says_so() -> None:
    n = Node()
    n.node(0x10, "talker")
    n.timer(0x10, 0x20, 0x30, 10 * MS, 0, "tick()", clock=ClockType.ROS)
    n.run(0x30, BASE + 10 * MS)
    (cb,), _ = one(n.process())
    assert cb.figures.latency_ns is None and cb.figures.missed_releases == 0
    assert any("ROS time with no release grid" in x for x in cb.notes)


def test_callback_globs_match_the_name_or_program_and_name() -> None:
    n = timer_node()
    n.run(0x30, BASE + 10 * MS)
    results, _ = one(n.process())
    assert matching(results, "*lambda*") == results
    assert matching(results, "prog: minimal_publisher/*") == results
    assert matching(results, "*timer_callback*") == []


def test_meta_kinds_with_handles_of_another_process_do_not_leak() -> None:
    """Handles are a process's own pointers: the same address in two processes is two objects."""
    a, b = timer_node(), Node(pid=300, tid=300)
    b.node(0x10, "other")
    b.timer(0x10, 0x20, 0x30, 20 * MS, BASE + 20 * MS, "Other::tick()")
    a.run(0x30, BASE + 10 * MS)
    b.run(0x30, BASE + 20 * MS)
    results, _ = one(a.process(), b.process())
    assert sorted(r.name for r in results) == [f"minimal_publisher/{LAMBDA}", "other/Other::tick()"]
    assert replace(Meta(kind=MetaKind.NODE, tid=1, t_ns=0), a=1).a == 1


def test_a_timer_callback_still_running_at_the_end_misses_every_release_after_it_and_overran() -> None:
    """An executor stuck in a callback is not a cancelled timer: the releases to the end count as missed, the instance overran."""
    n = timer_node()
    for k in range(10):  # releases 0..9 served, each 0.1 ms long
        n.run(0x30, BASE + 10 * MS + k * 10 * MS)
    stuck = BASE + 10 * MS + 10 * 10 * MS + MS  # release 10's callback started and never ended
    threads = (RosThread(tid=100, comm="node", written=10, lost=0, open_cb=0x30, open_since_ns=stuck),)
    (cb,), _ = one(n.process(threads))
    due = (END - (BASE + 10 * MS) + 10 * MS - 1) // (10 * MS)  # 99 releases from the first to the end
    assert cb.figures.callbacks == 10
    assert cb.figures.missed_releases == due - 10 and cb.figures.releases == due
    assert cb.figures.overruns == 1


def test_a_timer_whose_only_instance_never_ended_is_listed_and_could_not_keep_up() -> None:
    n = timer_node()
    threads = (RosThread(tid=100, comm="node", written=0, lost=0, open_cb=0x30, open_since_ns=BASE + 10 * MS + 50_000),)
    (cb,), _ = one(n.process(threads))
    assert cb.name == f"minimal_publisher/{LAMBDA}" and cb.pids == [100]
    assert cb.figures.callbacks == 0 and cb.figures.missed_releases == 99 and cb.figures.overruns == 1


def test_a_timer_with_no_callback_after_its_last_and_none_running_is_taken_as_cancelled() -> None:
    n = timer_node()
    for k in range(10):
        n.run(0x30, BASE + 10 * MS + k * 10 * MS)
    (cb,), _ = one(n.process())
    assert cb.figures.missed_releases == 0 and cb.figures.overruns == 0
    assert any("had no callback (the timer was cancelled" in x for x in cb.notes)


def test_a_timer_whose_callbacks_fell_millions_of_releases_behind_is_measured_in_bounded_memory() -> None:
    # a 1 µs timer (or a first release far behind) with one callback a second late: a million missed releases, each a
    # latency; they were a list of a million values (the whole list again for each figure), hundreds of MB for more
    import tracemalloc

    n = timer_node(period=1000)
    n.run(0x30, BASE + 10 * MS + 1000 * MS)
    n.run(0x30, BASE + 10 * MS + 1000 * MS + 1500)
    tracemalloc.start()
    try:
        (cb,), _ = one(n.process(), end=BASE + 1011 * MS)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20, peak
    assert cb.figures.missed_releases == 1_000_000 and cb.figures.releases == 1_000_002
    assert cb.figures.latency_ns is not None and cb.figures.latency_ns.max == 1000 * MS
    assert cb.histograms.latency is not None and cb.histograms.latency.count == 1_000_002


def test_a_timer_made_anew_at_the_same_address_thousands_of_times_is_resolved_in_linear_work() -> None:
    # a one-shot timer re-created in its callback (a common pattern) reuses its addresses: every lookup of a handle
    # listed the times of all its registrations again, so 100,000 of them took the runner's end of cell for hours
    reads = [0]

    class Counted(Meta):
        def __getattribute__(self, name: str) -> object:
            if name == "t_ns":
                reads[0] += 1
            return super().__getattribute__(name)

    n = Node()
    n.node(0x10, "talker")
    count = 1000
    for i in range(count):
        n.t = BASE + i * 10 * MS  # made in the callback before
        n.timer(0x10, 0x20, 0x30, 10 * MS, BASE + (i + 1) * 10 * MS, "f()")
        n.run(0x30, BASE + (i + 1) * 10 * MS + 1000)
    p = n.process()
    p = replace(p, metas=tuple(Counted(**vars(m)) for m in p.metas))
    results, _ = one(p, end=BASE + (count + 1) * 10 * MS)
    assert len(results) == count and {r.figures.callbacks for r in results} == {1}  # each timer ran once, on time
    assert {r.figures.latency_ns.max for r in results if r.figures.latency_ns} == {1000}
    assert reads[0] < 100 * count, reads[0]


def test_a_timer_of_period_0_is_said_to_be_always_ready_not_unseen() -> None:
    n = timer_node(period=0)
    n.run(0x30, BASE + 10 * MS)
    (cb,), _ = one(n.process())
    assert cb.figures.latency_ns is None and cb.notes == [
        "its timer's period is 0 (always ready: it runs at every turn of its executor): no release grid, "
        "so no latency, missed releases or slack"
    ]
