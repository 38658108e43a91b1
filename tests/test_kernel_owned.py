"""What the runner kills is its own: not another runner's because a PID namespace hides it, not a stranger given a PID.

A PID names a process only in its namespace and only while that process holds it.  These tests
make both happen on purpose: a sweep run from a new PID namespace (`unshare --pid`, as a runner
in a container), and a PID handed to a new process as soon as its owner is reaped (a new PID
namespace's `ns_last_pid` says which number the next process gets, so nothing outside it is
touched).  What is checked is the kernel's: whether the bystander process is still alive.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time

import pytest
from test_safety import _alive

from runner.run import memcg

pytestmark = [pytest.mark.kernel, pytest.mark.skipif(not shutil.which("unshare"), reason="needs unshare (util-linux)")]


def _in_new_pid_namespace(code: str, *args: str) -> str:
    """Run Python `code` as the first process of a new PID namespace (its own /proc); its stdout."""
    done = subprocess.run(
        ["unshare", "--pid", "--fork", "--mount-proc", sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=60
    )
    if done.returncode != 0 and "unshare failed: Operation not permitted" in done.stderr:
        pytest.skip("a PID namespace needs CAP_SYS_ADMIN (unshare --pid)")
    assert done.returncode == 0, done.stderr
    return done.stdout


def _hierarchy() -> memcg.Hierarchy:
    where, why = memcg.hierarchy(limit=False)
    if where is None:
        pytest.skip(f"the runner may not make cgroups here: {why}")
    return where


_SWEEP = """\
import os, sys
from runner.run import memcg
h, name = memcg.hierarchy(limit=False)[0], sys.argv[1]
listed = os.listdir
os.listdir = lambda p: [n for n in listed(p) if n == name] if p == h.folder else listed(p)  # this test's cgroup alone
assert not os.path.exists('/proc/%d' % int(sys.argv[2])), 'the namespace sees the owner'
memcg.MemoryCgroup.create(h, 'sweeper', None).remove()  # what every program's and command's start does first
"""


def test_a_runner_in_another_pid_namespace_leaves_a_live_runners_programs_alone():
    """A runner in a container sees no process with the PID in a host runner's cgroup name, and killed that
    runner's program (and everything in its cgroup) as a dead runner's leftovers, at its own program's start."""
    h = _hierarchy()
    group = memcg.MemoryCgroup.create(h, "owned", None)
    program = subprocess.Popen(["sleep", "60"])
    try:
        group.add(program.pid)
        _in_new_pid_namespace(_SWEEP, os.path.basename(group.folder), str(os.getpid()))
        time.sleep(0.1)
        assert program.poll() is None, "the live runner's program was killed by a sweep from another PID namespace"
        assert os.path.isdir(group.folder)
    finally:
        program.kill()
        program.wait()
        group.kill_all()
        group.remove()


def test_the_cgroup_of_a_dead_runner_of_this_namespace_is_still_emptied_and_removed():
    h = _hierarchy()
    code = (
        "import subprocess, sys\nfrom runner.run import memcg\n"
        "g = memcg.MemoryCgroup.create(memcg.hierarchy(limit=False)[0], 'left', None)\n"
        "p = subprocess.Popen(['sleep', '60'], start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\n"
        "g.add(p.pid)\n"
        "print(g.folder, p.pid, flush=True)\n"
    )
    dead = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)  # exits: its cgroup is left
    folder, left = dead.stdout.split()
    try:
        assert os.path.isdir(folder) and os.path.exists(f"/proc/{left}")
        memcg._remove_stale(h, owner=int(os.path.basename(folder).split("-")[1]))
        assert not os.path.exists(folder), "a dead runner's cgroup of this namespace is removed"
        assert not _alive(int(left)), "and what it held is killed"
    finally:
        if os.path.isdir(folder):
            memcg.kill_all(folder)
            memcg.remove(folder)


_PROGRAM_EXITS_EARLY = """\
import os, subprocess, sys, time
from runner.run import kernel
from runner.run.external import ProgramRun
from runner.scenario.model import ProgramSpec

class NoGuard:
    def watch(self, pgid): pass
    def forget(self, pgid): pass
    def watch_cgroup(self, path): pass
    def forget_cgroup(self, path): pass

run = ProgramRun(ProgramSpec.parse({"name": "quick", "command": ["true"]}), sys.argv[1], kernel.current_settings(), kernel.online_cpus())
run.launch(NoGuard())
run.release()
until = time.monotonic() + 10
while not run.poll() and time.monotonic() < until:  # what the monitor does while the cell runs
    time.sleep(0.005)
with open("/proc/sys/kernel/ns_last_pid", "w") as f:  # the next process gets the program's number, if it is free
    f.write(str(run.pid - 1))
newcomer = subprocess.Popen(["sleep", "60"], start_new_session=True)  # a group leader: a shell's job, a daemon
run.stop(NoGuard())
getattr(run, "reap", lambda: None)()  # reaped by now before it had one
time.sleep(0.1)
print(run.pid, newcomer.pid, newcomer.poll())
newcomer.kill()
"""


