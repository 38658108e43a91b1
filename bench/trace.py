"""What the scheduler trace costs at a high event rate: events per second, the reader's CPU share, losses, memory.

    python bench/trace.py [--seconds 5] [--buffer-kb 4096] [--rounds 8] [--quick]

Two processes ping-pong a byte through two pipes, one pinned to each of the first two
CPUs (SCHED_OTHER), so every round trip is two wake-ups and four switches: the
heaviest scheduler load two tasks make.  runner/run/tracing.py traces them; prints
events/s, the native reader's CPU time as a share of one CPU, events lost, and this
process's peak RSS before and after (the reader must not grow with the run).
Targets: 0 lost with the default 4 MiB per CPU, reader under 5% of a CPU.

Then what tracing costs the traced tasks themselves, in the kernel: the same ping-pong with
both tasks on one CPU (every round trip two wake-ups and two switches, nothing else running
between them), timed untraced and traced, alternating; the difference per round trip over
the events the trace recorded per round trip is the kernel's cost of writing one event.  It
is paid on the wake-up path of a traced thread (sched_waking, then the sched_switch onto its
CPU), which is what moves the wake-up latency of a traced probe (README, Fidelity).
Last, where a traced probe's wake-up latency goes, with no runner involved: the runner's
native periodic loop alone (FIFO 80, 1 ms, memory locked: `bench/fidelity.py --native-loop`)
under one busy loop per CPU, in rounds (each in a shuffled order) of untraced, a tracefs instance of
its own with only sched_switch (pid-filtered to the loop, as the runner's is), and with
sched_switch and sched_waking (the events the runner's trace puts on a wake-up's path).
Prints each one's wake-up latency (p50 and p99 of all rounds pooled, and the median of the
rounds' own) and the shift over untraced.
Needs root (tracefs).  `--quick` (0.5 s, for CI) checks that it runs and prints its figures.
"""

from __future__ import annotations

import argparse
import os
import resource
import signal
import statistics
import subprocess
import sys
import time

from fidelity import busy_loops, in_turn, percentile, run_native_loop  # this folder: python bench/trace.py puts it first on sys.path

from runner.run import tracing
from runner.run.guard import remove_instance

PING_PONG = r"""
import os
open('/proc/self/comm', 'w').write('trace-bench')
r1, w1 = os.pipe()
r2, w2 = os.pipe()
cpus = sorted(os.sched_getaffinity(0))
if os.fork() == 0:
    os.sched_setaffinity(0, {cpus[0]})
    while True:
        os.read(r1, 1)
        os.write(w2, b'x')
os.sched_setaffinity(0, {cpus[-1]})
while True:
    os.write(w1, b'x')
    os.read(r2, 1)
"""

SAME_CPU = r"""
import os, sys, time
open('/proc/self/comm', 'w').write('trace-cost')
n = int(sys.argv[1])
r1, w1 = os.pipe()
r2, w2 = os.pipe()
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
if os.fork() == 0:
    for _ in range(n + 1):
        os.read(r1, 1)
        os.write(w2, b'x')
    os._exit(0)
os.write(w1, b'x')
os.read(r2, 1)  # the child runs: both are in the trace's pid list from here on
sys.stdout.write('ready\n')
sys.stdout.flush()
sys.stdin.readline()
t0 = time.perf_counter_ns()
for _ in range(n):
    os.write(w1, b'x')
    os.read(r2, 1)
sys.stdout.write(f'{time.perf_counter_ns() - t0}\n')
"""


