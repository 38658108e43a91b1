"""A user's own program (command:) against the real kernel: settings through exec, thread rules, figures from outside.

The subject is tests/programs/rtprog.c, compiled here under a name of its own: a main thread,
a periodic `ctl_loop` and three idle "middleware" threads.  Settings are checked with the real
`ps` while the runner runs, and the figures are the kernel's own counters read from /proc;
the effects asserted are large (every thread FIFO 80 or none but one; hundreds of
involuntary switches per second against none), never exact timings.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
import yaml
from kernelrun import finish, needs_rt, needs_tracing, ps_table, start_runner, thread, wait_for_threads

from runner.run import kernel, memcg
from runner.run.external import Monitor, ProgramRun
from runner.run.kernel import find_pids
from runner.scenario.model import Policy, ProgramSpec

pytestmark = [pytest.mark.kernel, needs_rt]

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NAME = "rtprog-kt"  # the program's comm: the file name it is exec'd from
TWO_CPUS = pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="pins the program to CPU 1")


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> str:
    path = str(tmp_path_factory.mktemp("bin") / NAME)
    subprocess.run(["gcc", "-O2", "-pthread", "-o", path, os.path.join(REPO, "tests", "programs", "rtprog.c")], check=True)
    return path


def _scenario(tmp_path, process: dict, **extra: object) -> str:
    scenario = {"name": "prog", "duration": "1s", "processes": [{"name": "talker", **process}], **extra}
    path = tmp_path / "prog.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return str(path)


def _run(tmp_path, path: str, *args: str, out_name: str = "out"):
    out = tmp_path / out_name
    done = finish(start_runner(path, "--out", str(out), "--settle", "0", *args, cwd=str(tmp_path)), str(out))
    assert done.results is not None, done.err
    assert not find_pids(NAME), "the program outlived its cell"
    return done


def _ps_rows(pid: int) -> dict[str, tuple[str, str]]:
    """comm -> (RTPRIO, CLS) from the real ps."""
    rows = [line.split() for line in ps_table(pid).splitlines()[1:]]
    return {r[1]: (r[2], r[3]) for r in rows}


def _live_table(tmp_path, path: str) -> tuple[dict[str, tuple[str, str]], dict]:
    proc = start_runner(path, "--out", str(tmp_path / "out"), "--settle", "0", "--duration", "2s", cwd=str(tmp_path))
    try:
        pid = wait_for_threads(NAME, 5)
        time.sleep(0.2)
        table = _ps_rows(pid)
    finally:
        done = finish(proc, str(tmp_path / "out"))
    assert done.results is not None, done.err
    assert not find_pids(NAME)
    return table, done.results


def test_every_thread_the_program_creates_inherits_fifo_80_through_exec(tmp_path, program):
    table, results = _live_table(tmp_path, _scenario(tmp_path, {"command": [program], "sched": "fifo:80"}))
    assert set(table) == {NAME, "ctl_loop", "mw_exec", "mw_io", "mw_timer"}
    assert all(row == ("80", "FF") for row in table.values()), table
    threads = results["cells"][0]["threads"]
    assert {t["name"] for t in threads} == set(table)
    assert all(t["applied"]["policy"] == "fifo" and t["applied"]["priority"] == 80 and t["program"] for t in threads)
    assert results["cells"][0]["status"] == "passed"


def test_the_threads_of_a_process_the_program_starts_are_measured_and_ruled(tmp_path, program):
    """`ros2 run` starts the node as a child: only the wrapper was measured, and a rule for the node's thread said
    `no thread matched`.  The program's cgroup holds every process it starts; their threads are its threads."""
    rules = [{"match": "ctl_loop", "sched": "fifo:80"}]
    wrapper = {"command": ["sh", "-c", f"{program} --burn-us 200; true"], "threads": rules}
    done = _run(tmp_path, _scenario(tmp_path, wrapper), "--duration", "1s")
    cell = done.results["cells"][0]
    if not memcg.hierarchy(limit=False)[0]:
        pytest.skip("no cgroup the runner may make here: a program's children are not followed")
    assert cell["status"] == "passed", cell["reason"]
    prog = cell["programs"][0]
    ctl = thread(done.results, "ctl_loop")
    assert ctl["pid"] != prog["pid"] and ctl["rule"] == "ctl_loop" and ctl["applied"]["policy"] == "fifo"
    assert ctl["figures"]["voluntary"]["per_second"] > 500  # its 1 ms loop, measured in the child
    assert "which the program started" in ctl["work"] and thread(done.results, "sh")["pid"] == prog["pid"]
    assert {"ctl_loop", "mw_io"} <= {row["comm"] for row in cell["thread_table"]}


