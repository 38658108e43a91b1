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
