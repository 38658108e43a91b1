"""A scenario process: the child the runner starts for each process instance (and for hogs).

Run as `python -m runner.run.worker`; reads its spec from stdin, reports over stdout
with one JSON line per step, and records every measurement in the shared sample
buffer through the native core.  It imports only the standard library and the
native core, so it starts fast, and its measured threads never hold the GIL.

Steps, in the order the ros2-realtime-examples take them:
  1. name the process; reset settings if asked (reset-on-fork); default stack size;
  2. main thread settings if applied before_threads;
  3. create the threads in declared order (they inherit per the kernel's rules and
     apply their own settings); threads declared `spawned` are only prepared: a spawn
     event of another thread creates them mid-run;
  4. main thread settings if applied after_threads;
  5. lock memory and preallocate, once every thread exists;
  6. report ready (TIDs, errors); every thread waits at the start gate in the shared
     buffer, which the runner opens with START and END (a hog's START is now) or cancels;
  7. run: every thread starts at START (CLOCK_MONOTONIC) and stops at END; each notes
     when it passed the gate, so the runner sees one released after START.
"""

from __future__ import annotations

import json
import mmap
import os
import signal
import sys
from typing import Any

from runner.run import _probe

_RT_OR_IDLE = (os.SCHED_FIFO, os.SCHED_RR, os.SCHED_IDLE)


def _reset_on_fork() -> dict[str, int]:
    """What SCHED_RESET_ON_FORK would have given this process: no RT policy, no negative nice."""
    policy = os.sched_getscheduler(0) & ~0x40000000
    nice = os.getpriority(os.PRIO_PROCESS, 0)
    errs = _probe.apply(os.SCHED_OTHER if policy in _RT_OR_IDLE else None, 0, 0 if nice < 0 else None, None)
    return {"sched": errs[0], "nice": errs[1]}


def _sched_args(entry: dict[str, Any]) -> tuple[Any, Any, Any, Any, Any]:
    """(policy, priority, nice, cpus, extra): extra carries SCHED_DEADLINE's parameters and uclamp, else None."""
    sched = entry.get("sched")
    policy, priority, nice, extra = sched if sched else (None, None, None, None)
    return policy, priority, nice, entry.get("cpus"), tuple(extra) if extra else None


def _program(work: list[Any]) -> tuple[Any, ...]:
    """A work tuple from JSON: lists back to the tuples the native core parses (a program nests them)."""

    def tup(value: Any) -> Any:
        return tuple(tup(v) for v in value) if isinstance(value, list) else value

    return tup(work)


def _send(message: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()


def run(spec: dict[str, Any]) -> int:
    """Set up, report ready, run; return the exit code."""
    _probe.set_name(spec["comm"])
    errors: dict[str, Any] = {}
    if spec.get("reset_on_fork"):
        errors["reset_on_fork"] = _reset_on_fork()
    memory = spec.get("memory", {})
    if memory.get("stack_size"):
        _probe.set_default_stacksize(memory["stack_size"])

    threads = spec["threads"]
    nslots = 1 + len(threads)
    fd = int(spec["samples_fd"])  # the runner's memfd, inherited
    try:
        buf = mmap.mmap(fd, 0)
    finally:
        os.close(fd)
    resources = None
    if spec.get("resources_fd") is not None:  # the scenario's shared mutexes, conditions, barriers and queues
        rfd = int(spec["resources_fd"])
        try:
            resources = mmap.mmap(rfd, 0)
        finally:
            os.close(rfd)
    group = _probe.Group(
        buf,
        nslots,
        spec["capacity"],
        spec["all_cpus"],
        spec.get("histograms", True),
        spec.get("events", 0),
        spec.get("phases", 0),
        resources,
        spec.get("locks", 0),
    )
    main = spec["main"]
    group.adopt(0, main["name"], _program(main["work"]))

    main_errs = (0, 0, 0)
    if main["apply"] == "before_threads":
        main_errs = _probe.apply(*_sched_args(main))
    for index, thread in enumerate(threads, start=1):
        policy, priority, nice, cpus, extra = _sched_args(thread)
        group.spawn(
            index,
            thread["name"],
            _program(thread["work"]),
            policy,
            priority,
            nice,
            cpus,
            thread.get("explicit", False),
            extra,
            thread.get("spawned", False),
            thread.get("after", -1),
        )
    if main["apply"] == "after_threads":
        main_errs = _probe.apply(*_sched_args(main))
    errors["main"] = dict(zip(("sched", "nice", "cpus"), main_errs))
    if not group.wait_ready(10.0):
        _send({"failed": "threads did not reach the start gate within 10s"})
        return 4

    if memory.get("lock"):
        try:
            _probe.lock_memory()
            if memory.get("prealloc"):
                _probe.preallocate(memory["prealloc"])
        except OSError as exc:
            errors["memory"] = {"errno": exc.errno or 0, "message": str(exc)}

    tids = [group.errors(i)[0] for i in range(nslots)]
    errors["threads"] = [list(group.errors(i)[1:]) for i in range(nslots)]
    _send({"ready": True, "pid": os.getpid(), "tids": tids, "errors": errors})

    if not group.run_main(0):
        return 0  # the runner cancelled the gate: the cell never started, and no thread worked
    group.join()
    _send({"done": True, "stopped": _probe.stopped()})
    return 0


def main() -> int:
    _probe.set_pdeathsig(signal.SIGKILL)  # no worker outlives the runner
    if os.environ.get("RUNNER_PARENT_PID") not in (None, str(os.getppid())):
        return 3  # the runner died before the line above took effect
    _probe.install_stop_handler()
    line = sys.stdin.readline()
    if not line:
        return 2
    return run(json.loads(line))


if __name__ == "__main__":
    raise SystemExit(main())
