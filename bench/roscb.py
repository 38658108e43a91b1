"""Benchmark: what the libtracetools interposer (runner/run/roscb.c) costs a ROS 2 node.

1. ns per callback (callback_start + callback_end, an empty callback): the stand-in node's `--bench N` loop
   (tests/programs/rosnode.c, Jazzy's header, against the fake libtracetools of tests/rosfake.py) bare, with the
   library preloaded but no capture file (it only forwards), and recording into a capture file.  The difference
   is the interposer's cost per callback: two getrusage(RUSAGE_THREAD), two clock reads, the ring's store.
2. The wake-up latency of a 1 ms timer (tests/programs/roscb_caller.c `timer N`: clock_nanosleep to the next
   release, the executor's calls, a callback that publishes) under SCHED_FIFO 80, without and with the library
   recording: p50/p99/max.  The interposer runs after the wake-up, so the latency should not move; a change
   would be the library's cost reaching the next release.  Without CAP_SYS_NICE it runs under SCHED_OTHER and
   says so.

    flock /tmp/runner-rt.lock python bench/roscb.py [--pairs 2000000] [--releases 3000] [--runs 5] [--quick]

Take the shared lock: part 2 runs a real-time thread.  `--quick` (CI) checks that the bench runs and prints
its figures, and exits 0 whatever they are.  The machine is noisy: read the medians.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "tests"))

from rosfake import build_into  # noqa: E402  (tests/rosfake.py: the fake libtracetools and the stand-in node)

from runner.run import roscb  # noqa: E402

PROGRAMS = os.path.join(REPO, "tests", "programs")


def _fifo() -> None:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(80))


def _can_fifo() -> bool:
    try:
        subprocess.run(["true"], preexec_fn=_fifo, check=True)
        return True
    except (OSError, subprocess.SubprocessError):
        return False


def _with_capture(run, env: dict[str, str]):
    capture = roscb.Capture.create("bench")
    try:
        out = run(capture.environment(env))
        read = capture.read()
        if read.error or not read.processes:
            raise SystemExit(f"the interposer recorded nothing: {read.error or 'no process reached a hook'}")
        return out
    finally:
        capture.close()


def per_callback(node: str, libdir: str, pairs: int, runs: int) -> dict[str, float]:
    """Median ns per callback_start/callback_end pair: bare, forwarding only, recording."""
    base = {"PATH": os.defpath, "LD_LIBRARY_PATH": libdir}

    def once(env: dict[str, str]) -> float:
        done = subprocess.run([node, "--bench", str(pairs)], env=env, capture_output=True, text=True, check=True)
        line = next(json.loads(x) for x in done.stdout.splitlines() if x.startswith("{"))
        return float(line["bench"]["ns_per_pair"])

    modes = {
        "bare": lambda: once(base),
        "forwarding only": lambda: once({**base, "LD_PRELOAD": roscb.LIBRARY}),
        "recording": lambda: _with_capture(once, base),
    }
    return {name: statistics.median(run() for _ in range(runs)) for name, run in modes.items()}


def timer_latency(caller: str, releases: int, fifo: bool) -> dict[str, tuple[int, int, int]]:
    """p50/p99/max wake-up latency (ns) of the 1 ms timer, without and with the library recording."""

    def once(env: dict[str, str]) -> tuple[int, int, int]:
        done = subprocess.run([caller, "timer", str(releases)], env=env, capture_output=True, text=True, check=True,
                              preexec_fn=_fifo if fifo else None)  # fmt: skip
        words = next(line.split() for line in done.stdout.splitlines() if line.startswith("latency_ns"))
        return int(words[1]), int(words[2]), int(words[3])

    base = {"PATH": os.defpath}
    return {"without": once(base), "with the interposer": _with_capture(once, base)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pairs", type=int, default=2_000_000)
    parser.add_argument("--releases", type=int, default=3000)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="a short run for CI: checks that it runs, exits 0")
    args = parser.parse_args()
    if args.quick:
        args.pairs, args.releases, args.runs = 100_000, 200, 1
    if not roscb.LIBRARY:
        raise SystemExit("the interposer was not built: pip install -e .")
    with tempfile.TemporaryDirectory(prefix="roscb-bench-") as root:
        ros = build_into(os.path.join(root, "ros"))
        jazzy = ros.distros["jazzy"]
        caller = os.path.join(root, "caller")
        subprocess.run(
            ["gcc", "-O2", "-pthread", "-DPUBLISH3", "-o", caller, os.path.join(PROGRAMS, "roscb_caller.c"),
             "-Wl,--no-as-needed", f"-L{jazzy.libdir}", "-ltracetools", f"-Wl,-rpath,{jazzy.libdir}"],
            check=True,
        )  # fmt: skip
        costs = per_callback(jazzy.node, jazzy.libdir, args.pairs, args.runs)
        print(f"ns per callback (start + end, empty), median of {args.runs} x {args.pairs:,} pairs:")
        for name, ns in costs.items():
            print(f"  {name:16} {ns:8.1f} ns")
        print(f"  interposer's cost: {costs['recording'] - costs['bare']:.1f} ns per callback")
        fifo = _can_fifo()
        policy = "SCHED_FIFO 80" if fifo else "SCHED_OTHER (no CAP_SYS_NICE: not the real-time figure)"
        print(f"wake-up latency of a 1 ms timer, {args.releases:,} releases, {policy}:")
        for name, (p50, p99, worst) in timer_latency(caller, args.releases, fifo).items():
            print(f"  {name:20} p50 {p50 / 1e3:7.1f} us  p99 {p99 / 1e3:7.1f} us  max {worst / 1e3:7.1f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
