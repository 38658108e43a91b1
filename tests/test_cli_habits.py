"""What a shell user expects of the command line: a did-you-mean for a mistyped command, and completion."""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import pathlib
import re
import shlex
import shutil
import subprocess
import sys

import pytest
import shtab
from conftest import SCENARIOS, _in_ci, run_cli

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


def _completion_folder(tmp_path: pathlib.Path) -> pathlib.Path:
    """A folder to complete in: a scenario under scenarios/, a file beside, a folder for results."""
    (tmp_path / "scenarios").mkdir(parents=True)
    (tmp_path / "scenarios" / "fifo80.yaml").write_text("")
    (tmp_path / "a.yaml").write_text("")
    (tmp_path / "results").mkdir()
    return tmp_path


# (the words of a command line, the last being completed; what completion offers): the same for bash and zsh
COMPLETIONS = [
    (["runner", "comp"], ["compare", "completion"]),
    (["runner", "scenarios/fi"], ["scenarios/fifo80.yaml"]),  # the README's main form: a scenario as the first word
    (["runner", "--"], ["--help", "--version"]),
    (["runner", "a.yaml", "--du"], ["--duration"]),  # then the run's options
    (["runner", "a.yaml", "--out", ""], ["results", "scenarios"]),  # folders only; it offered the commands
    (["runner", "a.yaml", "--out", "results", "--no-p"], ["--no-plots"]),
    (["runner", "run", "a.yaml", "--du"], ["--duration"]),
    (["runner", "validate", "sc"], ["scenarios"]),
    (["runner", "schema", "--r"], ["--results"]),
    (["runner", "merge", "x", "--out", "s"], ["scenarios"]),
]


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_bash_completes_a_scenario_then_the_run_options(tmp_path):
    """`runner scenarios/fi<TAB>` completed nothing, `runner x.yaml --du<TAB>` neither, and `runner x.yaml --out <TAB>`
    offered the commands: the script knew `runner COMMAND` only."""
    folder = _completion_folder(tmp_path)

    cases = [words for words, _ in COMPLETIONS] + [["runner", ""]]
    program = [  # loaded as a user loads it; the function completing is the one `complete -p runner` names
        f"source <({shlex.quote(sys.executable)} -m runner completion bash)",
        'function=$(complete -p runner | sed -n "s/.* -F \\([^ ]*\\) .*/\\1/p")',
    ]
    for words in cases:
        line = shlex.quote(" ".join(words))
        program += [
            f"COMP_WORDS=({' '.join(map(shlex.quote, words))}); COMP_CWORD={len(words) - 1}; COMP_LINE={line}; COMP_POINT=${{#COMP_LINE}}",
            'COMPREPLY=(); "$function"; printf "%s\\n" "${COMPREPLY[@]}" --',
        ]
    done = subprocess.run(["bash", "-c", "\n".join(program)], capture_output=True, text=True, cwd=folder, timeout=120)
    assert done.returncode == 0, done.stderr
    offered = [sorted(set(text.split())) for text in done.stdout.split("--\n")]
    assert len(offered) == len(cases) + 1, done.stdout
    wrong = [f"{' '.join(words)}<TAB>: {got}, expected {want}" for (words, want), got in zip(COMPLETIONS, offered) if got != want]
    assert not wrong, "\n".join(wrong)
    assert {"validate", "run", "a.yaml", "scenarios"} <= set(offered[len(COMPLETIONS)]), offered  # commands and files


_ZSH_DRIVER = r"""
# usage: zsh -f DRIVER FPATH_DIR OUT LINE...: an interactive zsh in a pseudo-terminal, with the completion from FPATH_DIR
# (as `runner completion zsh > "${fpath[1]}/_runner"` installs it) and compinit; each LINE is typed with a TAB, never run,
# and what completion offered for it goes to OUT, one match a line, each LINE's ended by a line `--`
zmodload zsh/zpty
dir=$1; export OFFERED=$2; shift 2
cat > $OFFERED.zsh <<'END'
compadd() {  # what each call adds, as matched against the word (-O), written down; calls that only ask are passed on
  if [[ ${@[1,(i)(-|--)]} == *-(O|A|D)\ * ]]; then builtin compadd "$@"; return; fi
  local -a matches
  builtin compadd -O matches "$@"
  print -rl -- $matches >> $OFFERED
  builtin compadd "$@"
}
complete-and-mark() { zle complete-word; print -r -- -- >> $OFFERED }  # TAB: complete, then say it is done
zle -N complete-and-mark
bindkey '^I' complete-and-mark
unsetopt autolist  # no list on the terminal, and no question whether to show a long one
zle-line-init() { print -r -- ready > $OFFERED.ready }  # the line editor reads keys now: what is typed before may be lost
zle -N zle-line-init
END
wait_for() {  # until the file $1 holds $2 lines `--` (0: until it exists), reading what the terminal shows meanwhile
  for i in {1..300}; do
    while zpty -rt z echoed; do :; done  # read, so that the pseudo-terminal never fills and blocks the shell
    [[ -e $1 ]] && (( $(grep -cx -- -- $1) >= $2 )) && return
    sleep 0.1
  done
  print -u2 "no answer from zsh"; exit 1
}
integer typed=0
for line in "$@"; do  # a shell for each line: nothing typed ahead while a completion runs, and nothing left of the last
  rm -f $OFFERED.ready
  zpty z zsh -f -i
  zpty -w z "PS1=''; fpath=($dir \$fpath); autoload -U compinit; compinit -u -D; source $OFFERED.zsh; path=()"  # no program runs
  wait_for $OFFERED.ready 0
  zpty -wn z "$line"$'\t'  # no newline: the line is completed, never run
  wait_for $OFFERED $(( typed += 1 ))
  zpty -d z
done
"""


