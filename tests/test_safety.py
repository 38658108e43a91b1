"""Nothing lost, nothing mixed up, nothing left behind: the runner against hostile timing and a hostile machine.

Each test runs a real scenario for a second or three and does to it what users and
machines do: a second run into the same folder, SIGKILL of the runner, Ctrl-C twice,
a worker stopped with SIGSTOP, a background hog killed, a disk that fills up.  What
is checked comes from the kernel (/proc: which processes are still alive) and from
the files left behind, never from the runner's own account of itself.
"""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import time

import pytest
from conftest import REPO, SCENARIOS
from kernelrun import finish, needs_rt, start_runner, thread, wait_for_threads

from runner.run import memcg
from runner.run.kernel import find_pids

pytestmark = [pytest.mark.kernel, needs_rt]

FIFO80 = os.path.join(SCENARIOS, "fifo80.yaml")


def _scenario(path, name: str, period: str = "100ms", burn: str = "10ms", extra: str = "", duration: str = "3s") -> str:
    path.write_text(
        f"name: {name}\nduration: {duration}\nprocesses:\n  - name: {name}\n    main:\n      sched: fifo:80\n"
        f"      work: {{kind: periodic, period: {period}, burn: {burn}}}\n{extra}"
    )
    return str(path)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        return False


def test_a_second_run_into_the_same_folder_is_refused_and_the_first_is_untouched(tmp_path):
    out = str(tmp_path / "r")
    first = start_runner(FIFO80, "--duration", "2s", "--out", out, "--quiet", cwd=str(tmp_path))
    wait_for_threads("minimal_schedul", 10)
    second = start_runner(FIFO80, "--duration", "2s", "--out", out, "--quiet", cwd=str(tmp_path))
    late = finish(second, out)
    done = finish(first, out)
    assert late.code == 2, late.err
    assert "in use by another runner" in late.err and "Traceback" not in late.err
    assert done.code == 0, done.err
    cell = done.results["cells"][0]
    assert cell["status"] == "passed" and len(done.results["cells"]) == 1
    main = thread(done.results, "minimal_schedul", index=0)
    assert main["figures"]["callbacks"] >= 15 and main["pid"] in {t["pid"] for t in cell["threads"]}


def test_background_commands_and_their_children_die_with_a_sigkilled_runner(tmp_path):
    marker = f"runner-safety-{os.getpid()}"
    forks = "import os, time; os.fork(); time.sleep(60)"  # the command leaves a child in its process group
    extra = f"background:\n  commands:\n    - argv: [{sys.executable}, -c, '{forks}', {marker}]\n"
    path = _scenario(tmp_path / "s.yaml", "cmdkill", extra=extra, duration="20s")
    proc = start_runner(path, "--out", str(tmp_path / "r"), "--quiet", cwd=str(tmp_path))
    wait_for_threads("cmdkill", 1)
    time.sleep(0.5)
    sleepers = _pids_with_cmdline(marker)
    assert len(sleepers) == 2, "the command and the child it left in its group should be running"
    proc.kill()
    proc.wait()
    until = time.monotonic() + 5
    while (_pids_with_cmdline(marker) or find_pids("cmdkill")) and time.monotonic() < until:
        time.sleep(0.05)
    assert not _pids_with_cmdline(marker), "a background command outlived the SIGKILLed runner"
    assert not find_pids("cmdkill") and not any(_alive(p) for p in sleepers)


@pytest.mark.parametrize("end", ["the cell ends", "the runner is SIGKILLed", "the runner and its guard are SIGKILLed together"])
def test_what_a_program_or_command_starts_in_a_session_of_its_own_dies_with_the_cell(tmp_path, end):
    """`setsid sleep &` left its group and outlived a finished run: the cgroup each is started in holds it anyway.

    With the guard killed beside the runner (`pkill -9`, a container's stop that spares no one), the
    program's children and grandchildren and the background commands once all lived on, in cgroups
    no one removed.
    """
    marker = f"runner-escape-{os.getpid()}-{end[4:12]}"
    escape = "import os, time; os.fork() or (os.setsid(), os.fork() or time.sleep(60)); time.sleep(60)"
    extra = (
        f"  - {{name: prog, command: [{sys.executable}, -c, '{escape}', {marker}]}}\n"
        f"background:\n  commands:\n    - argv: [{sys.executable}, -c, '{escape}', {marker}]\n"
    )
    path = _scenario(tmp_path / "s.yaml", "escape", extra=extra, duration="2s" if end == "the cell ends" else "20s")
    proc = start_runner(path, "--out", str(tmp_path / "r"), "--quiet", "--no-report", cwd=str(tmp_path))
    wait_for_threads("escape", 1)
    until = time.monotonic() + 5
    while len(_pids_with_cmdline(marker)) < 6 and time.monotonic() < until:
        time.sleep(0.05)
    assert len(_pids_with_cmdline(marker)) == 6, "each: itself, a child in its group, and one in a session of its own"
    groups = _runner_cgroups(proc.pid)
    assert len(groups) == 2 or not memcg.hierarchy(limit=False)[0], groups  # the program's and the command's, where cgroups serve
    if end == "the runner and its guard are SIGKILLed together":
        guards = [pid for pid in _children(proc.pid) if b"runner.run.guard" in _cmdline(pid)]
        assert len(guards) == 1, "the runner's guard"
        os.kill(guards[0], signal.SIGKILL)
        proc.kill()
    elif end == "the runner is SIGKILLed":
        proc.kill()
    proc.wait(timeout=30)
    until = time.monotonic() + 5
    while (_pids_with_cmdline(marker) or _runner_cgroups(proc.pid)) and time.monotonic() < until:
        time.sleep(0.05)
    assert not _pids_with_cmdline(marker), f"a process started by a program or command outlived the runner when {end}"
    assert not find_pids("escape"), f"a worker outlived the runner when {end}"
    assert not _runner_cgroups(proc.pid), f"the runner's cgroups were left behind when {end}"