def test_a_match_rule_gives_fifo_80_to_the_named_thread_only(tmp_path, program):
    rules = [{"match": "ctl_*", "sched": "fifo:80"}]
    table, results = _live_table(tmp_path, _scenario(tmp_path, {"command": [program, "--rename"], "threads": rules}))
    assert table.pop("ctl_loop") == ("80", "FF")
    assert all(row == ("-", "TS") for row in table.values()), table
    ctl = thread(results, "ctl_loop")
    assert ctl["rule"] == "ctl_*" and ctl["applied"]["policy"] == "fifo"
    assert [h["why"] for h in ctl["history"]][:2] == ["appeared", "rule"]  # renamed 20 ms after its creation, then matched
    assert thread(results, "mw_io")["applied"]["policy"] == "other"


@TWO_CPUS
def test_fifo_keeps_the_periodic_thread_from_being_preempted_by_a_hog_where_other_does_not(tmp_path, program):
    rates = {}
    for policy in ("other", "fifo:80"):
        process = {"command": [program, "--period-us", "10000", "--burn-us", "4000"], "sched": policy, "cpus": "1"}
        path = _scenario(tmp_path, process, background={"hogs": [{"count": "cpus"}]})
        done = _run(tmp_path, path, "--duration", "1s", out_name=policy)
        rates[policy] = thread(done.results, "ctl_loop")["figures"]["involuntary"]["per_second"]
    assert rates["other"] >= 20, rates  # preempted by the hog on its CPU at every slice
    assert rates["fifo:80"] <= 2, rates


@pytest.mark.parametrize(
    ("args", "until", "status", "words"),
    [
        (["--exit-after", "0.2"], "end", "error", "exited with code 0"),
        (["--crash-after", "0.2"], "end", "error", "was killed by SIGSEGV"),
        (["--exit-after", "0.2", "--exit-code", "3"], "exit", "error", "exited with code 3"),
        (["--exit-after", "0.2"], "exit", "passed", ""),
        (["--ignore-term"], "end", "passed", ""),
    ],
)
def test_a_program_that_exits_crashes_or_ignores_sigterm_ends_its_cell_cleanly(tmp_path, program, args, until, status, words):
    path = _scenario(tmp_path, {"command": [program, *args], "until": until, "grace": "200ms"})
    started = time.monotonic()
    done = _run(tmp_path, path, "--duration", "3s")
    cell = done.results["cells"][0]
    assert cell["status"] == status, cell["reason"]
    assert words in cell["reason"]
    prog = cell["programs"][0]
    if "crash" in args[0]:
        assert "crashing now" in " ".join(prog["tail"]) and prog["exit_signal"] == "SIGSEGV"
    if until == "exit" and status == "passed":
        assert prog["exit_code"] == 0 and time.monotonic() - started < 2.5  # the cell ended with the program, not at 3 s
    if "--ignore-term" in args:
        assert prog["stopped"] == "SIGKILL" and any("SIGKILL" in w for w in cell["warnings"])


def test_a_program_that_cannot_start_is_an_error_in_words(tmp_path):
    done = _run(tmp_path, _scenario(tmp_path, {"command": ["no-such-program-xyz"]}), "--duration", "0.5s")
    cell = done.results["cells"][0]
    assert cell["status"] == "error" and "'no-such-program-xyz' is not in PATH" in cell["reason"]


def test_a_script_whose_interpreter_is_missing_is_said_so(tmp_path):
    """`could not exec x.sh: No such file or directory` named a file that exists."""
    script = tmp_path / "x.sh"
    script.write_text("#!/nonexistent/interp\necho hi\n")
    script.chmod(0o755)
    done = _run(tmp_path, _scenario(tmp_path, {"command": [str(script)]}), "--duration", "0.5s")
    reason = done.results["cells"][0]["reason"]
    assert "No such file or directory (the file exists; the interpreter its #! line names, '/nonexistent/interp', does not)" in reason


