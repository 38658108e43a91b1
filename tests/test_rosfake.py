"""The ROS 2 stand-in of tests/rosfake.py: each distro's fake libtracetools has every function its header declares,
and the stand-in node runs without any preload, counts what it ran, and the fake counted every call it made.

Pure tests (SCHED_OTHER, short runs): they check the fixture the interposer's tests stand on.
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import signal
import subprocess
import time
from typing import Any

import pytest
from rosfake import DISTROS, HEADERS, SESSION_ENV, Declaration, Distro, NodeRun, RosFake, build, declarations, exported_names


@pytest.fixture(scope="session")
def ros(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
    return build(tmp_path_factory)


def _header(distro: str) -> str:
    with open(os.path.join(HEADERS, distro, "tracetools", "tracetools.h"), encoding="utf-8") as handle:
        return handle.read()


def _preprocessed_functions(distro: str) -> set[str]:
    """Every ros_trace_* function the header declares, as the C preprocessor expands it (independent of the parser)."""
    done = subprocess.run(
        ["gcc", "-E", "-I", os.path.join(HEADERS, distro), "-x", "c", "-"],
        input='#include "tracetools/tracetools.h"\n',
        capture_output=True,
        text=True,
        check=True,
    )
    return set(re.findall(r"\b(ros_trace_\w+)\s*\(", done.stdout))


def _assert_faithful(line: dict[str, Any]) -> None:
    """The fake counted exactly the calls the stand-in made, function by function."""
    assert line["calls"] == line["fake"]


@pytest.mark.parametrize("distro", DISTROS)
def test_the_generator_finds_every_declaration_block(distro: str) -> None:
    text = _header(distro)
    blocks = text.count("\nDECLARE_TRACEPOINT(") + text.count("\n_DECLARE_TRACEPOINT(")
    found = declarations(text)
    assert len(found) == blocks == {"humble": 28, "jazzy": 35, "rolling": 35}[distro]
    assert len({d.name for d in found}) == blocks
    by_name = {d.name: d for d in found}
    assert by_name["callback_start"].parameters == (("const void *", "callback"), ("const bool", "is_intra_process"))
    assert by_name["rcl_timer_init"].parameters == (("const void *", "timer_handle"), ("int64_t", "period"))
    assert by_name["rclcpp_executor_get_next_ready"].parameters == ()
    rmw_publish = [name for _, name in by_name["rmw_publish"].parameters]
    assert rmw_publish == (["message"] if distro == "humble" else ["rmw_publisher_handle", "message", "timestamp"])


def test_the_parser_reads_both_declaration_macros_past_comments_and_refuses_what_it_cannot_split() -> None:
    header = (
        "#  define DECLARE_TRACEPOINT(...) \\\n  nothing(__VA_ARGS__)\n"  # a macro's definition is no block
        "DECLARE_TRACEPOINT(\n  first, /* a comment, with a comma */\n  const void * handle,  // and (one)\n  int64_t  period)\n"
        "_DECLARE_TRACEPOINT(\n  second)\n"
    )
    assert declarations(header) == [
        Declaration("first", (("const void *", "handle"), ("int64_t", "period"))),
        Declaration("second", ()),
    ]
    assert [d.signature() for d in declarations(header)] == ["const void * handle, int64_t period", "void"]
    with pytest.raises(ValueError, match="cannot split the parameter"):
        declarations("DECLARE_TRACEPOINT(\n  third,\n  const void *)\n")


@pytest.mark.parametrize("distro", DISTROS)
def test_the_fake_defines_every_function_the_header_declares(ros: RosFake, distro: str) -> None:
    declared = _preprocessed_functions(distro)
    assert {f"ros_trace_{name}" for name in exported_names(_header(distro))} == declared
    assert ("ros_trace_enabled_callback_start" in declared) == (distro != "humble")
    lib = ctypes.CDLL(ros.distros[distro].lib)
    for function in declared:
        getattr(lib, function)  # AttributeError when the fake lacks one
    lib.fake_tracetools_size.restype = ctypes.c_size_t
    assert lib.fake_tracetools_size() == len(declared)
    lib.ros_trace_compile_status.restype = ctypes.c_bool
    assert lib.ros_trace_compile_status() is False


def _run(node: Distro, *args: str, **kwargs: Any) -> NodeRun:
    done = node.run(*args, **kwargs)
    assert done.returncode == 0, done.stderr
    return done


@pytest.mark.parametrize("distro", DISTROS)
def test_the_stand_in_runs_without_a_preload_and_the_fake_counts_every_call(ros: RosFake, distro: str) -> None:
    assert "LD_PRELOAD" not in ros.distros[distro].environ({})
    done = _run(ros.distros[distro], "--count", "5", "--period", "2ms", "--burn", "50us")
    assert len(done.lines) == 1 and done.main["pid"] > 0
    timer, sub = done.callback("timer0"), done.callback("subscription")
    assert (timer["count"], timer["started"], timer["ended"], timer["period"]) == (5, 5, 5, 2_000_000)
    assert timer["thread"] == "exec0" and timer["first_release"] > 0 and sub["count"] == 5
    assert timer["latency"]["n"] == 5 and 0 <= timer["latency"]["min"] <= timer["latency"]["mean"] <= timer["latency"]["max"]
    calls = done.main["calls"]
    assert calls["callback_start"] == calls["callback_end"] == 10
    assert sub["empty_takes"] == 1  # every fifth message, a poll that takes nothing
    assert calls["rcl_timer_init"] == 1 and calls["rmw_publish"] == calls["rcl_take"] == calls["rmw_take"] - 1 == 5
    assert calls["rcl_node_init"] == 2 and calls["rcl_publisher_init"] == 2  # /rosout and /topic
    if distro == "humble":
        assert calls["rclcpp_callback_register"] == 4  # 2 parameter services, the timer, the subscription
    else:
        assert calls["enabled_rclcpp_callback_register"] == 4 and "do_rclcpp_callback_register" not in calls
    _assert_faithful(done.main)


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_a_tracing_session_enables_the_register_tracepoint_from_iron_on(ros: RosFake, distro: str) -> None:
    calls = _run(ros.distros[distro], "--count", "1", "--period", "1ms", extra_env={SESSION_ENV: "1"}).main["calls"]
    if distro == "humble":
        assert calls["rclcpp_callback_register"] == 4 and not any(name.startswith("do_") for name in calls)
    else:
        assert calls["enabled_rclcpp_callback_register"] == calls["do_rclcpp_callback_register"] == 4


def test_the_skip_rule_counts_missed_releases(ros: RosFake) -> None:
    """A callback burning 5 ms of CPU every 2 ms: every release after the first finds the next one already past."""
    timer = _run(ros.distros["jazzy"], "--count", "3", "--period", "2ms", "--burn", "5ms", "--no-sub").callback("timer0")
    assert timer["count"] == 3 and timer["missed"] >= 2


def test_duration_bounds_the_run_instead_of_a_count(ros: RosFake) -> None:
    """Releases every 10 ms from 10 ms after the timer's creation, until 30 ms after its executor started."""
    timer = _run(ros.distros["rolling"], "--duration", "30ms", "--period", "10ms", "--burn", "0", "--no-sub").callback("timer0")
    assert 1 <= timer["count"] <= 4 and timer["count"] == timer["latency"]["n"]


