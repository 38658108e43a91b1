"""The libtracetools interposer (runner/run/roscb.c) at the raw level, and its shell (runner/run/roscb.py).

The subject is tests/programs/roscb_caller.c, which calls the `ros_trace_*` functions as rcl and
rclcpp do, built against a minimal counting libtracetools (tests/programs/roscb_minifake.c) in
Humble's shape (1-argument rmw_publish, no enabled_ API) and Jazzy's (3 arguments, enabled_/do_),
and with no library at all.  Every run preloads the built library with a capture file of its own;
what the file holds is decoded and checked against what the caller did, and the fake's counts say
every call was forwarded.  No real-time settings: SCHED_OTHER, outside the `kernel` mark.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import time
from collections import Counter
from dataclasses import replace

import pytest

from runner.run import _probe, roscb
from runner.run.records import RECORDS
from runner.run.roscbdata import MetaKind, ProcessFlag, RosCapture

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PROGRAMS = os.path.join(REPO, "tests", "programs")
CFLAGS = ["-O2", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter"]

pytestmark = pytest.mark.skipif(not roscb.LIBRARY, reason="the interposer was not built (pip install -e .)")


def _gcc(*args: str) -> None:
    subprocess.run(["gcc", *CFLAGS, *args], check=True, capture_output=True)


@pytest.fixture(scope="module")
def bins(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The caller against each fake (humble, jazzy), and bare (no libtracetools)."""
    root = tmp_path_factory.mktemp("roscb")
    out = {}
    for distro, define in (("humble", []), ("jazzy", ["-DPUBLISH3"])):
        folder = root / distro
        folder.mkdir()
        _gcc("-fPIC", "-shared", *define, "-o", str(folder / "libtracetools.so"), os.path.join(PROGRAMS, "roscb_minifake.c"))
        out[distro] = str(folder / "caller")
        _gcc("-pthread", *define, "-o", out[distro], os.path.join(PROGRAMS, "roscb_caller.c"),
             "-Wl,--no-as-needed", f"-L{folder}", "-ltracetools", f"-Wl,-rpath,{folder}")  # fmt: skip
    out["bare"] = str(root / "bare")
    _gcc("-pthread", "-o", out["bare"], os.path.join(PROGRAMS, "roscb_caller.c"))
    return out


def _run(argv: list[str], tmp_path, env: dict[str, str] | None = None, **bounds: int) -> tuple[subprocess.CompletedProcess, RosCapture]:
    capture = roscb.Capture.create("test", folder=str(tmp_path), **bounds)
    try:
        environ = capture.environment({"PATH": os.defpath, **(env or {})})
        done = subprocess.run(argv, env=environ, capture_output=True, text=True, timeout=60)
        return done, capture.read()
    finally:
        capture.close()


def _calls(out: str) -> dict[str, int]:
    return {w[1]: int(w[2]) for line in out.splitlines() if (w := line.split())[0] == "calls"}