def test_output_past_its_limit_is_counted_and_dropped_and_the_program_runs_on_to_its_exit(tmp_path):
    """3,000,000 bytes through a 1 MiB output_limit: the file holds the first MiB, the results count the rest and say so."""
    command = ["sh", "-c", "yes | head -c 3000000; echo last words >&2"]
    path = _scenario(tmp_path, {"command": command, "until": "exit", "output_limit": "1MiB"})
    started = time.monotonic()
    done = _run(tmp_path, path, "--duration", "5s", "--no-report")
    assert time.monotonic() - started < 4.5, "the program was held up: the cell ran to its limit instead of its exit"
    cell = done.results["cells"][0]
    assert cell["status"] == "passed", cell["reason"]
    prog = cell["programs"][0]
    folder = tmp_path / "out" / "cells" / cell["id"]
    assert (folder / "talker.stdout").read_bytes() == b"y\n" * (1 << 19)
    assert (folder / "talker.stderr").read_bytes() == b"last words\n"
    assert (prog["output_limit"], prog["stdout_bytes"], prog["stdout_dropped"]) == (1 << 20, 3_000_000, 3_000_000 - (1 << 20))
    assert (prog["stderr_bytes"], prog["stderr_dropped"]) == (11, 0)
    assert [w for w in cell["warnings"] if "talker wrote" in w] == [
        "program talker wrote 2.9MiB to stdout; the first 1MiB are in talker.stdout, the rest (1.9MiB) was dropped (output_limit: 1MiB)"
    ]


def _watch(tmp_path, target: str, duration: str, name: str = "w", extra: tuple[str, ...] = ()):
    """`runner watch TARGET --duration D [EXTRA]` into its own folder, finished and read back."""
    out = tmp_path / name
    argv = ("watch", target, "--duration", duration, *extra, "--out", str(out), "--no-plots")
    return finish(start_runner(*argv, cwd=str(tmp_path)), str(out))


def test_watch_measures_a_running_program_and_its_table_is_what_ps_shows(tmp_path, program):
    proc = subprocess.Popen([program, "--burn-us", "200"], stdout=subprocess.DEVNULL, start_new_session=True)
    try:
        pid = wait_for_threads(NAME, 5)
        done = _watch(tmp_path, NAME, "1s", "watch")
        assert done.code == 0, done.err
        ps = _ps_rows(pid)
    finally:
        proc.kill()
        proc.wait()
    results = done.results
    assert results is not None
    cell = results["cells"][0]
    table = {row["comm"]: ("-" if not row["rtprio"] else str(row["rtprio"]), row["cls"]) for row in _table_rows(cell)}
    assert table == ps
    ctl = thread(results, "ctl_loop")
    assert ctl["figures"]["voluntary"]["per_second"] > 500  # a 1 ms loop sleeps about 1000 times a second
    assert ctl["tid"] != pid and thread(results, NAME)["tid"] == pid