def test_zsh_completes_a_scenario_then_the_run_options(tmp_path):
    if shutil.which("zsh") is None:
        if _in_ci():
            pytest.fail("zsh is not installed; .ci/run installs it")
        pytest.skip("needs zsh")
    folder = _completion_folder(tmp_path / "work")
    functions = tmp_path / "functions"
    functions.mkdir()
    outcome = run_cli("completion", "zsh")
    assert outcome.code == 0 and outcome.out.startswith("#compdef runner")
    (functions / "_runner").write_text(outcome.out)
    (tmp_path / "driver.zsh").write_text(_ZSH_DRIVER)
    lines = [" ".join(words) for words, _ in COMPLETIONS] + ["runner "]
    out = tmp_path / "offered"
    subprocess.run(["zsh", "-f", str(tmp_path / "driver.zsh"), str(functions), str(out), *lines], cwd=folder, timeout=120, check=True)
    offered = out.read_text().split("--\n")
    assert len(offered) == len(lines) + 1, offered
    got = {line: sorted(set(text.split())) for line, text in zip(lines, offered)}
    want = {" ".join(words): [w.rsplit("/", 1)[-1] for w in want] for words, want in COMPLETIONS}  # zsh offers a path's last part
    assert {line: got[line] for line in want} == want
    assert {"validate", "run", "a.yaml", "scenarios"} <= set(got["runner "]), got["runner "]


def test_tcsh_completion_is_written_with_the_version_option():
    outcome = run_cli("completion", "tcsh")
    assert outcome.code == 0 and "version" in re.search(r"'c/--/\(([^)]*)\)/'", outcome.out).group(1).split()


def test_every_argument_naming_a_file_or_folder_completes_as_one():
    """report's --hdr FILE and --kcidb FILE completed nothing: which arguments complete files goes by their names."""
    from runner.cli import _PARSERS
    from runner.completion import parser_tree

    names = {"FILE", "FILE.json", "FILE.yaml", "SCENARIO.yaml", "RESULTS", "BASE", "NEW", "DIR"}
    top = parser_tree(_PARSERS, "")
    (commands,) = [a for a in top._actions if isinstance(a, argparse._SubParsersAction)]
    bare = [
        f"runner {name} {'/'.join(a.option_strings) or a.dest} {a.metavar}"
        for name, parser in commands.choices.items()
        for a in parser._actions
        if a.metavar in names and not hasattr(a, "complete")
    ]
    assert not bare, bare
    assert {a.dest: a.complete for a in commands.choices["run"]._actions if a.dest in ("out", "resume")} == {
        "out": shtab.DIRECTORY,
        "resume": shtab.DIRECTORY,
    }


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
    assert done.code == 2  # the error is the last line: a user without RT rights is warned of them first (README, Limits)
    assert done.err.strip().splitlines()[-1] == (
        "runner: no cell of shard 2/2 matches policy=other,priority=0 (policy=other,priority=0 is in shard 1/2); "
        "shard 2/2 holds: policy=fifo,priority=80, policy=rr,priority=80"
    )
    done = run_cli(matrix, "--list", "--shard", "7/7", "--cell", "policy=rr*")
    assert done.code == 2 and done.err.strip().endswith("is in shard 4/7); shard 7/7 holds none of the scenario's 5 cells")
    done = run_cli(matrix, "--list", "--shard", "2/2", "--cell", "nosuch")  # in no shard at all: every cell is listed
    last = done.err.strip().splitlines()[-1]
    assert done.code == 2 and last.startswith("runner: no cell matches nosuch; cells: policy=fifo,priority=10, ")


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


def test_an_option_several_commands_take_is_the_same_option_in_each():
    """runner/options.py declares them once: flags, action, default and metavar agree wherever they are taken."""
    from runner import options

    shared = {name: o for name, o in vars(options).items() if isinstance(o, options.Option)}
    own_metavar = {("import-rtapp", "--output")}  # FILE.yaml: what the file is, said in its metavar
    other_option = {("report", "--cell")}  # the one cell to export (an ID), not a filter of cells (GLOBs)
    for name, option in shared.items():
        declared = option.add(argparse.ArgumentParser(add_help=False))
        takers = []
        for command, make in _PARSERS.items():
            for action in make()._actions:
                if option.flags[-1] in action.option_strings and (command, option.flags[-1]) not in other_option:  # `ps -o` is --columns
                    takers.append(command)
                    assert (type(action), action.option_strings, action.dest, action.default, action.nargs, action.const) == (
                        type(declared),
                        declared.option_strings,
                        declared.dest,
                        declared.default,
                        declared.nargs,
                        declared.const,
                    ), (name, command)
                    assert action.metavar == declared.metavar or (command, declared.option_strings[-1]) in own_metavar, (name, command)
        assert len(takers) >= 2, f"{name} is taken by {takers} only: an option of one command is declared in its parser"