def _one(capture: RosCapture):
    assert not capture.error
    assert len(capture.processes) == 1, capture.processes
    return capture.processes[0]


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_records_every_callback_with_its_handles_and_forwards_every_call(bins, tmp_path, distro):
    done, capture = _run([bins[distro], "basic", "10"], tmp_path)
    assert done.returncode == 0, done.stderr
    calls = _calls(done.stdout)
    # forwarded: the real library saw every call the program made, the register through the path its distro takes
    assert calls["callback_start"] == calls["callback_end"] == 20
    assert calls["rmw_publish"] == calls["rcl_publish"] == 11 and calls["rmw_publish_bad"] == 0
    assert calls["rmw_take"] == 20 and calls["rclcpp_executor_execute"] == 20 and calls["rcl_timer_init"] == 1
    assert calls["rclcpp_callback_register"] == (2 if distro == "humble" else 0)
    p = _one(capture)
    assert p.pid > 0 and p.exe.endswith("caller")
    assert ProcessFlag.TRACETOOLS in p.flags and ProcessFlag.SHADOWED not in p.flags
    assert (ProcessFlag.PUBLISH_TIMESTAMP in p.flags) is (distro == "jazzy")
    (thread,) = p.threads
    assert thread.comm == "caller" and thread.lost == thread.lost_other == 0 and thread.open_cb == 0
    kinds = Counter(m.kind for m in p.metas)
    assert kinds == {MetaKind.NODE: 1, MetaKind.PUB: 2, MetaKind.SUB: 1, MetaKind.SUBOBJ: 1, MetaKind.SUBCB: 1,
                     MetaKind.TIMER: 1, MetaKind.TIMERCB: 1, MetaKind.TIMERNODE: 1, MetaKind.SYM: 2}  # fmt: skip
    by_kind = {m.kind: m for m in p.metas}
    # the strings were copied before the caller overwrote them
    assert by_kind[MetaKind.NODE].s1 == "minimal_publisher" and by_kind[MetaKind.NODE].s2 == "/"
    assert {m.s1 for m in p.metas if m.kind is MetaKind.SYM} == {
        "MinimalPublisher::timer_callback()",
        "MinimalSubscriber::topic_callback(std_msgs::msg::String const&)",
    }
    assert sorted(m.s1 for m in p.metas if m.kind is MetaKind.PUB) == ["/rosout", "/topic"]
    timer = by_kind[MetaKind.TIMER]
    assert timer.d == 100_000_000 and timer.e == pytest.approx(timer.t_ns + 100_000_000, abs=5_000_000)  # no rcl: init + period
    timer_cb = by_kind[MetaKind.TIMERCB].b
    sub_cb = by_kind[MetaKind.SUBCB].b
    assert Counter(c.cb for c in p.callbacks) == {timer_cb: 10, sub_cb: 10}
    assert [c.seq for c in p.callbacks] == list(range(20))
    for c in p.callbacks:
        assert c.end_ns >= c.start_ns > 0 and not c.unterminated and c.depth == 0
    timers = [c for c in p.callbacks if c.cb == timer_cb]
    subs = [c for c in p.callbacks if c.cb == sub_cb]
    assert all(c.wake_ns and c.wake_ns <= c.start_ns for c in timers)  # wait_for_work -> get_next_ready before it
    assert all(c.src_ts > 0 and c.take_handle == by_kind[MetaKind.SUB].c and c.age_ns >= 0 for c in subs)
    # the publishes inside the timer callbacks; the /rosout one is not recorded
    assert len(p.publishes) == 10
    assert [pub.enclosing_seq for pub in p.publishes] == [c.seq for c in timers]
    if distro == "jazzy":  # the middleware's timestamp: exactly what the subscriber's take carries
        assert all(pub.exact and pub.handle == by_kind[MetaKind.PUB].c for pub in p.publishes)
        assert [pub.src_ts for pub in p.publishes] == [c.src_ts for c in subs]
    else:  # the rcl publisher of the rcl_publish before it, and the hook's own clock
        topic = next(m for m in p.metas if m.kind is MetaKind.PUB and m.s1 == "/topic")
        assert all(pub.handle_is_rcl and not pub.exact and pub.handle == topic.a for pub in p.publishes)


@pytest.mark.parametrize("session", [False, True])
def test_the_register_is_recorded_and_its_do_forwarded_only_when_the_real_library_is_enabled(bins, tmp_path, session):
    done, capture = _run([bins["jazzy"], "basic", "1"], tmp_path, {"FAKE_SESSION": "1"} if session else {})
    assert _calls(done.stdout)["do_rclcpp_callback_register"] == (2 if session else 0)
    assert sum(m.kind is MetaKind.SYM for m in _one(capture).metas) == 2


def test_without_its_file_the_library_only_forwards(bins, tmp_path):
    env = {"PATH": os.defpath, "LD_PRELOAD": roscb.LIBRARY}
    alone = subprocess.run([bins["jazzy"], "basic", "3"], env={"PATH": os.defpath}, capture_output=True, text=True)
    preloaded = subprocess.run([bins["jazzy"], "basic", "3"], env=env, capture_output=True, text=True)
    assert preloaded.returncode == alone.returncode == 0
    assert preloaded.stdout == alone.stdout and _calls(preloaded.stdout)["rmw_publish_bad"] == 0
    assert preloaded.stderr == ""


