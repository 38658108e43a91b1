"""The ps-style table renders as procps does (pure checks; the comparison with real ps is in test_kernel)."""

from __future__ import annotations

import pytest

from runner.errors import UsageError
from runner.results.pstable import ThreadRow, parse_columns, render_ps


def row(tid, comm, policy, rtprio, psr=0, nice=0, prio=20):
    return ThreadRow(pid=tid, tid=tid, comm=comm, policy=policy, rtprio=rtprio, nice=nice, psr=psr, prio=prio)


def test_seed_table_layout():
    rows = [row(6775, "minimal_sched_f", 1, 80, 7, prio=-81), row(6776, "minimal_sched_f", 0, 0, 1), row(6778, "dq.builtins", 0, 0, 0)]
    assert render_ps(rows, pid_width=7) == (
        "    TID COMMAND         RTPRIO CLS PSR\n"
        "   6775 minimal_sched_f     80  FF   7\n"
        "   6776 minimal_sched_f      -  TS   1\n"
        "   6778 dq.builtins          -  TS   0\n"
    )


def test_batch_idle_rr_and_nice_columns_follow_procps():
    rows = [row(1, "b", 3, 0, nice=5, prio=25), row(2, "i", 5, 0, prio=20), row(3, "r", 2, 10, prio=-11)]
    assert render_ps(rows, ["tid", "comm", "rtprio", "cls", "ni", "pri"]) == (
        "  TID COMMAND         RTPRIO CLS  NI PRI\n"
        "    1 b                    0   B   5  14\n"
        "    2 i                    0 IDL   -  19\n"
        "    3 r                   10  RR   -  50\n"
    )


def test_command_last_is_not_padded():
    assert render_ps([row(7, "sleep", 0, 0)], ["tid", "comm"]) == "  TID COMMAND\n    7 sleep\n"


def test_unknown_column():
    with pytest.raises(UsageError, match="did you mean 'rtprio'"):
        parse_columns("tid,rtpri")


def test_columns_are_named_as_procps_names_them():
    """`ps -L -o tid,nvcsw,nivcsw` in procps 4 prints the headers VCSW and IVCSW; the runner takes the same names."""
    voluntary = ThreadRow(1, 7, "w", 0, 0, 0, 0, 120, (0,), 12, 3)
    assert parse_columns("tid,nvcsw,nivcsw") == ["tid", "nvcsw", "nivcsw"]
    assert render_ps([voluntary], ["tid", "nvcsw", "nivcsw"]) == "  TID  VCSW IVCSW\n    7    12     3\n"


def test_the_earlier_spellings_are_still_read_but_not_offered():
    assert parse_columns("vcsw,IVCSW") == ["nvcsw", "nivcsw"]
    with pytest.raises(UsageError) as caught:
        parse_columns("nvcw")
    assert "did you mean 'nvcsw'" in str(caught.value) and "ivcsw," not in str(caught.value).replace("nivcsw", "")


def test_runner_ps_imports_no_validation_library_and_no_scenario_model():
    """`runner ps` reads /proc and prints: pydantic and the scenario model (about 0.2 s of imports) stay out of it."""
    import subprocess
    import sys

    code = (
        "import os, sys; from runner import cli; code = cli.main(['ps', str(os.getpid())]); "
        "print(code, sorted(m for m in sys.modules if m.split('.')[0] == 'pydantic' or m.startswith('runner.scenario')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    lines = done.stdout.splitlines()
    assert lines[0].split() == ["TID", "COMMAND", "RTPRIO", "CLS", "PSR"], done.stdout
    assert lines[-1] == "0 []", done.stdout
