"""--history on real runs: a few nights of fifo80 into a history file, then a night with a FIFO 90 thread stealing CPU
on every CPU, which must be a regression against the history naming the thread and the figure."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from multiprocessing import Process

import pytest
from kernelrun import env, needs_rt

from runner.history.store import open_store

pytestmark = [pytest.mark.kernel, needs_rt]

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIFO80 = os.path.join(REPO, "scenarios", "fifo80.yaml")


def night(tmp_path, name: str, history: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "runner", FIFO80, "--duration", "1s", "--out", str(tmp_path / name), "--quiet", "--no-plots"]
    return subprocess.run([*argv, "--history", history], capture_output=True, text=True, env=env(), timeout=120, check=False, cwd=tmp_path)


def steal(cpu: int, stop_at: float) -> None:
    """SCHED_FIFO 90 on `cpu`: busy 600 us of each millisecond, above the measured FIFO 80 thread."""
    os.sched_setaffinity(0, {cpu})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(90))
    while time.monotonic() < stop_at:
        start = time.monotonic()
        while time.monotonic() - start < 0.0006:
            pass
        time.sleep(0.0004)


def test_a_night_with_a_fifo_90_interferer_is_a_regression_against_its_history(tmp_path):
    history = str(tmp_path / "history.sqlite")
    for n in range(5):
        done = night(tmp_path, f"n{n}", history)
        assert done.returncode == 0, done.stdout + done.stderr
    assert "still learning" in done.stdout  # the fifth night has four before it; the sixth is judged
    stop_at = time.monotonic() + 60
    thieves = [Process(target=steal, args=(cpu, stop_at), daemon=True) for cpu in sorted(os.sched_getaffinity(0))]
    for p in thieves:
        p.start()
    try:
        done = night(tmp_path, "planted", history)
    finally:
        for p in thieves:
            p.terminate()
            p.join(5)
    assert done.returncode == 1, done.stdout + done.stderr
    assert re.search(r"❌ \d+ regressions? against the history in 1 cell: ", done.stdout), done.stdout
    assert "of minimal_schedul[0]/minimal_schedul (main)" in done.stdout, done.stdout
    report = (tmp_path / "planted" / "report.md").read_text()
    assert "❌ regression" in report.split("## Against the history", 1)[1]
    with open_store(history) as store:
        assert len(store.nights()) == 6 and store.change_points()