def test_a_program_without_libtracetools_is_recorded_through_the_preload_alone(bins, tmp_path):
    done, capture = _run([bins["bare"], "basic", "2"], tmp_path)
    assert done.returncode == 0 and done.stdout == "done\n"
    p = _one(capture)
    assert ProcessFlag.TRACETOOLS not in p.flags
    assert len(p.callbacks) == 4 and len(p.publishes) == 2  # 1-argument rmw_publish: nothing more is read


@pytest.mark.parametrize("argv", [["true"], ["sh", "-c", "echo out; echo err >&2; exit 3"]])
def test_a_program_that_is_not_ros_is_unchanged(tmp_path, argv):
    alone = subprocess.run(argv, env={"PATH": os.defpath}, capture_output=True, text=True)
    done, capture = _run(argv, tmp_path)
    assert (done.returncode, done.stdout, done.stderr) == (alone.returncode, alone.stdout, alone.stderr)
    assert capture.processes == () and not capture.error


def test_maps_say_the_library_is_loaded_and_which_ros_libraries_are(bins, tmp_path):
    capture = roscb.Capture.create("maps", folder=str(tmp_path))
    try:
        proc = subprocess.Popen(["sleep", "5"], env=capture.environment({"PATH": os.defpath}))
        try:
            for _ in range(200):
                capture.look([proc.pid])
                if capture.loaded:
                    break
                time.sleep(0.01)
        finally:
            proc.kill()
            proc.wait()
        assert capture.read().loaded is True
        assert os.path.basename(roscb.LIBRARY) in capture.read().libraries
    finally:
        capture.close()
    assert roscb.is_ros_library("/opt/ros/jazzy/lib/librclcpp.so") and not roscb.is_ros_library("/usr/lib/libc.so.6")


def test_nested_callbacks_and_one_whose_end_never_came(bins, tmp_path):
    done, capture = _run([bins["humble"], "nested"], tmp_path)
    assert done.returncode == 0, done.stderr
    p = _one(capture)
    first_b, first_a, second_b, second_a = p.callbacks  # written at their ends: inner first
    assert (first_b.depth, first_a.depth) == (1, 0) and first_b.cb != first_a.cb
    assert first_a.start_ns <= first_b.start_ns <= first_b.end_ns <= first_a.end_ns and not first_a.unterminated
    assert second_b.unterminated and second_b.depth == 1 and second_b.end_ns == second_a.end_ns
    assert not second_a.unterminated and second_a.cb == first_a.cb
    assert [c.seq for c in (first_a, first_b, second_a, second_b)] == [0, 1, 2, 3]  # numbered as they started
    assert p.threads[0].lost_other == 0 and p.threads[0].open_cb == 0


def test_callbacks_nested_deeper_than_the_stack_are_counted_and_the_thread_goes_on(bins, tmp_path):
    done, capture = _run([bins["humble"], "deep"], tmp_path)
    assert done.returncode == 0, done.stderr
    p = _one(capture)
    assert p.threads[0].lost_other == 12 - _probe.ROSCB_STACK
    assert [c.depth for c in p.callbacks] == [*range(_probe.ROSCB_STACK - 1, -1, -1), 0]
    assert not any(c.unterminated for c in p.callbacks)


def test_an_end_without_a_start_is_counted(bins, tmp_path):
    done, capture = _run([bins["humble"], "orphan"], tmp_path)
    assert done.returncode == 0, done.stderr
    p = _one(capture)
    assert p.threads[0].lost_other == 1 and len(p.callbacks) == 1


def test_a_thread_that_exits_inside_a_callback(bins, tmp_path):
    done, capture = _run([bins["humble"], "thread-exit"], tmp_path)
    assert done.returncode == 0, done.stderr
    p = _one(capture)
    quitter = next(t for t in p.threads if t.comm == "quitter")
    assert quitter.exited and quitter.open_cb == 0
    (c,) = [c for c in p.callbacks if c.tid == quitter.tid]
    assert c.unterminated and c.end_ns >= c.start_ns


def test_a_program_that_exits_inside_a_callback_leaves_it_open(bins, tmp_path):
    done, capture = _run([bins["humble"], "never-end"], tmp_path)
    assert done.returncode == 0, done.stderr
    p = _one(capture)
    assert p.callbacks == ()
    (thread,) = p.threads
    assert thread.open_cb != 0 and thread.open_since_ns > 0 and not thread.exited