def test_the_group_of_a_program_that_exited_early_is_never_a_strangers_it_was_given_to(tmp_path):
    """Reaped at its exit, a program left its PID free while the cell ran on, and the SIGKILL of its group at the
    cell's end went to the process group that had been given that number since."""
    program, newcomer, code = _in_new_pid_namespace(_PROGRAM_EXITS_EARLY, str(tmp_path)).split()
    assert code == "None", f"the process given the program's PID {program} ({newcomer}) was killed at the program's stop"


_RUN_WITH_ONE_ENDING_EARLY = """\
import os, signal, subprocess, sys, time
folder = sys.argv[1]
scenario = os.path.join(folder, "s.yaml")
with open(scenario, "w") as f:
    f.write(
        "name: reuse\\nduration: 3s\\nprocesses:\\n"
        + "".join(f"  - name: {n}\\n    main:\\n      sched: other\\n      work: {{kind: periodic, period: 100ms, burn: 1ms}}\\n"
                  for n in ("victim", "keeper"))
        + f"background:\\n  commands:\\n    - argv: [sh, -c, 'echo $$ > {folder}/command.pid']\\n"
    )
runner = subprocess.Popen([sys.executable, "-m", "runner", scenario, "--out", os.path.join(folder, "out"), "--quiet",
                           "--no-report", "--no-trace", "--settle", "0"], cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True)

def freed(pid):
    until = time.monotonic() + 1.0
    while os.path.exists(f"/proc/{pid}") and time.monotonic() < until:
        time.sleep(0.005)
    return not os.path.exists(f"/proc/{pid}")

def newcomer(pid):  # a group leader given `pid`: the next number this namespace hands out
    with open("/proc/sys/kernel/ns_last_pid", "w") as f:
        f.write(str(pid - 1))
    return subprocess.Popen(["sleep", "60"], start_new_session=True)

def named(comm):
    for entry in os.listdir("/proc"):
        try:
            if entry.isdigit() and open(f"/proc/{entry}/comm").read().strip() == comm:
                return int(entry)
        except OSError:
            pass
    raise SystemExit(f"no {comm}")

until = time.monotonic() + 20
while not os.path.exists(f"{folder}/command.pid") and time.monotonic() < until:
    time.sleep(0.01)
given = {}
command = int(open(f"{folder}/command.pid").read())  # the background command, which ends at once
if freed(command):
    given["command"] = newcomer(command)
worker = named("victim")  # a worker killed mid-cell; the keeper keeps the cell going
os.kill(worker, signal.SIGKILL)
if freed(worker):
    given["worker"] = newcomer(worker)
runner.communicate(timeout=60)
for what, process in given.items():
    print(what, process.pid, process.poll())
    process.kill()
print("runner", runner.returncode)
"""


def test_the_group_of_a_worker_or_command_that_ended_early_is_never_a_strangers_it_was_given_to(tmp_path):
    """A background command that ended at once (reaped by the run's next look) and a worker killed mid-cell (reaped by
    the zygote) left their PIDs free; the SIGKILL of their groups at the cell's end went to whoever had them since."""
    lines = [line.split() for line in _in_new_pid_namespace(_RUN_WITH_ONE_ENDING_EARLY, str(tmp_path)).splitlines()]
    assert lines[-1] == ["runner", "4"], lines  # the cell is an error: a worker was killed, a command ended before it
    killed = [what for what, _, code in lines[:-1] if code != "None"]
    assert killed == [], f"the process given the PID of the {killed} was killed at the cell's end: {lines}"


_GUARD_AFTER_REUSE = """\
import io, os, subprocess, time
from runner.run import guard
leader = subprocess.Popen(["sleep", "60"], start_new_session=True)
left = guard.follow(io.StringIO(f"+{leader.pid}\\n"))  # told, as the runner tells it of each group it starts
time.sleep(0.05)  # start times count clock ticks (10 ms); a PID comes round again after pid_max others, never this fast
leader.kill()
leader.wait()  # reaped (by the zygote, say) before the runner could say -PID, and then the runner died
with open("/proc/sys/kernel/ns_last_pid", "w") as f:
    f.write(str(leader.pid - 1))
newcomer = subprocess.Popen(["sleep", "60"], start_new_session=True)
guard.clean(left)
time.sleep(0.1)
print(leader.pid, newcomer.pid, newcomer.poll())
newcomer.kill()
"""


def test_the_guard_leaves_a_group_alone_whose_number_another_process_was_given():
    leader, newcomer, code = _in_new_pid_namespace(_GUARD_AFTER_REUSE).split()
    assert leader == newcomer, "the namespace handed the number out again"
    assert code == "None", "the guard killed the group of the process given its dead leader's PID"