def test_fork_runs_callbacks_in_the_child_and_the_parent(ros: RosFake) -> None:
    done = _run(ros.distros["jazzy"], "--fork", "--count", "3", "--period", "1ms")
    child = next(line for line in done.lines if line["role"] == "child")
    assert child["pid"] != done.main["pid"]
    assert [cb["count"] for cb in child["callbacks"]] == [3] and child["callbacks"][0]["thread"] == "exec_child"
    assert done.callback("timer0")["count"] == done.callback("subscription")["count"] == 3
    for line in done.lines:
        _assert_faithful(line)


@pytest.mark.parametrize("prog, status", [("true", 0), ("false", 1)])
def test_exec_runs_a_program_and_reports_its_status(ros: RosFake, prog: str, status: int) -> None:
    done = _run(ros.distros["humble"], "--exec", prog, "--count", "2", "--period", "1ms")
    assert done.main["exec"] == {"prog": prog, "status": status} and done.callback("timer0")["count"] == 2


def test_exec_of_a_missing_program_is_127_and_its_name_stays_json(ros: RosFake) -> None:
    done = _run(ros.distros["jazzy"], "--exec", 'no "such" \\ program', "--count", "1", "--period", "1ms", "--no-sub")
    assert done.main["exec"] == {"prog": 'no "such" \\ program', "status": 127}


def test_many_callback_objects(ros: RosFake) -> None:
    done = _run(ros.distros["rolling"], "--many", "3000", "--count", "1", "--period", "1ms", "--no-sub")
    assert done.callback("many")["objects"] == done.callback("many")["count"] == 3000
    assert done.main["calls"]["rcl_timer_init"] == 3001 and done.main["calls"]["callback_start"] == 3001
    _assert_faithful(done.main)


def test_bench_times_empty_callbacks(ros: RosFake) -> None:
    done = _run(ros.distros["jazzy"], "--bench", "20000")
    assert done.main["bench"]["pairs"] == 20000 and done.main["bench"]["ns_per_pair"] > 0
    assert done.main["calls"]["callback_start"] == done.main["calls"]["callback_end"] == 20000
    _assert_faithful(done.main)