def test_a_forked_child_writes_its_own_block_and_never_the_parents(bins, tmp_path):
    done, capture = _run([bins["humble"], "fork"], tmp_path)
    assert done.returncode == 0
    parent, child = sorted(capture.processes, key=lambda p: ProcessFlag.FORKED in p.flags)
    assert ProcessFlag.FORKED in child.flags and child.ppid == parent.pid != child.pid
    assert len(parent.callbacks) == 3 and len(child.callbacks) == 3
    assert {c.tid for c in parent.callbacks} == {parent.pid} and {c.tid for c in child.callbacks} == {child.pid}
    assert [c.seq for c in parent.callbacks] == [0, 1, 2] and [c.seq for c in child.callbacks] == [0, 1, 2]


def test_an_exec_keeps_its_exit_code_and_the_new_program_records_afresh(bins, tmp_path):
    done, capture = _run([bins["humble"], "exec", bins["humble"], "many"], tmp_path)
    assert done.returncode == 0 and done.stdout.endswith("done\n")
    before, after = capture.processes
    assert before.pid == after.pid and len(before.callbacks) == 1 and len(after.callbacks) == 10
    done, capture = _run([bins["humble"], "exec", "sh", "-c", "exit 7"], tmp_path)
    assert done.returncode == 7


def test_a_full_ring_overwrites_its_oldest_records_and_counts_them(bins, tmp_path):
    done, capture = _run([bins["humble"], "many", "1000"], tmp_path, capacity=64)
    assert done.returncode == 0, done.stderr
    p = _one(capture)
    (thread,) = p.threads
    assert thread.written == 1000 + 11 and thread.lost == thread.written - 64
    assert len(p.callbacks) == 64 and [c.seq for c in p.callbacks] == list(range(1000 - 64, 1000))


