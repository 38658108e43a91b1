"""What a shell user expects of the command line: a did-you-mean for a mistyped command, and completion."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import subprocess

import pytest
from conftest import SCENARIOS, run_cli

from runner.cli import _PARSERS, COMMANDS


def test_a_mistyped_command_gets_a_did_you_mean_and_exit_2():
    outcome = run_cli("comapre", "a", "b")
    assert outcome.code == 2
    assert outcome.err.strip() == "runner: unknown command 'comapre'; did you mean 'compare'?"


def test_a_word_like_no_command_lists_the_commands():
    outcome = run_cli("frobnicate")
    assert outcome.code == 2 and "unknown command 'frobnicate'; expected one of: run, validate" in outcome.err


@pytest.mark.parametrize("first", ["missing.yaml", "missing.yml", "missing.json", "sub/valdate"])
def test_what_names_a_scenario_file_is_still_run_as_one(first):
    outcome = run_cli(first)
    assert outcome.code == 2 and "unknown command" not in outcome.err and "cannot read file" in outcome.err


def test_an_existing_file_without_extension_runs_as_a_scenario(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "valdate").write_text(open(os.path.join(SCENARIOS, "fifo80.yaml")).read())
    outcome = run_cli("valdate", "--list")
    assert outcome.code == 0 and "fifo80: 1 cell" in outcome.out


def test_every_command_has_its_parser_for_completion():
    assert set(_PARSERS) == set(COMMANDS)


def _help_of(*argv: str) -> str:
    """What `runner ARGV --help` prints: argparse exits 0 after printing it."""
    from runner.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exited:
        main([*argv, "--help"])
    assert exited.value.code == 0
    return out.getvalue()


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_the_dispatcher_accepts_is_listed_in_the_top_help(command):
    top = run_cli("--help")
    assert top.code == 0
    named = set(re.findall(r"`?runner ([a-z][a-z-]*)", top.out))  # `runner run --help` names run
    assert command in named, f"runner --help does not list {command!r}"
    assert _help_of(command).startswith(f"usage: runner {command} "), f"{command!r} is listed but not dispatched to its own parser"


@pytest.mark.parametrize("command", COMMANDS)
def test_no_group_title_appears_twice_in_a_commands_help(command):
    titles = [line for line in _help_of(command).splitlines() if line.endswith(":") and not line.startswith(" ")]
    assert titles and len(titles) == len(set(titles)), f"runner {command} --help repeats a group: {titles}"


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_bash_completion_completes_commands_options_and_files(tmp_path):
    outcome = run_cli("completion", "bash")
    assert outcome.code == 0
    (tmp_path / "script").write_text(outcome.out)
    (tmp_path / "a.yaml").write_text("")

    def complete(*words: str) -> list[str]:
        line = " ".join(words)
        program = (
            f"source {tmp_path / 'script'}; COMP_WORDS=({' '.join(repr(w) for w in words)}); COMP_CWORD={len(words) - 1}; "
            f'COMP_LINE="{line}"; COMP_POINT=${{#COMP_LINE}}; _shtab_runner; printf "%s\\n" "${{COMPREPLY[@]}}"'
        )
        done = subprocess.run(["bash", "-c", program], capture_output=True, text=True, cwd=tmp_path, timeout=30)
        return sorted(done.stdout.split())

    assert complete("runner", "comp") == ["compare", "completion"]
    assert complete("runner", "run", "--dur") == ["--duration"]
    assert complete("runner", "validate", "") == ["a.yaml", "script"]
    assert "--results" in complete("runner", "schema", "--")


def test_zsh_completion_is_written_too():
    outcome = run_cli("completion", "zsh")
    assert outcome.code == 0 and outcome.out.startswith("#compdef runner")


def test_completion_refuses_a_shell_it_cannot_write_for():
    with pytest.raises(SystemExit) as caught:  # argparse's own usage error
        run_cli("completion", "fish")
    assert caught.value.code == 2


def test_list_honours_the_options_a_run_would_honour():
    """--list once listed every cell and the file's duration whatever --cell, --duration or a bad option said."""
    matrix = os.path.join(SCENARIOS, "policy_matrix.yaml")
    done = run_cli(matrix, "--list", "--cell", "policy=fifo*", "--duration", "2s")
    assert done.code == 0, done.err
    cells = [line for line in done.out.splitlines() if line.startswith("cell ")]
    assert len(cells) == 2 and all("duration 2s)" in line for line in cells) and "2 of 5 cells" in done.out
    for bad in (["--cell", "nosuch"], ["--duration", "abc"], ["--repeat", "0"], ["--dma-latency", "x"], ["--shard", "9/2"]):
        done = run_cli(matrix, "--list", *bad)
        assert done.code == 2 and "Traceback" not in done.err, (bad, done.err)


def test_a_cell_of_another_shard_is_said_to_be_there_not_missing():
    """`--shard 2/2 --cell X` with X in shard 1/2 said "no cell matches X; cells: ..., X", X among them."""
    matrix = os.path.join(SCENARIOS, "policy_matrix.yaml")
    done = run_cli(matrix, "--list", "--shard", "2/2", "--cell", "policy=other,priority=0")
    assert done.code == 2
    assert done.err.strip() == (
        "runner: no cell of shard 2/2 matches policy=other,priority=0 (policy=other,priority=0 is in shard 1/2); "
        "shard 2/2 holds: policy=fifo,priority=80, policy=rr,priority=80"
    )
    done = run_cli(matrix, "--list", "--shard", "7/7", "--cell", "policy=rr*")
    assert done.code == 2 and done.err.strip().endswith("is in shard 4/7); shard 7/7 holds none of the scenario's 5 cells")
    done = run_cli(matrix, "--list", "--shard", "2/2", "--cell", "nosuch")  # in no shard at all: every cell is listed
    assert done.code == 2 and done.err.startswith("runner: no cell matches nosuch; cells: policy=fifo,priority=10, ")


def test_a_scenario_after_a_bare_shuffle_is_said_to_be_no_seed():
    """`runner run --shuffle s.yaml` took the path for the seed, then said only that the scenario was required."""
    from runner.cli import main

    fifo80 = os.path.join(SCENARIOS, "fifo80.yaml")
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as caught:
        main(["run", "--shuffle", fifo80])
    assert caught.value.code == 2
    assert f"{fifo80!r} is no seed (an integer); give the scenario before --shuffle, or write --shuffle=SEED" in err.getvalue()
    assert run_cli(fifo80, "--shuffle", "7", "--list").code == 0
    assert run_cli(fifo80, "--shuffle", "--list").code == 0
