"""The scheduler trace on this kernel: busy loops that preempt each other, a FIFO sleeper beside a hog, cleanup.

Each run traces about 1 s; the processes are named `trt-*` and pinned to the last
CPU.  The figures (events/s, the reader's CPU share) are printed (`pytest -s`).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Optional

import pytest
from kernelrun import needs_rt, needs_tracing

from runner import histogram
from runner.run import tracing

pytestmark = [pytest.mark.kernel, needs_tracing]

CPU = max(os.sched_getaffinity(0))
SPIN = "while True:\n    pass\n"
SLEEP_1MS = "import time\nwhile True:\n    time.sleep(0.001)\n"


@pytest.fixture(autouse=True)
def _tracefs() -> None:
    found = tracing.find_tracefs()
    if isinstance(found, tracing.TraceUnavailable):
        pytest.skip(found.reason)


@pytest.fixture
def procs() -> Iterator[list[subprocess.Popen[bytes]]]:
    started: list[subprocess.Popen[bytes]] = []
    yield started
    for p in started:
        p.kill()
        p.wait()


def spawn(started: list[subprocess.Popen[bytes]], name: str, code: str, fifo: Optional[int] = None, cpu: int = CPU) -> int:
    """A Python process named `name` on `cpu`, running `code`; its pid once its name is set."""
    prologue = f"import os\nopen('/proc/self/comm', 'w').write({name!r})\nos.sched_setaffinity(0, {{{cpu}}})\n"
    if fifo is not None:
        prologue += f"os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({fifo}))\n"
    p = subprocess.Popen([sys.executable, "-c", prologue + code], start_new_session=True)
    started.append(p)
    until = time.monotonic() + 5
    while time.monotonic() < until:
        try:
            with open(f"/proc/{p.pid}/comm") as handle:
                if handle.read().strip() == name:
                    time.sleep(0.05)  # its policy is set right after its name
                    return p.pid
        except OSError:
            pass
        time.sleep(0.01)
    raise AssertionError(f"{name} did not start")


def trace(pids: list[int], seconds: float = 1.0) -> tuple[tracing.TraceData, tuple[str, ...]]:
    tracer = tracing.open_trace(pids)
    assert isinstance(tracer, tracing.Tracer), tracer
    time.sleep(seconds)
    data = tracer.stop()
    return data, tracer.paths


def report(label: str, data: tracing.TraceData) -> None:
    seconds = data.duration_ns / 1e9
    print(
        f"\n{label}: {data.events} events in {seconds:.2f} s = {data.events / seconds:,.0f} events/s, "
        f"reader CPU {data.reader_cpu_ns / 1e6:.1f} ms = {100 * data.reader_cpu_ns / data.duration_ns:.2f}%, lost {data.lost}"
    )


def test_two_busy_loops_on_one_cpu_preempt_each_other(procs):
    a = spawn(procs, "trt-busy-a", SPIN)
    b = spawn(procs, "trt-busy-b", SPIN)
    data, paths = trace([a, b])
    report("two busy loops", data)
    assert data.lost == 0 and data.out_of_order == 0 and data.untracked == 0
    assert set(data.threads) == {a, b}, "only the listed threads are aggregated"
    for me, other in ((a, "trt-busy-b"), (b, "trt-busy-a")):
        t = data.threads[me]
        assert t.preemptions >= 50, t
        assert t.preemptors[0].comm == other and t.preemptors[0].prio == 120
        assert t.preemptors[0].times >= 0.5 * t.preemptions, t.preemptors  # the rest: whatever else ran there (kernel threads)
        assert t.cpus == (CPU,)
    run_a, run_b = data.threads[a].run_ns, data.threads[b].run_ns
    assert 0.5 * data.duration_ns <= run_a + run_b <= data.duration_ns, "the CPU is theirs, most of the time"
    assert 0.35 <= run_a / (run_a + run_b) <= 0.65, "SCHED_OTHER shares it fairly between the two"
    assert not any(os.path.exists(p) for p in paths), "the instances are removed"


@needs_rt  # tracing is root's, and root may have no CAP_SYS_NICE (a container, securebits)
def test_a_fifo_sleeper_beside_a_hog_is_woken_and_never_preempted(procs):
    hog = spawn(procs, "trt-hog", SPIN)
    rt = spawn(procs, "trt-fifo80", SLEEP_1MS, fifo=80)
    data, paths = trace([rt, hog])
    report("FIFO 80 sleeper and a hog", data)
    t = data.threads[rt]
    lat = histogram.from_rows(t.latency, t.latency_min, t.latency_max)
    assert lat is not None
    print(f"FIFO 80 wake-ups {t.wakeups}, p50 {lat.quantile(0.5) / 1000:.1f} us, max {t.latency_max / 1000:.1f} us")
    assert data.lost == 0
    assert t.wakeups > 500 and t.preemptions <= 2
    assert lat.quantile(0.5) < 200_000
    assert t.worst[0].latency_ns == t.latency_max and t.worst[0].cpu == CPU
    assert {w.delayer_comm for w in t.worst} <= {"trt-hog", f"swapper/{CPU}"} | {p.comm for p in data.threads[hog].preemptors}
    h = data.threads[hog]
    assert h.preemptions >= 500 and h.preemptors[0].comm == "trt-fifo80" and h.preemptors[0].prio == 99 - 80
    assert not any(os.path.exists(p) for p in paths)


def test_threads_and_children_created_while_tracing_are_followed(procs):
    code = (
        "import os, threading, time\ntime.sleep(0.3)\n"
        "t = threading.Thread(target=time.sleep, args=(0.05,))\nt.start()\nt.join()\n"
        "if os.fork() == 0:\n    time.sleep(0.05)\n    os._exit(0)\nos.wait()\ntime.sleep(5)\n"
    )
    parent = spawn(procs, "trt-forker", code)
    data, _ = trace([parent], seconds=0.8)
    assert len(data.threads) == 3, data.threads.keys()
    assert sum(t.exited for t in data.threads.values()) == 2, "the thread and the child exited"


def test_a_killed_owner_leaves_no_instance_behind(tmp_path):
    script = (
        "import time\nfrom runner.run import tracing\nfrom runner.run.guard import Guard\n"
        "g = Guard()\nt = tracing.open_trace([1], guard=g)\nprint(' '.join(t.paths), flush=True)\ntime.sleep(60)\n"
    )
    owner = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    assert owner.stdout is not None
    paths = owner.stdout.readline().split()
    assert paths and all(os.path.isdir(p) for p in paths)
    owner.kill()
    owner.wait()
    until = time.monotonic() + 5
    while any(os.path.exists(p) for p in paths) and time.monotonic() < until:
        time.sleep(0.05)
    assert not any(os.path.exists(p) for p in paths), "the guard removes the instances of its dead owner"


def test_a_backend_lets_go_of_its_instances_and_zygote_once_the_cells_are_done():
    from runner.run.kernelbackend import KernelBackend

    backend = KernelBackend()
    try:
        backend.prepare(trace=True)
        assert backend._preparing is not None
        backend._preparing.join()
        paths, zygote = backend.traces.paths, backend.zygote
        assert paths and all(os.path.isdir(p) for p in paths) and zygote is not None
        backend.cells_done()
        backend.cells_done()  # a second call starts nothing more
        assert len(backend._winding_down) == 2
    finally:
        backend.close()
    assert not any(os.path.exists(p) for p in paths), "the trace's instances are removed by the time close() returns"
    assert zygote.proc.returncode is not None and zygote.closed, "the zygote is reaped"
    assert backend.guard.proc is None


def test_instances_of_a_dead_runner_are_removed_at_open():
    gone = subprocess.Popen(["true"])
    gone.wait()
    root = tracing.find_tracefs()
    assert isinstance(root, tracing.TracefsRoot)
    stale = [os.path.join(root.path, "instances", f"runner-{gone.pid}-0{suffix}") for suffix in ("", "-migrate")]
    for path in stale:
        os.mkdir(path)
    tracer = tracing.open_trace([os.getpid()])
    assert isinstance(tracer, tracing.Tracer)
    with tracer:
        assert not any(os.path.exists(p) for p in stale)
        assert f"removed the tracing instance runner-{gone.pid}-0 of a runner that died" in tracer.notes
    assert not any(os.path.exists(p) for p in tracer.paths), "close() removes them too"


def test_a_tracer_dropped_or_left_at_exit_stops_tracing():
    tracer = tracing.open_trace([os.getpid()])
    assert isinstance(tracer, tracing.Tracer)
    paths = tracer.paths
    del tracer
    assert not any(os.path.exists(p) for p in paths), "dropped: the finalizer removed them"
    script = "import os\nfrom runner.run import tracing\nt = tracing.open_trace([os.getpid()])\nprint(' '.join(t.paths))\n"
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, cwd="/")
    paths = tuple(done.stdout.split())
    assert paths and not any(os.path.exists(p) for p in paths), "left at interpreter exit: removed then"


def _sweep_in_another_pid_namespace(root: str, owner: int) -> list[str]:
    """What a runner started in a new PID namespace (a container: `unshare --pid --fork --mount-proc`) removes of
    `owner`'s instances at its start; it must not see `owner` among its processes."""
    code = (
        "import os, sys\nfrom runner.run import tracing\n"
        f"assert not os.path.exists('/proc/{owner}'), 'the namespace sees the owner'\n"
        f"print(' '.join(tracing.remove_stale({root!r}, owner={owner})))\n"
    )
    argv = ["unshare", "--pid", "--fork", "--mount-proc", sys.executable, "-c", code]
    done = subprocess.run(argv, capture_output=True, text=True, cwd="/")
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


