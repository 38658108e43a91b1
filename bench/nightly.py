"""Benchmark: can a nightly verdict be trusted?  Identical nights judged by --history, counting false alarms; then planted
regressions that must be caught; and the same identical nights judged as the nightly workflow used to (each compared with
the night before, a fixed threshold per figure), for contrast.

    python bench/nightly.py --lock /tmp/runner-rt.lock [--nights 20] [--quick] [--keep DIR]

Each night is `runner scenarios/policy_matrix.yaml --duration 2s --settle 200ms --history H` (the shipped nightly sweep:
five cells, a 100 ms callback under a busy loop on every CPU, about 13 s a night on a 2-CPU VM), nothing changed between
nights.  Then three planted nights, each judged against a copy of the identical nights' history:

- a FIFO 90 thread on every CPU stealing 300 us of each millisecond (the measured threads run at FIFO/RR 80 and 10);
- the measured thread losing its FIFO or RR policy (set back to SCHED_OTHER by another process as soon as it appears);
- a FIFO 1 busy loop on every CPU taking 800 us of each millisecond, which makes the OTHER cell's thread miss releases
  (a nice -20 loop would not: autogroup keeps another session's nice values to itself); caught when the night fails
  naming the OTHER cell's thread (its missed releases vary from 0 to 10 of 20 on identical nights here, so its
  switches per callback and its worst slack are what give it away).

A thread that lost its policy is caught by the run itself before any history: the kernel's read-back says `other
applied` and the cell is an error (exit 4); the bench counts that, naming the thread, as caught.

Goal: at most 1 false alarm in 20 identical nights, every planted regression caught (exit 1, naming the figure).  For
contrast, the same identical nights as the nightly workflow judged them before --history: each compared with the night
before by its thresholds alone (`runner compare`'s rule before sampling was weighed), and by today's `runner compare`.

`--rejudge DIR` judges the nights a `--keep DIR` run kept again, with the current code, into a fresh history (no
real run: the planted nights' cell errors, judged by the run itself, are not in it).

`--quick` (for CI: 6 nights of two cells, then the three planted ones, about a minute) checks that the bench runs and
prints its figures, and exits 0 whatever they are; its numbers are not the ones to quote.  Spawns real-time processes:
`--lock FILE` takes that lock (flock) for each night, so the bench never holds it for more than a night's half minute.
"""

from __future__ import annotations

import argparse
import fcntl
import itertools
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing import Process

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENARIO = os.path.join(REPO, "scenarios", "policy_matrix.yaml")
QUICK_CELLS = ("policy=fifo,priority=80", "policy=other,priority=0")


def runner_command() -> list[str]:
    script = os.path.join(os.path.dirname(sys.executable), "runner")
    return [script] if os.path.exists(script) else [sys.executable, "-m", "runner"]


LOCK: list[str] = []  # --lock FILE