def test_a_programs_cgroup_is_no_one_elses_to_write_under_umask_0(tmp_path):
    """Made under umask 0, a program's cgroup was 0777: another user could make a cgroup inside it, which no rmdir then removes."""
    if memcg.hierarchy(limit=False)[0] is None:
        pytest.skip("the runner may not make cgroups here")
    path = _scenario(tmp_path / "s.yaml", "umask", extra="  - {name: prog, command: [sleep, '60']}\n", duration="20s")
    proc = start_runner(
        path, "--out", str(tmp_path / "r"), "--quiet", "--no-report", cwd=str(tmp_path), prefix=("sh", "-c", 'umask 0; exec "$@"', "sh")
    )
    try:
        wait_for_threads("umask", 1)
        until = time.monotonic() + 5
        while not _runner_cgroups(proc.pid) and time.monotonic() < until:
            time.sleep(0.05)
        groups = _runner_cgroups(proc.pid)
        assert groups, "the program's cgroup"
        for group in groups:
            assert stat.S_IMODE(os.stat(group).st_mode) == 0o755, (group, oct(os.stat(group).st_mode))
    finally:
        proc.kill()
        proc.wait(timeout=30)


def _runner_cgroups(pid: int) -> list[str]:
    """The cgroups the runner of `pid` made (`runner-<pid>-*`), in every hierarchy it could make them in."""
    found = memcg.locate(open("/proc/self/mountinfo").read(), open("/proc/self/cgroup").read())
    return sorted(
        os.path.join(h.folder, n) for h in found if os.path.isdir(h.folder) for n in os.listdir(h.folder) if n.startswith(f"runner-{pid}-")
    )


def _children(pid: int) -> list[int]:
    out: list[int] = []
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as handle:
            out += [int(p) for p in handle.read().split()]
    return out


def _cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            return handle.read()
    except OSError:
        return b""


def _pids_with_cmdline(marker: str) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/cmdline", "rb") as handle:
                    if marker.encode() in handle.read().split(b"\0") and _alive(int(entry)):
                        out.append(int(entry))
            except OSError:
                continue
    return out


@pytest.mark.parametrize("gap", [0.05, 0.3])
def test_a_second_signal_while_stopping_still_writes_results_and_report(tmp_path, gap):
    out = str(tmp_path / "r")
    proc = start_runner(FIFO80, "--duration", "4s", "--out", out, "--quiet", cwd=str(tmp_path))
    wait_for_threads("minimal_schedul", 10)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    time.sleep(gap)
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    done = finish(proc, out)
    assert done.code == 130, (done.code, done.err)
    assert "Traceback" not in done.err
    assert done.results["status"] == "interrupted"
    assert [c["status"] for c in done.results["cells"]] == ["interrupted"]
    assert os.path.exists(os.path.join(out, "report.md"))
    assert not find_pids("minimal_schedul") and not find_pids("hog")


def test_a_stopped_worker_is_an_error_with_its_missed_releases_counted(tmp_path):
    out = str(tmp_path / "r")
    proc = start_runner(FIFO80, "--duration", "3s", "--out", out, "--quiet", cwd=str(tmp_path))
    pid = wait_for_threads("minimal_schedul", 10)
    time.sleep(0.7)
    os.kill(pid, signal.SIGSTOP)
    time.sleep(1.5)
    os.kill(pid, signal.SIGCONT)
    done = finish(proc, out)
    assert done.code == 4, done.err
    cell = done.results["cells"][0]
    assert cell["status"] == "error" and "was stopped (SIGSTOP or a debugger)" in cell["reason"], cell["reason"]
    main = thread(done.results, "minimal_schedul", index=0)
    # 30 releases of 100 ms in 3 s; about 15 fell in the 1.5 s stop: far more than the jitter of a free run
    assert main["figures"]["missed_releases"] >= 8 and main["figures"]["callbacks"] + main["figures"]["missed_releases"] >= 29, main