@needs_tracing
def test_watch_traces_the_scheduler_as_a_run_does_and_says_so_when_told_not_to(tmp_path, program):
    """`runner watch` never traced: its report had no wake-up latency, no preemptions, and said nothing about it."""
    # on CPU 0: this VM's kernel traces no switch out of idle on CPU 1, where most of a 1 ms loop's wake-ups go unmeasured
    proc = subprocess.Popen(["taskset", "-c", "0", program, "--burn-us", "200"], stdout=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_for_threads(NAME, 5)
        done = _watch(tmp_path, NAME, "1s", "traced")
        untraced = _watch(tmp_path, NAME, "500ms", "untraced", ("--no-trace",))
    finally:
        proc.kill()
        proc.wait()
    assert done.code == 0, done.err
    cell = done.results["cells"][0]
    assert cell["trace"]["enabled"] and cell["trace"]["events"] > 0, cell["trace"]
    wakeup = thread(done.results, "ctl_loop")["figures"]["wakeup_ns"]
    assert wakeup is not None and wakeup["count"] > 500, wakeup  # a 1 ms loop wakes about 1000 times a second
    report = (tmp_path / "traced" / "report.md").read_text(encoding="utf-8")
    assert "Wake-ups traced" in report and "Scheduler trace: " in report
    assert untraced.results is not None, untraced.err
    cell = untraced.results["cells"][0]
    assert not cell["trace"]["enabled"] and "--no-trace" in cell["trace"]["reason"]
    assert "watch: scheduler trace not taken: not asked for (--no-trace)" in untraced.out
    assert "Scheduler trace: not taken (not asked for (--no-trace))" in (tmp_path / "untraced" / "report.md").read_text(encoding="utf-8")


def test_watch_of_a_real_time_process_changes_and_checks_nothing_and_a_stopped_one_is_an_error(tmp_path):
    """`runner watch` of a FIFO 30 process was an error (`policy other requested`); of a stopped one, `passed`."""
    proc = subprocess.Popen(["chrt", "-f", "30", "sleep", "30"], start_new_session=True)
    try:
        time.sleep(0.2)
        done = _watch(tmp_path, str(proc.pid), "500ms", "rt")
        assert done.code == 0 and done.results["cells"][0]["status"] == "passed", done.results["cells"][0]["reason"]
        os.kill(proc.pid, signal.SIGSTOP)
        done = _watch(tmp_path, str(proc.pid), "500ms", "stopped")
        cell = done.results["cells"][0]
        assert done.code == 4 and cell["status"] == "error" and "was stopped (SIGSTOP or a debugger)" in cell["reason"]
    finally:
        proc.kill()
        proc.wait()


def test_a_grace_longer_than_the_runners_own_is_given_in_full_before_sigkill(tmp_path, program):
    """With `grace: 8s` the watchdog fired at about 3 s: an error, `overran its deadline`, not the grace's SIGKILL."""
    path = _scenario(tmp_path, {"command": [program, "--ignore-term"], "grace": "3500ms"})
    started = time.monotonic()
    cell = _run(tmp_path, path, "--duration", "500ms").results["cells"][0]
    assert cell["status"] == "passed", cell["reason"]
    assert cell["programs"][0]["stopped"] == "SIGKILL" and any("within 3.5s of SIGTERM" in w for w in cell["warnings"])
    assert time.monotonic() - started > 3.5


def test_watch_follows_a_process_whose_main_thread_has_exited(tmp_path):
    """pthread_exit in main leaves the leader a zombie while its other threads run: watch refused such a process."""
    code = "import threading, ctypes, time; threading.Thread(target=time.sleep, args=(20,)).start(); ctypes.CDLL(None).pthread_exit(None)"
    proc = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    try:
        until = time.monotonic() + 5
        while kernel.process_state(proc.pid) != "Z" and time.monotonic() < until:
            time.sleep(0.02)
        assert kernel.process_state(proc.pid) == "Z" and kernel.process_alive(proc.pid)
        done = _watch(tmp_path, str(proc.pid), "300ms")
        assert done.code == 0, done.err
    finally:
        proc.kill()
        proc.wait()
    assert not kernel.process_alive(proc.pid)


def test_a_program_that_stops_itself_is_an_error_that_says_so(tmp_path):
    """A program that SIGSTOPped itself 0.3 s in passed its cell (it was SIGKILLed at the end, a warning)."""
    path = _scenario(tmp_path, {"command": ["sh", "-c", "sleep 0.3; kill -STOP $$; echo resumed"], "grace": "200ms"})
    cell = _run(tmp_path, path).results["cells"][0]
    assert cell["status"] == "error" and "program talker" in cell["reason"] and "was stopped (SIGSTOP or a debugger)" in cell["reason"]


def _table_rows(cell: dict) -> list[dict]:
    """The mid-run table as results.json stores it (with the class ps prints, a computed field)."""
    return [{"comm": r["comm"], "rtprio": r["rtprio"], "cls": r["cls"]} for r in cell["thread_table"]]


@TWO_CPUS
def test_the_trace_names_the_hogs_as_preemptors_of_an_other_thread_and_nothing_preempts_a_fifo_one(tmp_path, program):
    found = {}
    for policy in ("other", "fifo:80"):
        process = {"command": [program, "--period-us", "10000", "--burn-us", "4000"], "sched": policy, "cpus": "1"}
        path = _scenario(tmp_path, process, background={"hogs": [{"count": "cpus", "name": "kthog"}]})
        done = _run(tmp_path, path, "--duration", "1s", out_name=policy)
        cell = done.results["cells"][0]
        if not cell["trace"]["enabled"]:
            pytest.skip(f"no scheduler trace here: {cell['trace']['reason']}")
        assert cell["trace"]["lost"] == 0
        found[policy] = thread(done.results, "ctl_loop")
    other = found["other"]
    by_hog = sum(p["count"] for p in other["preempted_by"] if p["comm"] == "kthog")
    assert other["figures"]["preemptions"] >= 20 and by_hog >= other["figures"]["preemptions"] // 2, other["preempted_by"]
    assert all(p["cls"] == "TS" for p in other["preempted_by"] if p["comm"] == "kthog")
    fifo = found["fifo:80"]
    assert not any(p["comm"] == "kthog" for p in fifo["preempted_by"]), fifo["preempted_by"]
    assert fifo["figures"]["preemptions"] <= 2
    assert fifo["figures"]["wakeup_ns"]["p50"] < 1_000_000  # from its sched_waking to running: far below its period


class _NoGuard:
    def watch(self, pid: int) -> None:
        pass

    def forget(self, pid: int) -> None:
        pass

    def watch_cgroup(self, path: str) -> None:
        pass

    def forget_cgroup(self, path: str) -> None:
        pass


def _renamer_monitored(tmp_path, program: str, open_events=None):
    """rtprog --rename (its ctl_loop thread named 20 ms after it appears) with a FIFO 10 rule, followed 0.2 s; what it left."""
    spec = ProgramSpec.parse(
        {"name": "talker", "command": [program, "--rename"], "threads": [{"match": "ctl_*", "sched": "fifo:10"}], "grace": "100ms"}
    )
    run = ProgramRun(spec, str(tmp_path), kernel.current_settings(), kernel.online_cpus())
    run.launch(_NoGuard())
    monitor = Monitor([run]) if open_events is None else Monitor([run], open_events)
    try:
        monitor.listen()
        run.release()
        monitor.window_start = time.monotonic_ns()
        monitor.start()
        time.sleep(0.2)
    finally:
        monitor.stop()
        run.stop(_NoGuard())
    return run.raw(monitor.window_start, time.monotonic_ns())


@pytest.mark.parametrize("by_events", [True, False], ids=["events", "listing"])
def test_a_rule_is_applied_as_the_kernel_reports_the_name_or_at_the_next_listing_and_the_thread_sees_it(tmp_path, program, by_events):
    raw = _renamer_monitored(tmp_path, program, None if by_events else lambda pids: (None, "left out by the test"))
    if by_events and raw.seen_by != "events":
        pytest.skip(f"no process events here: {raw.seen_note}")
    assert (raw.seen_by, raw.seen_note) == (("events", "") if by_events else ("listing", "left out by the test"))
    ctl = next(t for t in raw.threads if t.comm == "ctl_loop")
    assert ctl.rule == 0 and ctl.applied is not None and ctl.applied.policy is Policy.FIFO
    assert ctl.rule_ns is not None and ctl.rule_ns >= ctl.named_ns >= ctl.seen_ns + 15_000_000  # renamed 20 ms after it appeared
    assert "policy changed" in (tmp_path / "talker.stdout").read_text()  # the thread itself found itself FIFO


def test_memory_max_holds_a_program_to_its_cgroup_and_the_oom_killer_ends_one_that_passes_it(tmp_path, program):
    where, why = memcg.hierarchy()
    if where is None:
        pytest.skip(f"no memory cgroup for programs here: {why}")
    scenario = {
        "name": "mem",
        "duration": "1s",
        "processes": [
            {"name": "small", "command": [program, "--alloc-mib", "16"], "memory_max": "64MiB"},
            {"name": "big", "command": [program, "--alloc-mib", "128"], "memory_max": "32MiB"},
        ],
    }
    path = tmp_path / "mem.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    done = _run(tmp_path, str(path))
    cell = done.results["cells"][0]
    programs = {p["name"]: p for p in cell["programs"]}
    small, big = programs["small"], programs["big"]
    assert small["memory_max"] == 64 << 20 and small["memory_peak"] >= 16 << 20 and small["oom_kills"] == 0  # read back from its cgroup
    assert small["stopped"] == "SIGTERM"
    assert big["exit_signal"] == "SIGKILL" and big["oom_kills"] >= 1 and big["memory_peak"] <= 32 << 20
    assert cell["status"] == "error" and "program big was killed by the OOM killer" in cell["reason"]
    assert not [name for name in os.listdir(where.folder) if name.startswith("runner-")], "a program's cgroup outlived its cell"


def test_watch_counts_from_its_start_not_what_the_process_did_before(tmp_path):
    """A process that burnt 0.6 s of CPU, then sleeps: its 0.3 s watch once said 0.5 s of CPU time and its startup's faults."""
    code = "import time, sys\nend = time.process_time() + 0.6\nwhile time.process_time() < end: pass\nprint(flush=True)\ntime.sleep(30)"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "\n"  # done burning
        done = _watch(tmp_path, str(proc.pid), "300ms")
        assert done.code == 0, done.err
    finally:
        proc.kill()
        proc.wait()
    main = next(t for t in done.results["cells"][0]["threads"] if t["tid"] == proc.pid)
    figures = main["figures"]
    assert figures["cpu_time_ns"] < 50_000_000, figures  # asleep all the watch long
    assert figures["faults"]["minor"] < 100, figures  # the interpreter's start faulted thousands of pages


def test_watch_says_the_settings_its_rules_gave_outlive_it(tmp_path):
    """runner watch --rule changes a process the user runs, and nothing puts it back: the kernel keeps it, the report says so."""
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], start_new_session=True)
    try:
        time.sleep(0.1)
        done = _watch(tmp_path, str(sleeper.pid), "300ms", extra=("--rule", "*@0"))
        assert done.code == 0, done.err
        assert os.sched_getaffinity(sleeper.pid) == {0}  # after the watch
    finally:
        sleeper.kill()
        sleeper.wait()
    warnings = done.results["cells"][0]["warnings"]
    assert any("--rule changed the settings of 1 thread; they keep them after the watch" in w for w in warnings), warnings


