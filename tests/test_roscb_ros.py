"""The interposer end to end on the stand-in ROS 2 node of each distro (tests/rosfake.py): what it recorded against
what the node says it ran, and what the fake libtracetools counted against what the node called (forwarding).

No real-time settings: SCHED_OTHER, outside the `kernel` mark.  The node prints one JSON line: its callbacks'
counts, first release and period, its own tally of every tracepoint call, and the fake's count of each.
"""

from __future__ import annotations

import os
import subprocess
import time
from collections import Counter

import pytest
from rosfake import SESSION_ENV, Distro, RosFake, build

from runner.run import roscb
from runner.run.roscbdata import MetaKind, ProcessFlag, RosCapture

pytestmark = pytest.mark.skipif(not roscb.LIBRARY, reason="the interposer was not built (pip install -e .)")
HOOKED = {  # the functions the interposer defines, by the name the node and the fake count them under
    "rcl_init", "rcl_node_init", "rcl_publisher_init", "rcl_subscription_init", "rclcpp_subscription_init",
    "rclcpp_subscription_callback_added", "rcl_service_init", "rclcpp_service_callback_added", "rcl_timer_init",
    "rclcpp_timer_callback_added", "rclcpp_timer_link_node", "rclcpp_callback_register", "rclcpp_executor_wait_for_work",
    "rclcpp_executor_get_next_ready", "rclcpp_executor_execute", "rmw_take", "rcl_publish", "rmw_publish",
    "callback_start", "callback_end",
}  # fmt: skip


