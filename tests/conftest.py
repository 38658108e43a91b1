"""Shared helpers: the repository layout and an in-process CLI call."""

from __future__ import annotations

import contextlib
import io
import os
from dataclasses import dataclass

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENARIOS = os.path.join(REPO, "scenarios")


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