class _FailingEvents:
    """Process events whose socket fails at the first read, as a kernel's may (EIO, a netlink error)."""

    def read(self, timeout_s: float):
        raise OSError(5, "Input/output error")

    def close(self) -> None:
        pass


def test_when_the_kernels_process_events_fail_the_listing_takes_over_and_the_results_say_so(tmp_path, program):
    """The listener died with a traceback on stderr, the results still said `events`, and new threads waited a slow listing."""
    raw = _renamer_monitored(tmp_path, program, lambda pids: (_FailingEvents(), ""))
    assert raw.seen_by == "listing" and "process events failed (Input/output error" in raw.seen_note, raw.seen_note
    ctl = next(t for t in raw.threads if t.comm == "ctl_loop")
    assert ctl.rule == 0 and ctl.applied is not None and ctl.applied.policy is Policy.FIFO


def test_a_program_abandoned_at_its_gate_exits_0_without_exec_even_beside_a_later_one() -> None:
    """Closing a held program's gate makes it leave without exec: the child no longer holds the gate's
    write end itself, nor does a program forked after it (it held the first one's gate open too)."""
    from runner.run import _probe

    out = os.open(os.devnull, os.O_WRONLY | os.O_CLOEXEC)
    none = (None, None, None, None)
    started = [_probe.spawn_program(b"/bin/true", [b"true"], [], None, none, False, out, out) for _ in range(2)]
    first, report, gate = started[0]
    opened = {report, gate, *started[1][1:]}
    try:
        assert len(os.read(report, 12)) == 12  # its settings applied: it is at its gate
        for fd in (gate, report):
            os.close(fd)
            opened.discard(fd)
        for _ in range(200):
            pid, status = os.waitpid(first, os.WNOHANG)
            if pid:
                break
            time.sleep(0.01)
        assert pid == first and os.waitstatus_to_exitcode(status) == 0, "the abandoned program is still at its gate after 2 s"
    finally:
        for pid, _, _ in started:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
        for fd in (*opened, out):
            os.close(fd)


