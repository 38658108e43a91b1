"""How soon a thread rule reaches a program's thread, and what following a program costs the runner: events against listing.

    python bench/rules.py [--rounds 30] [--seconds 3] [--quick]

The subject is tests/programs/rtprog.c with `--rename`: it creates `ctl_loop` as `tmp_name`,
renames it 20 ms later, and then, from inside that thread, polls its own policy every 20 us
and prints how long after its renaming it found itself SCHED_FIFO.  The runner's monitor
(runner/run/external.py) follows it with a rule `ctl_* -> fifo:10`, once with the kernel's
process events and once by listing /proc every 2 ms, alternating, `--rounds` times each.
Printed per mode: the delay the runner records (`rule_after_ns`) and the delay the thread
itself saw (median and max), so a recorded figure that hides part of the wait shows.

Then the monitor's own cost: one program with five threads followed for `--seconds` in each
mode, the runner process's CPU time (user + system) as a share of one CPU.
Needs the right to use SCHED_FIFO, gcc, and the connector for the events mode.  `--quick`
(3 rounds, 0.5 s, for CI) checks that it runs and prints its figures.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Optional

from runner.run import kernel
from runner.run.external import Monitor, OpenEvents, ProgramRun
from runner.run.procevents import ProcEvents
from runner.scenario.model import ProgramSpec

SOURCE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests", "programs", "rtprog.c")
SEEN = re.compile(r"policy changed (\d+) us after its renaming")


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


class _NoGuard:
    def watch(self, pid: int) -> None:
        pass

    def forget(self, pid: int) -> None:
        pass

    def watch_cgroup(self, path: str) -> None:
        pass

    def forget_cgroup(self, path: str) -> None:
        pass


def _listing_only(pids: frozenset[int]) -> tuple[Optional[ProcEvents], str]:
    return None, "listing, for the bench"


def _printed(folder: str) -> Optional[re.Match[str]]:
    with open(os.path.join(folder, "bench.stdout")) as handle:
        return SEEN.search(handle.read())


def _follow(
    binary: str, folder: str, opener: OpenEvents, args: list[str], rules: list[dict[str, str]], seconds: float
) -> tuple[ProgramRun, Monitor, float]:
    """Run the program under the monitor for `seconds` (or until it prints its delay); the process CPU seconds it took."""
    spec = ProgramSpec.parse({"name": "bench", "command": [binary, *args], "threads": rules, "grace": "100ms"})
    run = ProgramRun(spec, folder, kernel.current_settings(), kernel.online_cpus())
    run.launch(_NoGuard())
    monitor = Monitor([run], opener)
    cpu = 0.0
    try:
        monitor.listen()
        run.release()
        monitor.window_start = time.monotonic_ns()
        before = _cpu_s()
        monitor.start()
        until = time.monotonic() + seconds
        while time.monotonic() < until and not (rules and _printed(folder)):
            time.sleep(0.01)
        cpu = _cpu_s() - before
    finally:
        monitor.stop()
        run.stop(_NoGuard())
    return run, monitor, cpu


def _delays(binary: str, folder: str, opener: OpenEvents) -> tuple[Optional[int], Optional[int], str]:
    """(recorded rule_after_ns, the delay the thread saw in ns, how its threads were found)."""
    run, monitor, _ = _follow(binary, folder, opener, ["--rename"], [{"match": "ctl_*", "sched": "fifo:10"}], 2.0)
    raw = run.raw(monitor.window_start, time.monotonic_ns())
    ctl = next((t for t in raw.threads if t.comm == "ctl_loop"), None)
    recorded = ctl.rule_ns - ctl.named_ns if ctl is not None and ctl.rule_ns is not None else None
    seen = _printed(folder)
    return recorded, int(seen.group(1)) * 1000 if seen else None, raw.seen_by


def _us(values: list[int]) -> str:
    return f"{statistics.median(values) / 1000:.0f} / {max(values) / 1000:.0f}" if values else "-"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.rounds, args.seconds = 3, 0.5
    folder = tempfile.mkdtemp(prefix="rules-bench-")
    binary = os.path.join(folder, "rtprog-bench")
    subprocess.run(["gcc", "-O2", "-pthread", "-o", binary, SOURCE], check=True)
    modes: dict[str, OpenEvents] = {"events": ProcEvents.open, "listing": _listing_only}
    recorded: dict[str, list[int]] = {m: [] for m in modes}
    seen: dict[str, list[int]] = {m: [] for m in modes}
    for _ in range(args.rounds):
        for mode, opener in modes.items():
            got, saw, by = _delays(binary, folder, opener)
            if by != mode:
                print(f"{mode}: the monitor found the threads by {by or 'nothing'}; no process events here?", file=sys.stderr)
                return 1
            if got is None or saw is None:
                print(f"{mode}: the rule never reached ctl_loop", file=sys.stderr)
                return 1
            recorded[mode].append(got)
            seen[mode].append(saw)
    print(f"rule delay over {args.rounds} rounds, median / max in us (ctl_loop renamed 20 ms after its creation):")
    print("| threads found by | recorded rule_after_ns | the thread saw its new policy after |")
    print("|---|---|---|")
    for mode in modes:
        print(f"| {mode} | {_us(recorded[mode])} | {_us(seen[mode])} |")
    print(f"\nthe monitor's cost, following one program of 5 threads for {args.seconds:g} s:")
    print("| threads found by | runner CPU, % of one CPU |")
    print("|---|---|")
    for mode, opener in modes.items():
        _, _, cpu = _follow(binary, folder, opener, [], [], args.seconds)
        print(f"| {mode} | {100 * cpu / args.seconds:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
