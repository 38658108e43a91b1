"""Helpers for tests that run scenarios for real: start the runner, find its live workers, read results."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Any, Optional

import pytest

from runner.run.kernel import find_pids, thread_rows


def can_use_rt() -> bool:
    """Whether this process may use SCHED_FIFO: tried on the kernel, and put back."""
    try:
        param = os.sched_getparam(0)
        policy = os.sched_getscheduler(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, policy, param)
        return True
    except OSError:
        return False


# The skips of tests that need a right, declared once so every reason in the `-ra` summary names the right
# and how one has it (an ordinary user's README test command passes, skipping these; CI refuses to, conftest.py).
RT_REASON = "needs the right to use SCHED_FIFO (root, CAP_SYS_NICE or RLIMIT_RTPRIO above 0)"
needs_rt = pytest.mark.skipif(not can_use_rt(), reason=RT_REASON)
TRACING_REASON = "tracing needs root (tracefs is root's)"
needs_tracing = pytest.mark.skipif(os.geteuid() != 0, reason=TRACING_REASON)


def unprivileged_prefix() -> tuple[tuple[str, ...], str]:
    """The command prefix that drops this process's RT rights, and who that leaves: always the same way down, whatever
    the machine: root stripped of every capability (securebits), or, when the tests do not run as root (their RT
    rights then come from RLIMIT_RTPRIO), this user with RLIMIT_RTPRIO lowered to 0, soft and hard.

    Not `nobody`: whether nobody can reach the interpreter and the test's folder depends on where the
    virtual environment and the temporary folder happen to be, and made the outcome machine-dependent.
    """
    if os.geteuid() != 0:
        return ("prlimit", "--rtprio=0:0", "--nice=0:0"), f"uid {os.geteuid()} with RLIMIT_RTPRIO 0"
    return (
        "setpriv",
        "--securebits=+noroot,+noroot_locked,+no_setuid_fixup,+no_setuid_fixup_locked",
        "--bounding-set=-all",
        "--inh-caps=-all",
        "--ambient-caps=-all",
    ), "root without capabilities"


def env() -> dict[str, str]:
    """The runner's environment: this one (the same interpreter finds the same installed package), minus CI's step summary."""
    out = dict(os.environ)
    out.pop("GITHUB_STEP_SUMMARY", None)
    return out


def start_runner(*args: str, cwd: str, prefix: tuple[str, ...] = ()) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [*prefix, sys.executable, "-m", "runner", *args],
        cwd=cwd,
        env=env(),
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def wait_for_threads(comm: str, count: int, timeout: float = 15.0) -> int:
    """PID of the live process named `comm` once it has `count` threads."""
    until = time.monotonic() + timeout
    while time.monotonic() < until:
        for pid in find_pids(comm):
            if len(thread_rows(pid)) == count:
                return pid
        time.sleep(0.02)
    raise AssertionError(f"no process {comm!r} with {count} threads within {timeout}s")


def ps_table(pid: int) -> str:
    return subprocess.run(["ps", "-L", "-o", "tid,comm,rtprio,cls,psr", "-p", str(pid)], capture_output=True, text=True, check=True).stdout


@dataclass
class Finished:
    code: int
    out: str
    err: str
    results: Optional[dict[str, Any]]


def finish(proc: subprocess.Popen[str], out_dir: str, timeout: float = 60.0) -> Finished:
    out, err = proc.communicate(timeout=timeout)
    path = os.path.join(out_dir, "results.json")
    results = json.load(open(path)) if os.path.exists(path) else None
    return Finished(proc.returncode, out, err, results)


def thread(results: dict[str, Any], name: str, cell: int = 0, index: Optional[int] = None) -> dict[str, Any]:
    threads = [t for t in results["cells"][cell]["threads"] if t["name"] == name and (index is None or t["index"] == index)]
    assert threads, f"no thread {name!r}"
    return threads[0]


# README's exit-code table, written out here so the tests check the tool against the documentation,
# not against its own mapping: the most severe cell decides.
README_EXIT = {"interrupted": 130, "error": 4, "failed": 1, "degraded": 0, "passed": 0}
SEVERITY = ["error", "interrupted", "failed", "degraded", "passed"]


def documented_exit(results: dict[str, Any]) -> int:
    """The exit code README documents for these cells."""
    statuses = [c["status"] for c in results["cells"]] or ["passed"]
    return README_EXIT[min(statuses, key=SEVERITY.index)]


def failed_metrics(results: dict[str, Any]) -> set[str]:
    """The metrics of every expectation the scenario states that failed, in every cell.

    The implicit keeping-up verdict (no line in the file: every release served) is left out, as
    `ran_cleanly` leaves it: a VM stall longer than a 1 ms period makes a thread miss a release,
    which the runner rightly fails, and which is not what the tests asking this check.  Their
    exit-code checks still see it.
    """
    return {v["metric"] for c in results["cells"] for v in c["expectations"] if not v["passed"] and v["line"] is not None}


def ran_cleanly(code: int, results: dict[str, Any]) -> bool:
    """Every cell ran to its end without an error, and nothing failed but, at most, the implicit keeping-up verdict.

    For tests whose subject is not timing: a host that stalls the VM for longer than a short period
    makes a thread miss a release, which the runner rightly reports (exit 1), and which is not what
    such a test checks.  Any other failure, any error, and any other exit code still fail it.
    """
    implicit = {"missed_releases", "overruns"}
    failed = [v for c in results["cells"] for v in c["expectations"] if not v["passed"]]
    clean = all(v["line"] is None and v["metric"] in implicit for v in failed)
    return code == documented_exit(results) and clean and all(c["status"] in ("passed", "failed") for c in results["cells"])