def test_the_watchdog_kills_every_process_it_holds_past_4096_and_refuses_a_pid_of_0() -> None:
    """It kept the first 4,096 process ids and dropped the rest unsaid: a cell of more processes left them to run on."""
    from runner.run import _probe

    with open("/proc/sys/kernel/pid_max") as handle:
        unused = int(handle.read()) + 1  # above the largest pid: no process has these
    child = subprocess.Popen(["sleep", "30"], start_new_session=True)
    watchdog = _probe.Watchdog(0)
    try:
        with pytest.raises(ValueError, match="pid 0"):
            watchdog.arm(time.monotonic_ns() + 10**12, [child.pid, 0])  # kill(-0) would be the runner's own group
        watchdog.arm(time.monotonic_ns() + 50_000_000, [*range(unused, unused + 5000), child.pid])
        assert child.wait(timeout=5) == -signal.SIGKILL and watchdog.fired
    finally:
        watchdog.close()
        child.kill()
        child.wait()


def test_a_program_that_raises_itself_to_priority_99_is_an_error_unless_allowed(tmp_path):
    """Issue 40: `chrt -f 99` in a program's command (its own doing, after the runner's exec) passed without a word."""
    path = _scenario(tmp_path, {"command": ["chrt", "-f", "99", "sleep", "5"]})
    done = _run(tmp_path, path)
    cell = done.results["cells"][0]
    assert done.code == 4 and cell["status"] == "error", (done.code, done.err)
    assert "program talker raised thread sleep (tid " in cell["reason"] and "fifo:99" in cell["reason"]
    assert "--allow-priority-99" in cell["reason"]
    main = thread(done.results, "sleep")
    assert main["applied"]["policy"] == "fifo" and main["applied"]["priority"] == 99, "the kernel's read-back, not the YAML"
    allowed = _run(tmp_path, path, "--allow-priority-99", out_name="allowed")
    cell = allowed.results["cells"][0]
    assert allowed.code == 0 and cell["status"] == "passed", allowed.err
    assert any("program talker ran thread sleep" in w and "(--allow-priority-99)" in w for w in cell["warnings"]), cell["warnings"]