@pytest.fixture
def small_shm(tmp_path):
    """A tmpfs of 256 KiB, far smaller than a capture file: a container's /dev/shm, full."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    folder = tmp_path / "shm"
    folder.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(folder)], capture_output=True).returncode:
        pytest.skip("no tmpfs mount here")
    yield folder
    subprocess.run(["umount", str(folder)], check=True)


def test_a_full_dev_shm_refuses_the_thread_and_never_kills_the_program(bins, small_shm):
    # a ring of 1.5 MiB in a tmpfs of 256 KiB: its first page beyond the room was a SIGBUS in the program
    done, capture = _run([bins["humble"], "many", "20000"], small_shm)
    assert done.returncode == 0 and done.stdout.endswith("done\n"), done
    assert capture.threads_refused == 1 and not capture.error
    done, capture = _run([bins["humble"], "many", "2000"], small_shm, capacity=1024)  # a ring that fits is recorded
    assert done.returncode == 0 and capture.threads_refused == 0 and len(_one(capture).callbacks) == 1024


def test_threads_and_processes_beyond_the_file_are_refused_and_counted(bins, tmp_path):
    done, capture = _run([bins["humble"], "thread-exit"], tmp_path, max_threads=1)
    assert done.returncode == 0 and capture.threads_refused == 1 and len(_one(capture).threads) == 1
    done, capture = _run([bins["humble"], "fork"], tmp_path, max_procs=1)
    assert done.returncode == 0 and capture.processes_refused == 1 and len(capture.processes) == 1


def test_a_static_program_runs_unchanged(tmp_path):
    source = tmp_path / "hello.c"
    source.write_text('#include <stdio.h>\nint main(void) { puts("static"); return 4; }\n')
    binary = str(tmp_path / "hello")
    built = subprocess.run(["gcc", "-static", "-o", binary, str(source)], capture_output=True, text=True)
    if built.returncode != 0:
        pytest.skip(f"no static C library here (gcc -static: {built.stderr.strip().splitlines()[-1:]})")
    done, capture = _run([binary], tmp_path)
    assert (done.returncode, done.stdout) == (4, "static\n") and capture.processes == ()
    assert roscb.blocked(binary) == (
        "hello is statically linked: no dynamic loader reads LD_PRELOAD for it, so its callbacks cannot be measured"
    )
    script = tmp_path / "script"
    script.write_text(f"#!{binary} --flag\n")
    assert roscb.blocked(str(script)).startswith("hello is statically linked")  # a script is judged by its interpreter


def test_programs_the_preload_cannot_enter_are_named_from_their_elf_header(tmp_path):
    assert roscb.blocked(shutil.which("true") or "/bin/true") == "" and roscb.blocked(str(tmp_path / "missing")) == ""
    elf32 = tmp_path / "old"
    elf32.write_bytes(b"\x7fELF\x01\x01\x01" + bytes(57))  # ELFCLASS32: what gcc -m32 makes, where it can
    assert roscb.blocked(str(elf32)) == "old is a 32-bit program: the dynamic loader cannot load the runner's 64-bit interposer into it"
    if os.geteuid() != 0:
        return
    setuid = tmp_path / "su-like"
    shutil.copy(shutil.which("true") or "/bin/true", setuid)
    os.chown(setuid, 65534, 65534)
    os.chmod(setuid, 0o4755)
    assert roscb.blocked(str(setuid)).startswith("su-like is set-user-ID or set-group-ID: the dynamic loader ignores LD_PRELOAD")


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [("version", 99, "version 0x63"), ("record_size", 64, "record_size 0x40"), ("magic", 1, "magic 0x1")],
)
def test_a_file_of_another_layout_is_refused_by_both_sides_with_words(bins, tmp_path, field, value, words):
    capture = roscb.Capture.create("layout", folder=str(tmp_path))
    try:
        at = roscb.FILE.fields[field]
        os.pwrite(capture.fd, at.struct.pack(value), at.offset)
        done = subprocess.run([bins["humble"], "basic", "2"], env=capture.environment({"PATH": os.defpath}), capture_output=True, text=True)
        assert done.returncode == 0 and _calls(done.stdout)["callback_start"] == 4  # the program runs, forwarded
        read = capture.read()
    finally:
        capture.close()
    assert read.processes == () and "another layout" in read.error and words in read.error
    assert roscb.decode(b"\0" * 10).error.startswith("the capture file has 10 bytes")


def test_the_capture_file_is_new_private_sparse_and_removed(tmp_path):
    capture = roscb.Capture.create("file", folder=str(tmp_path))
    info = os.lstat(capture.path)
    assert stat.S_IMODE(info.st_mode) == 0o600 and info.st_uid == os.geteuid()
    assert info.st_size == roscb.file_size(roscb.MAX_PROCS, roscb.MAX_THREADS, roscb.CAPACITY) > 40 * 2**20
    assert info.st_blocks * 512 <= 64 * 1024  # sparse: the header alone is written
    capture.close()
    capture.close()
    assert not os.path.exists(capture.path)
    link = tmp_path / "runner-roscb-x-0"
    link.symlink_to(tmp_path / "elsewhere")
    with pytest.raises(FileExistsError):
        os.open(link, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)  # the flags Capture.create uses
    assert not (tmp_path / "elsewhere").exists()


def test_files_a_killed_runner_left_are_removed_by_the_next(tmp_path):
    dead = tmp_path / "runner-roscb-99999999-node-00"  # no process has that PID (above any pid_max)
    dead.write_bytes(b"")
    alive = tmp_path / f"runner-roscb-{os.getppid()}-node-00"
    alive.write_bytes(b"")
    other = tmp_path / "runner-roscb-notapid"
    other.write_bytes(b"")
    link = tmp_path / "runner-roscb-99999998-link"
    link.symlink_to(tmp_path / "target")
    (tmp_path / "target").write_bytes(b"kept")
    capture = roscb.Capture.create("node", folder=str(tmp_path))
    capture.close()
    assert not dead.exists() and alive.exists() and other.exists()
    assert link.is_symlink() and (tmp_path / "target").read_bytes() == b"kept"  # a link is never followed nor removed


def test_threads_are_named_as_the_monitor_last_saw_them():
    from runner.run.roscbdata import RosProcess, RosThread

    capture = RosCapture(processes=(RosProcess(1, 0, "node", threads=(RosThread(5, "node", 3, 0), RosThread(6, "mw", 1, 0))),))
    named = roscb.renamed(capture, {5: "exec0", 7: "other"})
    assert [t.comm for t in named.processes[0].threads] == ["exec0", "mw"]  # a thread the monitor never saw keeps its own


def test_the_users_preload_comes_first_and_ours_once():
    env = roscb.environment({"LD_PRELOAD": "/a.so /b.so", "X": "1"}, "/dev/shm/f")
    assert env["LD_PRELOAD"] == f"/a.so:/b.so:{roscb.LIBRARY}" and env[roscb.ENV] == "/dev/shm/f" and env["X"] == "1"
    assert roscb.environment(env, "/dev/shm/f")["LD_PRELOAD"] == env["LD_PRELOAD"]
    assert roscb.environment({}, "/p")["LD_PRELOAD"] == roscb.LIBRARY


def test_only_the_hooks_are_exported_and_never_compile_status():
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("no nm here")
    out = subprocess.run([nm, "-D", "--defined-only", roscb.LIBRARY], capture_output=True, text=True, check=True).stdout
    names = {line.split()[-1] for line in out.splitlines() if line.split()[1] in "TtWw"}
    assert names and all(n.startswith("ros_trace_") for n in names), names
    assert "ros_trace_compile_status" not in names
    assert {n for n in names if n.startswith("ros_trace_enabled_")} == {"ros_trace_enabled_rclcpp_callback_register"}


def test_the_tables_describe_the_records_python_reads():
    assert RECORDS["roscb_callback"].size == RECORDS["roscb_meta"].size == RECORDS["roscb_publish"].size == 96
    assert RECORDS["roscb_file"].size == 4096 and RECORDS["roscb_proc"].size == 512 and RECORDS["roscb_slot"].size == 128
    assert {kind.name: kind.value for kind in MetaKind} == {
        name.removeprefix("ROSCB_META_"): getattr(_probe, name) for name in dir(_probe) if name.startswith("ROSCB_META_")
    }
    assert sys.byteorder == "little"


class _Guard:
    def watch(self, pgid: int) -> None: ...
    def forget(self, pgid: int) -> None: ...
    def watch_cgroup(self, path: str) -> None: ...
    def forget_cgroup(self, path: str) -> None: ...


def _program_run(monkeypatch, tmp_path, command: list[str], **extra: object):
    from runner.run import external, kernel, memcg
    from runner.scenario.model import ProgramSpec

    monkeypatch.setattr(memcg, "hierarchy", lambda limit=True: (None, "no cgroup in this test"))
    spec = ProgramSpec.parse({"name": "node", "command": command, "until": "exit", **extra})
    return external.ProgramRun(spec, str(tmp_path), kernel.current_settings(), kernel.online_cpus())


def _files() -> set[str]:
    return {name for name in os.listdir(roscb.FOLDER) if name.startswith(f"runner-roscb-{os.getpid()}-node-")}


def test_a_command_program_runs_preloaded_and_its_raw_record_holds_the_decoded_capture(bins, monkeypatch, tmp_path):
    before = _files()
    run = _program_run(monkeypatch, tmp_path, [bins["jazzy"], "basic", "5"])
    run.launch(_Guard())
    assert run.capture is not None and os.path.exists(run.capture.path)
    path = run.capture.path
    run.release()
    for _ in range(500):
        run.look_callbacks(every_ns=0)
        if run.poll():
            break
        time.sleep(0.01)
    run.stop(_Guard())
    run.reap()
    raw = run.raw(None, time.monotonic_ns())
    assert raw.exit_code == 0 and raw.callbacks is not None and raw.callbacks.path == path
    (p,) = raw.callbacks.processes
    assert p.pid == run.pid and len(p.callbacks) == 10 and len(p.publishes) == 5 and raw.callbacks.blocked == ""
    assert not os.path.exists(path) and _files() == before  # removed at the end


def test_callbacks_off_runs_the_program_as_it_is(monkeypatch, tmp_path):
    run = _program_run(monkeypatch, tmp_path, ["sh", "-c", 'echo "[$LD_PRELOAD][$RUNNER_ROSCB]"'], callbacks=False)
    run.launch(_Guard())
    assert run.capture is None
    run.release()
    while not run.poll():
        time.sleep(0.01)
    run.stop(_Guard())
    run.reap()
    assert run.raw(None, time.monotonic_ns()).callbacks is None
    assert (tmp_path / "node.stdout").read_text() == f"[{os.environ.get('LD_PRELOAD', '')}][]\n"


def test_the_capture_file_is_removed_when_the_launch_fails(monkeypatch, tmp_path):
    from runner.run import external

    before = _files()

    def refused(*args: object) -> None:
        assert len(_files()) == len(before) + 1  # made before the fork
        raise KeyboardInterrupt

    monkeypatch.setattr(external._probe, "spawn_program", refused)
    run = _program_run(monkeypatch, tmp_path, ["true"])
    with pytest.raises(KeyboardInterrupt):
        run.launch(_Guard())
    run.stop(_Guard())
    callbacks = run.raw(None, time.monotonic_ns()).callbacks
    assert _files() == before and callbacks is not None and callbacks.error.startswith("the program never started")


def _synthetic(capacity: int, seqs: range, count: int, buf: bytearray | None = None) -> bytearray:
    """A capture file of one process (pid 123) and one thread whose ring holds callbacks numbered `seqs`, `count` written."""
    proc_at = roscb.FILE.size
    slot_at = proc_at + _probe.ROSCB_PROC_BYTES
    if buf is None:
        buf = bytearray(roscb.file_size(1, 1, capacity))
        buf[: roscb.FILE.size] = roscb.FILE.pack(
            {"magic": _probe.ROSCB_MAGIC, "version": _probe.ROSCB_VERSION, "header_size": roscb.FILE.size, "max_procs": 1,
             "max_threads": 1, "capacity": capacity, "record_size": 96, "proc_size": _probe.ROSCB_PROC_BYTES,
             "slot_size": roscb.SLOT.size + capacity * 96, "next_proc": 1, "next_thread": 1}
        )  # fmt: skip
        buf[proc_at : proc_at + roscb.PROC.size] = roscb.PROC.pack({"state": 1, "pid": 123})
    for n in seqs:
        at = slot_at + roscb.SLOT.size + (n % capacity) * 96
        buf[at : at + 96] = roscb.CALLBACK.pack({"type": 1, "seq": n, "cb": 7, "start_ns": n, "end_ns": n + 1})
    buf[slot_at : slot_at + roscb.SLOT.size] = roscb.SLOT.pack({"state": 1, "tid": 123, "pid": 123, "proc": 0, "count": count})
    return buf


def test_draining_while_the_program_runs_keeps_what_a_ring_alone_would_lose():
    reader = roscb.Reader()
    buf = _synthetic(4, range(3), 3)
    reader.drain(buf)
    _synthetic(4, range(3, 9), 9, buf)  # six more, the ring holds four: two were overwritten before this drain
    reader.drain(buf)  # and the oldest of the four may be being overwritten by the next: not taken while it runs
    _synthetic(4, range(9, 11), 11, buf)
    (p,) = reader.capture(buf).processes
    assert [c.seq for c in p.callbacks] == [0, 1, 2, 6, 7, 8, 9, 10]
    assert (p.threads[0].written, p.threads[0].lost) == (11, 3)
    assert [c.seq for c in roscb.decode(buf).processes[0].callbacks] == [7, 8, 9, 10]  # read once, at the end


def test_records_beyond_the_runners_bound_are_counted_lost():
    reader = roscb.Reader(max_records=5)
    (p,) = reader.capture(_synthetic(16, range(9), 9)).processes
    assert len(p.callbacks) == 5 and p.threads[0].lost == 4


def test_a_record_overwritten_while_it_was_copied_is_dropped_not_read_torn():
    class Racing(bytearray):
        """The thread writes two more records right after the runner copied its ring."""

        def __getitem__(self, index):  # type: ignore[override]
            out = super().__getitem__(index)
            if isinstance(index, slice) and len(range(*index.indices(len(self)))) == 4 * 96:
                _synthetic(4, range(4, 6), 6, self)
            return out

    reader = roscb.Reader()
    buf = Racing(_synthetic(4, range(4), 4))
    reader.drain(buf)  # while it runs
    (p,) = reader.capture(buf).processes
    assert [c.seq for c in p.callbacks] == [3, 4, 5] and p.threads[0].lost == 3  # record 6 may have begun to overwrite 2


def test_a_record_half_overwritten_by_the_next_while_it_was_copied_is_dropped():
    class Writing(bytearray):
        """The thread is writing record 4 over record 0 while the runner copies its ring: its count still says 4."""

        def __getitem__(self, index):  # type: ignore[override]
            out = super().__getitem__(index)
            if isinstance(index, slice) and len(range(*index.indices(len(self)))) == 4 * 96:
                out[:48] = roscb.CALLBACK.pack({"type": 1, "seq": 4, "cb": 9, "start_ns": 4, "end_ns": 5})[:48]
            return out

    reader = roscb.Reader()
    buf = Writing(_synthetic(4, range(4), 4))
    reader.drain(buf)  # while it runs
    (p,) = reader.capture(buf).processes
    assert [c.seq for c in p.callbacks] == [1, 2, 3] and p.threads[0].lost == 1


def test_a_capture_file_the_program_cut_short_reads_as_zeros_and_never_kills_the_runner(bins, tmp_path):
    # the file is the program's memory too: cut short under a mapped read, it was a SIGBUS in the runner (run apart here)
    script = f"""
