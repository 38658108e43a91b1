"""Benchmark: how long `runner --version` and `runner validate scenarios/fifo80.yaml` take (target: under 100 ms each), and `runner ps`.

Runs each command N times as a user would (the installed `runner` console script
beside this interpreter, a fresh process each time) and prints the median and the
fastest run, beside `python -c pass` (the interpreter's own start, which no change
to the runner can remove).  The machine is noisy: read the medians, and compare
them with the interpreter's.  Also lists the heaviest imports of the validate path
(`python -X importtime`), so a regression names its module.

    python bench/startup.py [--runs 21] [--quick]

`--quick` (5 runs, for CI) checks that the bench runs and prints its figures, and
exits 0 whatever they are.  Uses the installed runner package.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET_S = 0.100


def runner_command() -> list[str]:
    """The console script installed beside this interpreter, else `python -m runner`."""
    script = os.path.join(os.path.dirname(sys.executable), "runner")
    if os.path.exists(script):
        return [script]
    found = shutil.which("runner")
    return [found] if found else [sys.executable, "-m", "runner"]


def timed(argv: list[str], runs: int) -> list[float]:
    out = []
    for _ in range(runs):
        began = time.perf_counter()
        done = subprocess.run(argv, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, check=False)
        out.append(time.perf_counter() - began)
        if done.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} exited {done.returncode}: {done.stderr.decode(errors='replace')}")
    return out


def heaviest_imports(code: str, count: int = 6) -> list[tuple[int, str]]:
    """The top-level imports of `code` by cumulative microseconds, heaviest first (`python -X importtime`)."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    rows = []
    for line in done.stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            name = parts[2]
            if len(name) - len(name.lstrip(" ")) <= 3:  # a direct import of `code`, not one nested in another
                rows.append((int(parts[1]), name.strip()))
    return sorted(rows, reverse=True)[:count]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=21)
    p.add_argument("--quick", action="store_true", help="5 runs; exit 0 whatever the times (CI)")
    ns = p.parse_args()
    runs = 5 if ns.quick else ns.runs
    runner = runner_command()
    cases = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "runner --version": runner + ["--version"],
        "runner validate scenarios/fifo80.yaml": runner + ["validate", "scenarios/fifo80.yaml"],
        "runner ps PID (this bench's process)": runner + ["ps", str(os.getpid())],
    }
    slow = False
    for name, argv in cases.items():
        times = timed(argv, runs)
        median = statistics.median(times)
        target = f" (target {TARGET_S * 1000:.0f} ms)" if name.startswith(("runner --version", "runner validate")) else ""
        slow |= bool(target) and median >= TARGET_S
        print(f"{name}: median {median * 1000:.0f} ms, fastest {min(times) * 1000:.0f} ms over {runs} runs{target}")
    heavy = heaviest_imports("import runner.cli, runner.scenario.loader, runner.scenario.listing")
    print("heaviest imports of the validate path: " + ", ".join(f"{name} {us / 1000:.0f} ms" for us, name in heavy))
    return 0 if ns.quick or not slow else 1


if __name__ == "__main__":
    raise SystemExit(main())
