"""How far the runner scales on this machine, and what gives first: threads, processes, wake-ups, the trace.

    python bench/scale.py [--sizes 16x64,32x64,64x64,128x64] [--seconds 2] [--quick]

Each size PxT is one cell of P processes of T periodic threads (10 ms period, no burn,
SCHED_OTHER): P*T*100 wake-ups a second for the machine to serve.  Printed per size: the
runner's wall time for the cell (plots off), the peak resident memory of the runner and
what it waited for (GNU time's view: the largest of them), releases missed, callbacks
that overran, and the scheduler trace's events kept, lost (its per-CPU buffers full) and
untracked (threads beyond the reader's table).  `--quick` (2x8, 1 s, for CI) checks that
it runs and prints its figures.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

HEADER = (
    "| processes x threads | wake-ups/s asked | cell wall s | peak RSS MiB | missed releases | overran | trace kept / lost / untracked |"
)


def _scenario(processes: int, threads: int, seconds: float) -> str:
    lines = ["name: scale", f"duration: {seconds:g}s", "processes:"]
    for p in range(processes):
        lines += [
            f"  - name: proc{p}",
            "    main: {work: sleep}",
            "    threads:",
            f"      - {{name: cb, count: {threads}, work: {{kind: periodic, period: 10ms}}}}",
        ]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="16x64,32x64,64x64,128x64")
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.seconds = "2x8", 1.0
    work = tempfile.mkdtemp(prefix="scale-bench-")
    runner = shutil.which("runner") or "runner"
    print(HEADER)
    print("|---|---|---|---|---|---|---|")
    try:
        for size in args.sizes.split(","):
            processes, threads = (int(n) for n in size.split("x"))
            path = os.path.join(work, f"{size}.yaml")
            with open(path, "w") as handle:
                handle.write(_scenario(processes, threads, args.seconds))
            out = os.path.join(work, f"out-{size}")
            began = time.monotonic()
            done = subprocess.run([runner, path, "--out", out, "--settle", "0", "--no-plots", "--quiet"], capture_output=True, text=True)
            wall = time.monotonic() - began
            peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
            try:
                with open(os.path.join(out, "results.json")) as handle:
                    cell = json.load(handle)["cells"][0]
            except (OSError, ValueError, IndexError):
                print(f"| {size} | - | {wall:.1f} | {peak:.0f} | no results (exit {done.returncode}): {done.stderr.strip()[-200:]} | | |")
                continue
            periodic = [t for t in cell["threads"] if t["periodic"]]
            missed = sum(t["figures"]["missed_releases"] for t in periodic)
            releases = sum(t["figures"]["releases"] for t in periodic)
            overran = sum(t["figures"]["overruns"] for t in periodic)
            trace = cell.get("trace") or {}
            kept = "off"
            if trace.get("enabled"):
                kept = f"{trace.get('events', 0):,} / {trace.get('lost', 0):,} / {trace.get('untracked', 0):,}"
            print(
                f"| {size} | {processes * threads * 100:,} | {wall:.1f} | {peak:.0f} | {missed:,} of {releases:,} | {overran:,} | {kept} |"
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