import os, subprocess
from runner.run import roscb
capture = roscb.Capture.create("cut", folder={str(tmp_path)!r})
subprocess.run([{bins["humble"]!r}, "basic", "3"], env=capture.environment({{"PATH": os.defpath}}), check=True, capture_output=True)
capture.drain()  # while it runs: the records so far are the runner's
os.truncate(capture.path, roscb.FILE.size)
capture.drain()
read = capture.read()
capture.close()
print(len(read.processes), repr(read.error))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout == "0 ''\n"  # its process block reads as zeros: no process


def test_a_header_whose_sizes_change_after_the_first_read_is_another_layout():
    reader = roscb.Reader()
    buf = _synthetic(4, range(3), 3)
    reader.drain(buf)
    at = roscb.FILE.fields["capacity"]
    buf[at.offset : at.offset + at.struct.size] = at.struct.pack(2)  # the program rewrites the ring's geometry
    at = roscb.FILE.fields["slot_size"]
    buf[at.offset : at.offset + at.struct.size] = at.struct.pack(roscb.SLOT.size + 2 * 96)
    read = reader.capture(buf)
    assert (
        read.processes == ()
        and read.error == "the capture file's header changed while it was read: capacity 4 then 2, slot_size 512 then 320"
    )


def test_records_that_all_name_one_long_string_hold_no_more_than_their_arena():
    # the program's memory: a record may point anywhere in its arena, and 64 records at one 1 KiB string were 64 KiB held
    capacity = 64
    buf = _synthetic(capacity, range(0), capacity)
    slot_at = roscb.FILE.size + _probe.ROSCB_PROC_BYTES + roscb.SLOT.size
    for n in range(capacity):
        at = slot_at + n * 96
        buf[at : at + 96] = roscb.META.pack({"type": MetaKind.SYM.value, "a": n + 1, "s1_off": 0, "s1_len": _probe.ROSCB_STRING_MAX})
    arena_at = roscb.FILE.size + roscb.PROC.size
    buf[arena_at : arena_at + _probe.ROSCB_STRING_MAX] = b"x" * _probe.ROSCB_STRING_MAX
    (p,) = roscb.decode(buf).processes
    assert len(p.metas) == capacity and sum(len(m.s1) for m in p.metas) <= roscb.ARENA
    assert p.metas[0].s1 == "x" * _probe.ROSCB_STRING_MAX and not p.metas[0].truncated and p.metas[-1].truncated
    beyond = roscb.META.pack({"type": MetaKind.SYM.value, "a": 1, "s1_off": 0, "s1_len": _probe.ROSCB_STRING_MAX + 1})
    buf[slot_at : slot_at + 96] = beyond  # longer than the interposer ever writes: left out
    assert roscb.decode(buf).processes[0].metas[0] == replace(p.metas[0], s1="", truncated=True)


def test_the_capture_files_name_is_removed_only_while_it_is_the_runners_file(tmp_path):
    capture = roscb.Capture.create("swap", folder=str(tmp_path))
    os.rename(capture.path, tmp_path / "moved")  # the program moved it and put a file of its own in its place
    with open(capture.path, "w") as handle:
        handle.write("the program's")
    capture.close()
    assert open(capture.path).read() == "the program's"