@pytest.mark.skipif(not shutil.which("unshare"), reason="needs unshare (util-linux)")
def test_a_runner_in_another_pid_namespace_leaves_a_live_runners_instances_alone(procs):
    """PIDs are not unique across PID namespaces: a runner in a container sees no process with this runner's PID,
    and must still leave its instances, and their tracing, alone: between two traces (a run keeps its instances
    from its first cell to its end) and during one."""
    if subprocess.run(["unshare", "--pid", "--fork", "--mount-proc", "true"], capture_output=True).returncode != 0:
        pytest.skip("a PID namespace needs CAP_SYS_ADMIN (unshare --pid)")
    root = tracing.find_tracefs()
    assert isinstance(root, tracing.TracefsRoot)
    instances = tracing.TraceInstances()
    try:
        instances.prepare()
        paths = instances.paths
        assert paths, "the instances were set up"
        assert _sweep_in_another_pid_namespace(root.path, os.getpid()) == []
        assert all(os.path.isdir(p) for p in paths), "between two traces the instances stay"
        # on CPU 0: this VM's kernel traces no switch out of idle on CPU 1, where a lone sleeper's wake-ups go unmeasured
        sleeper = spawn(procs, "trt-ns", SLEEP_1MS, cpu=0)
        tracer = instances.open([sleeper])
        assert isinstance(tracer, tracing.Tracer), tracer
        with tracer:
            time.sleep(0.2)
            assert _sweep_in_another_pid_namespace(root.path, os.getpid()) == []
            assert [_read(os.path.join(p, "tracing_on")).strip() for p in paths] == ["1"] * len(paths), "tracing stays on"
            tracer.window(time.monotonic_ns(), None)  # only what the trace holds after the sweep
            time.sleep(0.3)
            data = tracer.stop()
        assert data.threads[sleeper].wakeups > 50, "the trace went on recording after the sweep"
    finally:
        instances.close()
    assert not any(os.path.exists(p) for p in paths), "the owner still removes its own"


def test_a_dead_runners_instance_is_removed_without_its_tracing_being_written():
    """The sweep removes an instance no one holds (rmdir), and never writes a file of one that someone holds."""
    gone = subprocess.Popen(["true"])
    gone.wait()
    root = tracing.find_tracefs()
    assert isinstance(root, tracing.TracefsRoot)
    dead, held = (os.path.join(root.path, "instances", f"runner-{gone.pid}-{n}") for n in (0, 1))
    os.mkdir(dead)
    os.mkdir(held)
    try:
        with open(os.path.join(held, "tracing_on"), "w") as on:
            on.write("1")
            on.flush()
            assert tracing.remove_stale(root.path, owner=gone.pid) == [f"runner-{gone.pid}-0"]
            assert not os.path.exists(dead) and os.path.isdir(held)
            assert _read(os.path.join(held, "tracing_on")).strip() == "1"
    finally:
        os.rmdir(held)


def _read(path: str) -> str:
    with open(path) as handle:
        return handle.read()
