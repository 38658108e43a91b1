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
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd="/")
    lines = done.stdout.splitlines()
    assert lines[0].split() == ["TID", "COMMAND", "RTPRIO", "CLS", "PSR"], done.stdout
    assert lines[-1] == "0 []", done.stdout


# ---------------------------------------------------------------- names as a terminal may get them


def test_names_are_shown_as_procps_shows_them():
    """procps 4.0.2 in a UTF-8 locale: what iswprint refuses is one `?` each, a byte that is not UTF-8 too."""
    from runner.printable import decode, for_terminal

    assert for_terminal("a\x1b[31mred\nx") == "a?[31mred?x"
    assert for_terminal("tab\there\x7f") == "tab?here?"
    assert for_terminal("x\x85y\u2028z") == "x?y?z"  # C1 NEL, line separator
    assert for_terminal(decode(b"\xff\xfeab")) == "??ab"
    assert for_terminal(decode(b"abcdefghijklm\xe4\xb8")) == "abcdefghijklm??"  # cut by the kernel: a `?` per byte
    assert for_terminal("café 中文 \u202eRTL \ue000") == "café 中文 \u202eRTL \ue000"  # printable, as iswprint says
    assert for_terminal("\U000e0080") == "?"  # unassigned


def test_a_table_pads_names_by_the_columns_they_take():
    rows = [row(1, "中文", 0, 0), row(2, "a\x1b[2Jb", 0, 0), row(3, "\u202eab", 0, 0)]
    assert render_ps(rows, ["tid", "comm", "cls"]) == (
        "  TID COMMAND         CLS\n    1 中文             TS\n    2 a?[2Jb           TS\n    3 \u202eab               TS\n"
    )


def test_the_terminals_cell_summary_shows_no_name_raw():
    """Thread names, cell ids, reasons, verdicts, warnings: from the kernel, the scenario or a results file."""
    from reportdata import main_thread, matrix

    from runner.report.cellview import render_cell
    from runner.results.document import Verdict

    name = "w\x1b]0;pwned\x07\nFAIL x"
    cell = matrix().cells[0]
    t = main_thread(cell)
    cell.threads[cell.threads.index(t)] = t.model_copy(update={"name": name, "degraded": [name]})
    cell.id, cell.reason, cell.warnings = f"v={name}", name, [name]
    cell.expectations = [Verdict(thread=name, metric="latency.p99", limit="<= 1us", measured=5_000, passed=False, note=name)]
    cell.thread_table = [cell.thread_table[0].model_copy(update={"comm": name})]
    text = render_cell(cell)
    assert "\x1b" not in text and "\x07" not in text
    assert not any(line.startswith("FAIL x") for line in text.splitlines()), text
    assert text.count("w?]0;pwned??FAIL x") >= 6, text


def test_notes_on_stderr_show_each_line_as_a_terminal_may_get_it(capsys):
    from runner.terminal import note

    note("runner: warning: thread a\x1b[2Jb stopped\nsecond line")
    assert capsys.readouterr().err == "runner: warning: thread a?[2Jb stopped\nsecond line\n"
