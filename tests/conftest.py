"""Shared helpers: the repository layout and an in-process CLI call; CI's rule for the kernel tests."""

from __future__ import annotations

import contextlib
import io
import os
import sys
from dataclasses import dataclass

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The tests import the installed package, never the source tree: `python -m pytest` puts the working
# directory first on sys.path, and a source tree lacks the native core a non-editable install built.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != REPO]
SCENARIOS = os.path.join(REPO, "scenarios")


def _in_ci() -> bool:
    return os.environ.get("CI", "") not in ("", "0", "false")


def pytest_sessionstart(session: pytest.Session) -> None:
    """In CI the kernel tests must run: a machine without RT rights fails the run instead of skipping 50 tests.

    A CI machine that really has no RT rights says so with RUNNER_TESTS_NO_RT=1; the kernel tests
    are then skipped, and the summary says why.
    """
    from kernelrun import can_use_rt

    if _in_ci() and not can_use_rt() and os.environ.get("RUNNER_TESTS_NO_RT", "") in ("", "0"):
        raise pytest.UsageError(
            "CI is set but this machine cannot use SCHED_FIFO (no CAP_SYS_NICE, RLIMIT_RTPRIO 0), so the "
            "kernel tests would be skipped; run CI as root or with CAP_SYS_NICE, or set "
            "RUNNER_TESTS_NO_RT=1 to run without them on purpose"
        )


@dataclass
class Outcome:
    code: int
    out: str
    err: str


def run_cli(*argv: str) -> Outcome:
    """Call runner's main() in-process and capture what it prints."""
    from runner.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return Outcome(int(code), out.getvalue(), err.getvalue())


@pytest.fixture
def write_scenario(tmp_path):
    """Write YAML text to a file and return its path."""

    def write(text: str, name: str = "s.yaml") -> str:
        path = tmp_path / name
        path.write_text(text)
        return str(path)

    return write