def test_a_callback_that_never_ends_does_not_hold_the_node(ros: RosFake) -> None:
    done = _run(ros.distros["jazzy"], "--never-end", "--count", "2", "--period", "1ms", timeout=10)
    stuck = done.callback("stuck")
    assert (stuck["started"], stuck["ended"], stuck["thread"]) == (1, 0, "exec_stuck")
    assert done.main["calls"]["callback_start"] == done.main["calls"]["callback_end"] + 1
    _assert_faithful(done.main)


def test_nested_callbacks(ros: RosFake) -> None:
    done = _run(ros.distros["humble"], "--nested", "--count", "3", "--period", "1ms", "--no-sub")
    assert done.callback("nested")["count"] == done.callback("timer0")["count"] == 3
    assert done.main["calls"]["callback_start"] == 6
    _assert_faithful(done.main)


def test_intra_process_subscription(ros: RosFake) -> None:
    done = _run(ros.distros["jazzy"], "--intra", "--threads", "2", "--count", "3", "--period", "1ms")
    assert done.callback("subscription")["count"] == 6 and done.callback("timer1")["thread"] == "exec1"
    calls = done.main["calls"]
    assert calls["rclcpp_intra_publish"] == 6 and "rmw_publish" not in calls and "rmw_take" not in calls
    assert calls["rclcpp_executor_execute"] == 6  # the timers' only: an intra-process subscription is a waitable
    assert calls["rclcpp_subscription_init"] == calls["rclcpp_subscription_callback_added"] == 2
    _assert_faithful(done.main)


@pytest.mark.parametrize("distro", DISTROS)
def test_an_existing_definer_takes_the_calls_from_the_fake(ros: RosFake, distro: str) -> None:
    node = ros.distros[distro]
    line = _run(node, "--count", "2", "--period", "1ms", program=node.definer).main
    assert line["definer_calls"] == line["calls"]["callback_start"] == 4
    assert "callback_start" not in line["fake"] and line["fake"]["callback_end"] == 4


def _while_running(node: Distro) -> tuple[str, set[str], dict[str, Any]]:
    """The maps and thread names of a running stand-in, and the line it prints when SIGTERM stops it."""
    proc = subprocess.Popen([node.node, "--count", "100000", "--period", "1ms"], env=node.environ(), stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 5
        while "exec0" not in _threads(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.01)
        with open(f"/proc/{proc.pid}/maps", encoding="utf-8") as handle:
            maps = handle.read()
        threads = _threads(proc.pid)
        time.sleep(0.05)  # some callbacks, usually: the line's counts must agree whatever their number
        proc.send_signal(signal.SIGTERM)  # stops the executors: the line is printed as at a normal end
        out, _ = proc.communicate(timeout=5)
    finally:
        proc.kill()
    assert proc.returncode == 0
    return maps, threads, json.loads(out)


def test_sigterm_ends_the_node_with_its_line(ros: RosFake) -> None:
    maps, threads, line = _while_running(ros.distros["jazzy"])
    assert "/jazzy/libtracetools.so" in maps and "/jazzy/librclcpp.so" in maps
    assert {"exec0", "exec_sub", "recvUC", "dq.builtins", "tev"} <= threads
    timer = next(cb for cb in line["callbacks"] if cb["name"] == "timer0")
    assert timer["count"] < 100000 and timer["count"] == timer["started"] == timer["ended"]
    _assert_faithful(line)


def test_a_ros_built_with_tracetools_disabled_has_librclcpp_but_no_libtracetools(ros: RosFake) -> None:
    node = ros.disabled
    assert node.lib is None and not os.path.exists(os.path.join(node.libdir, "libtracetools.so"))
    maps, _, line = _while_running(node)
    assert "librclcpp.so" in maps and "libtracetools" not in maps
    assert line["calls"] == {} and "fake" not in line and line["callbacks"][0]["name"] == "timer0"


def test_a_node_built_with_tracetools_disabled_still_calls_the_libraries_tracepoints(ros: RosFake) -> None:
    """rcl's, rmw's and librclcpp's own tracepoints fire; the callbacks' (rclcpp's header templates) do not."""
    done = _run(ros.disabled_node, "--count", "3", "--period", "1ms")
    calls = done.main["calls"]
    assert calls["rclcpp_executor_execute"] == 6 and calls["rmw_take"] == 3 and calls["rcl_timer_init"] == 1
    assert not {"callback_start", "callback_end", "rclcpp_timer_callback_added", "rclcpp_publish"} & set(calls)
    assert not any("callback_register" in name for name in calls)
    assert done.callback("timer0")["count"] == 3
    _assert_faithful(done.main)


def _threads(pid: int) -> set[str]:
    names = set()
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm", encoding="utf-8") as handle:
                names.add(handle.read().strip())
        except OSError:
            pass
    return names