@pytest.fixture(scope="session")
def ros(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
    return build(tmp_path_factory)


def _run(distro: Distro, *args: str, program: str | None = None, env: dict[str, str] | None = None):
    capture = roscb.Capture.create("rosnode")
    try:
        done = distro.run(*args, program=program, extra_env=capture.environment(env or {}))
        return done, capture.read()
    finally:
        capture.close()


def _process(capture: RosCapture):
    assert not capture.error
    (p,) = capture.processes
    return p


@pytest.mark.parametrize("name", ["humble", "jazzy", "rolling"])
def test_every_callback_the_node_ran_is_recorded_and_every_call_forwarded(ros, name):
    done, capture = _run(ros.distros[name], "--count", "8", "--period", "5ms", "--burn", "200us")
    assert done.returncode == 0, done.stderr
    main = done.main
    p = _process(capture)
    assert ProcessFlag.TRACETOOLS in p.flags and ProcessFlag.SHADOWED not in p.flags
    assert (ProcessFlag.PUBLISH_TIMESTAMP in p.flags) is (name != "humble")
    assert all(t.lost == 0 and t.lost_other == 0 for t in p.threads)
    # forwarding: the real (fake) library counted every call the node made of the functions interposed
    calls, fake = main["calls"], main["fake"]
    assert {f: fake.get(f, 0) for f in HOOKED & set(calls)} == {f: calls[f] for f in HOOKED & set(calls)}
    # the callbacks: as many per callback object as the node ran, on the threads it ran them on
    timer_cb = {m.a: m.b for m in p.metas if m.kind is MetaKind.TIMERCB}
    sub_cb = {m.b for m in p.metas if m.kind is MetaKind.SUBCB}
    (timer,) = [m for m in p.metas if m.kind is MetaKind.TIMER]
    counts = Counter(c.cb for c in p.callbacks)
    assert counts[timer_cb[timer.a]] == done.callback("timer0")["count"] == 8
    assert sum(counts[cb] for cb in sub_cb) == done.callback("subscription")["count"]
    (timer_tid,) = {c.tid for c in p.callbacks if c.cb == timer_cb[timer.a]}  # exec0 (named from its parent: see below)
    assert timer_tid != p.pid and timer_tid in {t.tid for t in p.threads}
    symbols = {m.a: m.s1 for m in p.metas if m.kind is MetaKind.SYM}
    assert symbols[timer_cb[timer.a]] == done.callback("timer0")["symbol"]
    nodes = {m.a: m.s1 for m in p.metas if m.kind is MetaKind.NODE}
    (link,) = [m for m in p.metas if m.kind is MetaKind.TIMERNODE]
    assert nodes[link.b] == done.callback("timer0")["node"]
    # the timer's period, and its first release as the node's own grid has it (no rcl: the hook's time + period)
    assert timer.d == done.callback("timer0")["period"] == 5_000_000
    assert abs(timer.e - done.callback("timer0")["first_release"]) < 1_000_000
    # publishes: the rmw arity of the distro; on Jazzy and later the stamp is exactly the subscriber's
    subs = [c for c in p.callbacks if c.cb in sub_cb]
    assert len(p.publishes) == main["calls"]["rmw_publish"] == len(subs)
    if name == "humble":
        assert all(pub.handle_is_rcl and not pub.exact for pub in p.publishes)
    else:
        assert all(pub.exact and not pub.handle_is_rcl for pub in p.publishes)
        assert sorted(pub.src_ts for pub in p.publishes) == sorted(c.src_ts for c in subs)
    assert all(pub.enclosing_cb == timer_cb[timer.a] for pub in p.publishes)


@pytest.mark.parametrize("name", ["jazzy", "rolling"])
@pytest.mark.parametrize("session", [False, True], ids=["no-session", "ros2-trace"])
def test_the_register_do_is_forwarded_only_when_the_real_library_says_enabled(ros, name, session):
    done, capture = _run(ros.distros[name], "--count", "1", env={SESSION_ENV: "1"} if session else {})
    registers = done.main["calls"]["do_rclcpp_callback_register"]
    assert registers > 0  # the interposer said enabled: the node computed the symbol and called do_
    assert done.main["fake"].get("do_rclcpp_callback_register", 0) == (registers if session else 0)
    assert sum(m.kind is MetaKind.SYM for m in _process(capture).metas) == registers


def test_humble_registers_unconditionally_and_is_forwarded(ros):
    done, capture = _run(ros.distros["humble"], "--count", "1")
    registers = done.main["calls"]["rclcpp_callback_register"]
    assert registers > 0 and done.main["fake"]["rclcpp_callback_register"] == registers
    assert sum(m.kind is MetaKind.SYM for m in _process(capture).metas) == registers


def test_a_node_whose_executable_defines_the_function_is_flagged_shadowed(ros):
    jazzy = ros.distros["jazzy"]
    done, capture = _run(jazzy, "--count", "3", program=jazzy.definer)
    assert done.returncode == 0 and done.main["definer_calls"] > 0
    p = _process(capture)
    assert ProcessFlag.SHADOWED in p.flags and p.shadowed_by.endswith("rosnode-definer")
    assert p.callbacks == ()  # callback_start went to the definer, which does not forward: no instance is recorded


def test_a_forked_node_child_records_its_own_callbacks(ros):
    done, capture = _run(ros.distros["jazzy"], "--count", "4", "--period", "2ms", "--fork")
    assert done.returncode == 0
    child_line = next(line for line in done.lines if line["role"] != "main")
    child = next(p for p in capture.processes if ProcessFlag.FORKED in p.flags)
    assert child.pid == child_line["pid"] and len(child.callbacks) == sum(cb["count"] for cb in child_line["callbacks"])


def test_a_ros_built_with_tracetools_disabled_calls_no_hook_and_its_maps_say_so(ros):
    capture = roscb.Capture.create("rosnode")
    try:
        node = subprocess.Popen(
            [ros.disabled.node, "--duration", "400ms", "--period", "10ms"],
            env=ros.disabled.environ(capture.environment({})),
            stdout=subprocess.DEVNULL,
        )
        try:
            for _ in range(100):  # until the dynamic linker has mapped them all: ours comes first, as a preload
                capture.look([node.pid])
                if "librclcpp.so" in capture.libraries:
                    break
                time.sleep(0.01)
        finally:
            assert node.wait(timeout=20) == 0
        read = capture.read()
    finally:
        capture.close()
    assert read.processes == () and read.loaded is True
    assert "librclcpp.so" in read.libraries and not any(lib.startswith("libtracetools") for lib in read.libraries)
    assert os.path.basename(roscb.LIBRARY) in read.libraries


def test_thousands_of_callbacks_one_that_never_ends_and_one_inside_another(ros):
    done, capture = _run(ros.distros["jazzy"], "--count", "5", "--period", "2ms", "--many", "5000", "--never-end", "--nested")
    assert done.returncode == 0, done.stderr
    p = _process(capture)
    # threads by what they ran (the node names each from its parent just after creating it: its first hook may come first)
    per_thread = Counter(c.tid for c in p.callbacks)
    many_tid, many_count = per_thread.most_common(1)[0]
    assert many_count == done.callback("many")["count"] == 5000
    threads = {t.tid: t for t in p.threads}
    assert threads[many_tid].lost == 0
    main = threads[p.pid]  # 5,000 objects' init records (timer, callback, symbol, node) overflow its ring: counted, not hidden
    assert main.written > roscb.CAPACITY and main.lost == main.written - roscb.CAPACITY
    # the string arena is bounded: the symbols it had no room for are counted, their records flagged
    assert p.strings_dropped > 0 and any(m.truncated and m.s1 == "" for m in p.metas if m.kind is MetaKind.SYM)
    (stuck,) = [t for t in p.threads if t.open_cb]
    assert stuck.open_since_ns > 0 and stuck.tid != many_tid and not any(c.tid == stuck.tid for c in p.callbacks)
    inner = [c for c in p.callbacks if c.depth == 1]
    assert len(inner) == done.callback("nested")["count"] > 0 and not any(c.unterminated for c in inner)