def test_a_hog_killed_mid_cell_is_an_error(tmp_path):
    out = str(tmp_path / "r")
    proc = start_runner(FIFO80, "--duration", "3s", "--out", out, "--quiet", cwd=str(tmp_path))
    wait_for_threads("minimal_schedul", 10)
    time.sleep(1.0)
    hogs = find_pids("hog")
    assert hogs
    os.kill(hogs[0], signal.SIGKILL)
    done = finish(proc, out)
    assert done.code == 4, done.err
    cell = done.results["cells"][0]
    assert cell["status"] == "error" and "killed by SIGKILL" in cell["reason"] and "background hog" in cell["reason"]


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs: room for a run's results, not for the samples of a fast thread."""
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mount)], capture_output=True, text=True)
    if done.returncode != 0:
        if os.environ.get("CI"):
            pytest.fail(f"cannot mount a tmpfs for the full-disk test: {done.stderr.strip()}")
        pytest.skip(f"cannot mount a tmpfs: {done.stderr.strip()}")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_full_disk_keeps_the_finished_cells_and_marks_the_one_in_flight(tmp_path, small_disk):
    # cell 1: 20 callbacks of 100 ms, a samples file of a few KiB; cell 2: a 20 us period for 2 s, up to 100,000
    # rows streamed to samples.csv.gz (a few MiB even compressed): the disk fills while the cell runs
    scenario = tmp_path / "s.yaml"
    scenario.write_text(
        "name: fulldisk\nduration: 1s\nmatrix:\n  period: [100ms, 20us]\nprocesses:\n  - name: fulldisk\n    main:\n"
        "      sched: fifo:80\n      work: {kind: periodic, period: '${{ matrix.period }}'}\n"
    )
    out = small_disk / "r"
    proc = start_runner(str(scenario), "--duration", "2s", "--settle", "0", "--out", str(out), "--quiet", cwd=str(tmp_path))
    done = finish(proc, str(out))
    assert done.code == 4, (done.code, done.err)
    assert "Traceback" not in done.err and "No space left on device" in done.err
    cells = done.results["cells"]
    assert cells[0]["status"] == "passed" and thread(done.results, "fulldisk")["figures"]["callbacks"] >= 15
    assert len(cells) == 2 and cells[1]["status"] == "error" and "No space left on device" in cells[1]["reason"]
    assert done.results["status"] == "error"
    leftovers = [
        os.path.join(d, f) for d, _, files in os.walk(out) for f in files if f.startswith(".results-") or f.endswith((".tmp", ".smp"))
    ]
    assert not leftovers
    assert not find_pids("fulldisk")
    with open(out / "results.json") as handle:
        json.load(handle)  # complete JSON, not a torn write


def test_root_without_cap_ipc_lock_is_bound_by_rlimit_memlock(tmp_path):
    """As in a container: uid 0 but no CAP_IPC_LOCK, so mlockall is limited by RLIMIT_MEMLOCK.

    Locking is refused before anything starts (exit 3, permission, with how to grant it), whatever
    the size asked: preallocating more than the limit once was invalid input (exit 2) while a
    small lock was a missing permission (exit 3), for the same missing right.
    """
    if os.geteuid() != 0:
        pytest.skip("needs root to drop CAP_IPC_LOCK while staying uid 0")
    prefix = ("prlimit", "--memlock=65536:65536", "setpriv", "--inh-caps=-ipc_lock", "--bounding-set=-ipc_lock")
    path = _scenario(tmp_path / "s.yaml", "locker", duration="1s")
    with open(path, "a") as handle:
        handle.write("    memory: {lock: true}\n")
    out = str(tmp_path / "r")
    done = finish(start_runner(path, "--out", out, cwd=str(tmp_path), prefix=prefix), out)
    assert done.code == 3, (done.code, done.err)
    assert "RLIMIT_MEMLOCK is 64KiB" in done.err and "CAP_IPC_LOCK" in done.err and "Traceback" not in done.err
    assert done.results is None

    lock = os.path.join(SCENARIOS, "memory_lock.yaml")
    prealloc = finish(start_runner(lock, "--cell", "*prealloc=128MiB", "--out", out, cwd=str(tmp_path), prefix=prefix), out)
    assert prealloc.code == 3, (prealloc.code, prealloc.err)
    assert "prealloc 128MiB and 6 thread stacks pin about 240MiB" in prealloc.err and "RLIMIT_MEMLOCK is 64KiB" in prealloc.err
    assert "LimitMEMLOCK=infinity" in prealloc.err and "Traceback" not in prealloc.err and prealloc.results is None
    listed = finish(start_runner(lock, "--list", cwd=str(tmp_path), prefix=prefix), out)
    assert listed.code == 0 and "warning: processes[0].memory: process minimal_memory_ locks its memory" in listed.err, listed.err
    assert "minimal_memory_" in listed.out
    for command in (("validate", lock), ("import-rtapp", os.path.join(REPO, "tests", "rtapp", "mp3-short.json"))):
        checked = finish(start_runner(*command, cwd=str(tmp_path), prefix=prefix), out)
        assert checked.code == 0 and "RLIMIT_MEMLOCK is 64KiB and this user has no CAP_IPC_LOCK" in checked.err, (command, checked.err)