@contextmanager
def locked() -> Iterator[None]:
    if not LOCK:
        yield
        return
    with open(LOCK[0], "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def night(folder: str, history: str, cells: tuple[str, ...]) -> tuple[int, str]:
    """One night of the sweep with --history; (exit code, report.md and what the run said)."""
    argv = [*runner_command(), SCENARIO, "--duration", "2s", "--settle", "200ms", "--out", folder, "--quiet", "--no-plots"]
    argv += ["--history", history] + [a for c in cells for a in ("--cell", c)]
    done = subprocess.run(argv, capture_output=True, text=True, check=False)
    report = os.path.join(folder, "report.md")
    text = ""
    if os.path.exists(report):
        with open(report, encoding="utf-8") as handle:
            text = handle.read()
    return done.returncode, text + done.stdout + done.stderr


def regressions(report: str) -> list[str]:
    """`figure (cell)` of each regression against the history in a report's section."""
    section = report.split("## Against the history", 1)[-1].split("<details>", 1)[0]
    out = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 5 and cells[4].startswith("❌"):
            out.append(f"{cells[2]} ({cells[0]})")
    return out


# ---------------------------------------------------------------- planted interference


def _steal(cpu: int, priority: int, busy_s: float, period_s: float, stop_at: float) -> None:
    os.sched_setaffinity(0, {cpu})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    while time.monotonic() < stop_at:
        start = time.monotonic()
        while time.monotonic() - start < busy_s:
            pass
        time.sleep(max(0.0, period_s - (time.monotonic() - start)))


@contextmanager
def processes(target: Callable[..., None], per_cpu: int, *args: object, seconds: float = 120) -> Iterator[None]:
    stop_at = time.monotonic() + seconds
    cpus = sorted(os.sched_getaffinity(0))
    started = [Process(target=target, args=(cpu, *args, stop_at), daemon=True) for cpu in cpus for _ in range(per_cpu)]
    for p in started:
        p.start()
    try:
        yield
    finally:
        for p in started:
            p.terminate()
            p.join(5)


@contextmanager
def demoted(name: str = "minimal_schedul") -> Iterator[None]:
    """Every FIFO or RR thread called `name` set back to SCHED_OTHER as soon as it is seen (every 20 ms)."""
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            for pid in filter(str.isdigit, os.listdir("/proc")):
                try:
                    for tid in os.listdir(f"/proc/{pid}/task"):
                        with open(f"/proc/{pid}/task/{tid}/comm") as handle:
                            if handle.read().strip() != name:
                                continue
                        if os.sched_getscheduler(int(tid)) in (os.SCHED_FIFO, os.SCHED_RR):
                            os.sched_setscheduler(int(tid), os.SCHED_OTHER, os.sched_param(0))
                except OSError:
                    continue
            done.wait(0.02)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


# ---------------------------------------------------------------- the old verdicts, for contrast


def consecutive(folders: list[str]) -> tuple[list[int], list[int]]:
    """Each night compared with the one before: figures past their threshold (the old rule), and today's regressions."""
    from runner.report.compare import Verdict, compare
    from runner.results.read import load

    old, new = [], []
    for before, after in itertools.pairwise(folders):
        cmp = compare(load(before), load(after))
        judged = [f for f in cmp.figures if f.base is not None and f.new is not None and not f.threshold.off]
        old.append(sum(f.threshold.exceeded(f.base, f.new) for f in judged if f.verdict != Verdict.UNCOMPARABLE))  # type: ignore[arg-type]
        new.append(cmp.regressions)
    return old, new


def rejudge(work: str) -> int:
    """Judge the nights kept in `work` (--keep) again with this runner's code, into a fresh history: no real run."""
    import glob

    from runner.history.apply import judged_into
    from runner.history.store import open_store
    from runner.report.compare import DEFAULT_THRESHOLDS
    from runner.results.read import load

    fresh = tempfile.mkdtemp(prefix="bench-nightly-rejudge-")
    history = os.path.join(fresh, "history.sqlite")
    alarms = []
    folders = sorted(glob.glob(os.path.join(work, "night-*")))
    with open_store(history) as store:
        for n, folder in enumerate(folders):
            verdict = judged_into(store, load(folder), folder, list(DEFAULT_THRESHOLDS))
            failed = [f"{f.figure.name} ({f.cell})" for f in verdict.figures if f.verdict.value in ("regression", "missing")]
            if failed:
                alarms.append((n, failed))
    print(f"identical nights: {len(folders)}; --history: {len(alarms)} false alarm night(s){': ' + str(alarms) if alarms else ''}")
    for folder in sorted(glob.glob(os.path.join(work, "planted-*"))):
        if not os.path.isdir(folder):
            continue
        copy = os.path.join(fresh, os.path.basename(folder) + ".sqlite")
        shutil.copyfile(history, copy)
        with open_store(copy) as store:
            verdict = judged_into(store, load(folder), folder, list(DEFAULT_THRESHOLDS))
        failed = [f"{f.figure.name} ({f.cell})" for f in verdict.figures if f.verdict.value in ("regression", "missing")]
        print(f"{os.path.basename(folder)}: {', '.join(failed) or 'no regression against the history'}")
    old, new = consecutive(folders)
    print(f"consecutive nights, thresholds alone: {sum(1 for x in old if x)} of {len(old)} nights ({sum(old)} figures)")
    print(f"consecutive nights, runner compare with sampling: {sum(1 for x in new if x)} of {len(new)} nights")
    shutil.rmtree(fresh, ignore_errors=True)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nights", type=int, default=20)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--keep", metavar="DIR", help="keep the nights and the history in DIR")
    parser.add_argument("--lock", metavar="FILE", help="take this lock (flock) for each night, as every real run here must")
    parser.add_argument("--rejudge", metavar="DIR", help="judge the nights kept in DIR (--keep) again with this code; run nothing")
    ns = parser.parse_args()
    if ns.rejudge:
        return rejudge(ns.rejudge)
    if ns.lock:
        LOCK.append(ns.lock)
    nights = 6 if ns.quick else ns.nights
    cells = QUICK_CELLS if ns.quick else ()
    work = ns.keep or tempfile.mkdtemp(prefix="bench-nightly-")
    os.makedirs(work, exist_ok=True)
    history = os.path.join(work, "history.sqlite")
    began = time.monotonic()
    folders, alarms = [], []
    for n in range(nights):
        folder = os.path.join(work, f"night-{n:02d}")
        with locked():
            code, report = night(folder, history, cells)
        folders.append(folder)
        found = regressions(report)
        if code not in (0, 1) or (code == 1 and not found and "expectation" not in report):
            print(f"night {n}: exit {code}", file=sys.stderr)
        if found:
            alarms.append((n, found))
        print(f"night {n:2d}: exit {code}{': ' + ', '.join(found) if found else ''}", flush=True)
    judged = max(0, nights - 5)
    old, new = consecutive(folders)
    print()
    print(f"scenario: scenarios/policy_matrix.yaml --duration 2s --settle 200ms{' (' + ', '.join(cells) + ')' if cells else ''}")
    print(f"identical nights: {nights}, judged against their history: {judged} (the first 5 learn)")
    print(f"  --history: {len(alarms)} false alarm night(s){': ' + str(alarms) if alarms else ''}")
    print(
        f"  each compared with the night before, thresholds alone (the workflow before --history): "
        f"{sum(1 for x in old if x)} of {len(old)} nights called regressions ({sum(old)} figures)"
    )
    print(f"  each compared with the night before, runner compare with sampling weighed: {sum(1 for x in new if x)} of {len(new)} nights")
    planted: list[tuple[str, Callable[[], object], str]] = [
        ("a FIFO 90 thread stealing 300 us of each ms on every CPU", lambda: processes(_steal, 1, 90, 0.0003, 0.001), "policy=fifo"),
        ("the measured thread losing its FIFO/RR policy", demoted, "other applied"),
        ("a FIFO 1 loop taking 800 us of each ms on every CPU", lambda: processes(_steal, 1, 1, 0.0008, 0.001), "policy=other"),
    ]
    caught = 0
    for n, (words, interference, expected) in enumerate(planted):
        copy = os.path.join(work, f"planted-{n}.sqlite")
        shutil.copyfile(history, copy)
        with locked(), interference():  # type: ignore[attr-defined]
            code, report = night(os.path.join(work, f"planted-{n}"), copy, cells)
        found = regressions(report)
        by_run = code == 4 and expected in report  # the run's own read-back: the cell is an error, naming the thread
        ok = by_run or (code == 1 and any(expected in f for f in found))
        if by_run:
            found = [line.strip()[:160] for line in report.splitlines() if expected in line][:1]
        caught += ok
        print(f"planted: {words}: {'caught' if ok else 'MISSED'} (exit {code}; {', '.join(found) or 'no regression'})", flush=True)
    print(f"planted regressions caught: {caught} of {len(planted)}")
    print(f"bench time: {time.monotonic() - began:.0f} s; nights in {work}")
    if not ns.keep:
        shutil.rmtree(work, ignore_errors=True)
    if ns.quick:
        return 0
    return 0 if len(alarms) <= 1 and caught == len(planted) else 1


if __name__ == "__main__":
    sys.exit(main())