def round_trip(n: int, traced: bool, buffer_kb: int) -> tuple[float, float]:
    """(ns per round trip, events the trace recorded per round trip; 0 untraced) of the one-CPU ping-pong."""
    load = subprocess.Popen([sys.executable, "-c", SAME_CPU, str(n)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert load.stdin is not None and load.stdout is not None
    tracer = None
    try:
        load.stdout.readline()
        if traced:
            with open(f"/proc/{load.pid}/task/{load.pid}/children") as handle:
                pids = [load.pid, *(int(p) for p in handle.read().split())]
            opened = tracing.open_trace(pids, buffer_kb=buffer_kb)
            if isinstance(opened, tracing.TraceUnavailable):
                raise SystemExit(f"trace unavailable: {opened.reason}")
            tracer = opened
        load.stdin.write("go\n")
        load.stdin.flush()
        elapsed = int(load.stdout.readline())
        events = tracer.stop().events if tracer is not None else 0
        tracer = None
    finally:
        if tracer is not None:
            tracer.close()
        load.kill()
        load.wait()
    return elapsed / n, events / n


def event_cost(rounds: int, n: int, buffer_kb: int) -> None:
    """Print the one-CPU ping-pong's round trip untraced and traced (medians over alternating rounds) and the cost per event."""
    plain, traced, per_trip = [], [], []
    for _ in range(rounds):
        plain.append(round_trip(n, False, buffer_kb)[0])
        ns, events = round_trip(n, True, buffer_kb)
        traced.append(ns)
        per_trip.append(events)
    a, b, e = statistics.median(plain), statistics.median(traced), statistics.median(per_trip)
    print(f"one-CPU round trip: {a / 1000:.2f} us untraced, {b / 1000:.2f} us traced ({e:.1f} events each); ", end="")
    print(f"{(b - a) / e:.0f} ns per event written" if e else "no events recorded")


WAKE_PATH = {"untraced": (), "sched_switch": ("sched_switch",), "sched_switch + sched_waking": ("sched_switch", "sched_waking")}
BENCH_INSTANCE = "runner-bench-wake-path"


def loop_under(events: tuple[str, ...], seconds: float) -> list[float]:
    """The native loop's latencies (us) while a private instance traces `events` of it (none: untraced)."""
    root = tracing.find_tracefs()
    if isinstance(root, tracing.TraceUnavailable):
        raise SystemExit(f"trace unavailable: {root.reason}")
    path = os.path.join(root.path, "instances", BENCH_INSTANCE)
    if os.path.isdir(path):  # left by a bench that was killed
        remove_instance(path)
    if events:
        os.mkdir(path)
    try:
        if events:
            for name, value in (("trace_clock", "mono"), ("options/event-fork", "1"), ("set_event_pid", str(os.getpid()))):
                with open(os.path.join(path, name), "w") as handle:
                    handle.write(value)
            for event in events:
                with open(os.path.join(path, "events", "sched", event, "enable"), "w") as handle:
                    handle.write("1")
        return run_native_loop(seconds)  # a child of this process: in the pid filter
    finally:
        if events:
            remove_instance(path)


def wake_path(rounds: int, seconds: float) -> None:
    """Print the native loop's latency untraced and under each set of events, the rounds turning between them."""
    got: dict[str, list[list[float]]] = {name: [] for name in WAKE_PATH}
    with busy_loops():
        for i in range(rounds):
            for name in in_turn(tuple(WAKE_PATH), i):
                got[name].append(loop_under(WAKE_PATH[name], seconds))
    print(f"the native loop's wake-up latency under {os.cpu_count()} busy loops, {rounds} x {seconds:g} s, in turn (us):")
    base: dict[str, float] = {}
    for name, per_round in got.items():
        pooled = [v for r in per_round for v in r]
        figs = {
            "p50": percentile(pooled, 0.5),
            "p99": percentile(pooled, 0.99),
            "rounds' p50": statistics.median(percentile(r, 0.5) for r in per_round),
            "rounds' p99": statistics.median(percentile(r, 0.99) for r in per_round),
        }
        base = base or figs
        shown = ", ".join(f"{k} {v:.1f} ({v - base[k]:+.1f})" for k, v in figs.items())
        print(f"  {name:<28} {shown}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--buffer-kb", type=int, default=4096)
    parser.add_argument("--rounds", type=int, default=8, help="rounds of the wake-path measurement (2 s each per configuration)")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    seconds = 0.5 if args.quick else args.seconds
    load = subprocess.Popen([sys.executable, "-c", PING_PONG], start_new_session=True)
    try:
        time.sleep(0.3)
        with open(f"/proc/{load.pid}/task/{load.pid}/children") as handle:
            pids = [load.pid, *(int(p) for p in handle.read().split())]
        rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        tracer = tracing.open_trace(pids, buffer_kb=args.buffer_kb)
        if isinstance(tracer, tracing.TraceUnavailable):
            print(f"trace unavailable: {tracer.reason}")
            return 1
        time.sleep(seconds)
        data = tracer.stop()
    finally:
        os.killpg(load.pid, signal.SIGKILL)
        load.wait()
    rss_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    span = data.duration_ns / 1e9
    wakeups = sum(t.wakeups for t in data.threads.values())
    print(f"traced {span:.2f} s: {data.events:,} events = {data.events / span:,.0f} events/s, {wakeups:,} wake-ups measured")
    print(f"reader CPU {data.reader_cpu_ns / 1e6:.1f} ms = {100 * data.reader_cpu_ns / data.duration_ns:.2f}% of one CPU")
    print(f"lost {data.lost:,}, out of order {data.out_of_order}, unseen switch-ins {data.unseen_switch_ins:,}")
    print(f"peak RSS {rss_before / 1024:.1f} MiB before, {rss_after / 1024:.1f} MiB after")
    event_cost(1 if args.quick else 5, 2_000 if args.quick else 100_000, args.buffer_kb)
    wake_path(1 if args.quick else args.rounds, seconds if args.quick else 2.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