def test_an_expectation_a_programs_thread_cannot_meet_is_refused_and_a_traced_one_without_the_trace_is_not_measured(tmp_path, program):
    """Issue 40: latency.max and missed_releases on a program's thread validated and vanished from the run (exit 0)."""
    bad = _scenario(
        tmp_path,
        {"command": [program]},
        expect=[
            {"thread": "talker/ctl_loop", "metric": "latency.max", "max": "1us"},
            {"thread": "talker/ctl_loop", "metric": "missed_releases", "max": 0},
        ],
    )
    refused = finish(start_runner("validate", bad, cwd=str(tmp_path)), str(tmp_path / "none"))
    assert refused.code == 2 and refused.err.count("is a thread of a command: program (measured from /proc), which has") == 2
    traced = _scenario(tmp_path, {"command": [program]}, expect=[{"thread": "talker/ctl_loop", "metric": "wakeup.p99", "max": "10ms"}])
    done = _run(tmp_path, traced, "--no-trace")
    (verdict,) = done.results["cells"][0]["expectations"]
    assert done.code == 1 and not verdict["passed"] and verdict["measured"] is None
    assert verdict["note"] == "not measured (the scheduler trace did not run: not asked for (--no-trace))"
    assert "FAIL talker/ctl_loop #1: wakeup.p99 <= 10ms: not measured (the scheduler trace" in done.out


@pytest.mark.skipif(
    shutil.which("cyclictest") is None, reason="scenarios/own_program.yaml runs cyclictest, which is not installed (rt-tests)"
)
def test_the_shipped_own_program_scenario_gives_cyclictest_fifo_80_on_cpu_0_and_passes(tmp_path):
    """README's "Measure your own program": cyclictest started by the runner as FIFO 80 on CPU 0, every thread it
    creates holding both (read back from the kernel), its threads measured from outside, its expectation met."""
    out = tmp_path / "out"
    scenario = os.path.join(REPO, "scenarios", "own_program.yaml")
    done = finish(start_runner(scenario, "--out", str(out), "--settle", "0", "--duration", "1s", cwd=str(tmp_path)), str(out))
    assert done.results is not None, done.err
    assert done.code == 0, done.out + done.err
    (cell,) = done.results["cells"]
    threads = [t for t in cell["threads"] if t["program"]]
    assert len(threads) >= 2, threads  # its main thread and its measuring thread
    assert all(t["applied"]["policy"] == "fifo" and t["applied"]["priority"] == 80 and t["applied"]["cpus"] == "0" for t in threads)
    assert cell["expectations"] and all(v["passed"] for v in cell["expectations"]), cell["expectations"]
    assert not find_pids("cyclictest"), "cyclictest outlived its cell"
