"""What a cell costs beyond its own duration: start to first callback, end of the window to results saved, matrix wall time.

    python bench/overhead.py [--runs 5] [--quick] [--src DIR]

Three cases, each run as a user would (`python -m runner ... --quiet --no-report`):
  * `scenarios/fifo80.yaml` for 1 s, one cell (target: 50 ms each way);
  * 1,024 threads in 16 processes (100 ms period, SCHED_OTHER), one cell of 1 s (target: 300 ms each way);
  * `scenarios/policy_matrix.yaml`, 5 cells of 0.5 s with `--settle 0`, and one of its
    cells alone: each further cell's cost, (wall of 5 - wall of 1) / 4, against its 0.5 s
    (target: within 5%; the runner's own start and exit are in the one cell's wall).
The per-cell figures come from results.json (`cells[].overhead_ns`, measured by the runner
with CLOCK_MONOTONIC): `start_to_first_callback`, and `end_to_saved` (the end of the
measured window to the results file's write) plus `save` (that write).  Medians over the
runs, and the worst run.

`--src DIR` runs the runner of another source tree (its extension built in place), to
measure a before and an after on the same machine.  `--quick` (1 run, for CI) checks that
the bench runs and prints its figures, and exits 0 whatever they are.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def many_threads(processes: int, threads: int) -> str:
    lines = ["name: overhead", "duration: 1s", "processes:"]
    for p in range(processes):
        lines += [
            f"  - name: proc{p}",
            "    main: {work: sleep}",
            "    threads:",
            f"      - {{name: cb, count: {threads}, work: {{kind: periodic, period: 100ms}}}}",
        ]
    return "\n".join(lines) + "\n"


def run(src: str, scenario: str, out: str, *extra: str) -> tuple[float, dict]:
    """Run the runner; its wall time (s) and results."""
    env = dict(os.environ)
    if src:
        env["PYTHONPATH"] = src
    began = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "runner", scenario, "--out", out, "--quiet", "--no-report", *extra],
        cwd=out_parent(out),  # not the repository: `python -m runner` there would import its source tree, unbuilt
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.monotonic() - began
    if done.returncode not in (0, 1):
        raise SystemExit(f"runner {scenario} exited {done.returncode}: {done.stderr.strip()[-2000:]}")
    with open(os.path.join(out, "results.json")) as handle:
        return wall, json.load(handle)


def out_parent(out: str) -> str:
    return os.path.dirname(os.path.abspath(out))


def ms(ns: object) -> str:
    return "-" if not isinstance(ns, (int, float)) else f"{ns / 1e6:.0f}"


def cell_case(name: str, src: str, scenario: str, runs: int, work: str, target_ms: int, *extra: str) -> None:
    starts, ends, walls = [], [], []
    untimed = False  # a runner before overhead_ns.save: its write is not in the figure
    for n in range(runs):
        wall, doc = run(src, scenario, os.path.join(work, f"{name}-{n}"), *extra)
        cell = doc["cells"][0]
        over = cell.get("overhead_ns", {})
        starts.append(over.get("start_to_first_callback"))
        end, save = over.get("end_to_saved"), over.get("save")
        untimed = untimed or not isinstance(save, int)
        ends.append(end + save if isinstance(end, int) and isinstance(save, int) else end)
        walls.append(wall)
    written = f"{med(ends)} ({worst(ends)})" + (" without the write (this runner does not time it)" if untimed else "")
    print(f"| {name} | {med(starts)} ({worst(starts)}) | {written} | {statistics.median(walls):.2f} | {target_ms} |", flush=True)


def med(values: list) -> str:
    known = [v for v in values if isinstance(v, (int, float))]
    return ms(statistics.median(known)) if known else "-"


def worst(values: list) -> str:
    known = [v for v in values if isinstance(v, (int, float))]
    return ms(max(known)) if known else "-"


def matrix_case(src: str, runs: int, work: str) -> None:
    """The marginal cost of a cell in a matrix: (wall of 5 cells - wall of 1 cell) / 4, against the 0.5 s asked."""
    scenario = os.path.join(REPO, "scenarios", "policy_matrix.yaml")
    fives, ones, saves, own = [], [], [], []
    cells = 0
    for n in range(runs):
        wall, doc = run(src, scenario, os.path.join(work, f"matrix-{n}"), "--duration", "500ms", "--settle", "0")
        cells = len(doc["cells"])
        fives.append(wall)
        own += [own_cost(cell) for cell in doc["cells"][1:]]
        wall, _ = run(src, scenario, os.path.join(work, f"one-{n}"), "--duration", "500ms", "--cell", "policy=fifo,priority=10")
        ones.append(wall)
        saves.append(save_time(src, os.path.join(work, f"matrix-{n}", "results.json")))
    five, one = statistics.median(fives), statistics.median(ones)
    per_cell = (five - one) / (cells - 1)
    print(
        f"\nmatrix policy_matrix, {cells} cells x 0.5 s, --settle 0 (medians of {runs}): runner wall {five:.2f} s, one of its cells"
        f" alone {one:.2f} s; each further cell {per_cell * 1000:.0f} ms: {100 * (per_cell / 0.5 - 1):.1f}% over its 0.5 s"
        f" (target 5%). Writing its results.json once: {statistics.median(saves) * 1000:.1f} ms."
    )
    known = [v for v in own if v is not None]
    if known:  # the processes' start and exit as the runner times them: steadier than two walls' difference on a noisy VM
        cost = statistics.median(known)
        print(
            f"By the runner's own timeline, each further cell's start to its first callback and end to its results written:"
            f" {cost / 1e6:.1f} ms, {100 * cost / 500e6:.1f}% of its 0.5 s (median of {len(known)} cells; the moments between"
            " two cells, the terminal's line, are left out)."
        )


def own_cost(cell: dict) -> int | None:
    """A cell's cost beyond its window by its own overhead_ns: start to first callback, end to saved, the save; None if untimed."""
    over = cell.get("overhead_ns") or {}
    parts = [over.get("start_to_first_callback"), over.get("end_to_saved"), over.get("save")]
    return sum(parts) if all(isinstance(p, int) for p in parts) else None  # type: ignore[arg-type]


def save_time(src: str, path: str) -> float:
    """Seconds to write a results document once more, as the runner does after each cell."""
    code = (
        "import sys, time\nfrom runner.results.read import load\n"
        "d = load(sys.argv[1]); t = time.perf_counter(); d.save(sys.argv[1]); print(time.perf_counter() - t)"
    )
    env = {**os.environ, **({"PYTHONPATH": src} if src else {})}
    argv = [sys.executable, "-c", code, path]
    done = subprocess.run(argv, env=env, cwd=os.path.dirname(path), capture_output=True, text=True, check=True)
    return float(done.stdout)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="1 run of each case (CI)")
    parser.add_argument("--src", default="", help="a source tree whose runner to measure instead of the installed one")
    args = parser.parse_args()
    runs = 1 if args.quick else args.runs
    src = os.path.abspath(args.src) if args.src else ""
    work = tempfile.mkdtemp(prefix="overhead-")
    try:
        many = os.path.join(work, "many.yaml")
        with open(many, "w") as handle:
            handle.write(many_threads(16, 64))
        print("| case | start to first callback ms, median (worst) | window end to results written ms | runner wall s | target ms |")
        print("|---|---|---|---|---|")
        cell_case("fifo80, 1 s", src, os.path.join(REPO, "scenarios", "fifo80.yaml"), runs, work, 50, "--duration", "1s")
        cell_case("1,024 threads in 16 processes, 1 s", src, many, runs, work, 300)
        matrix_case(src, runs, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
