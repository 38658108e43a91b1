"""Shell completion for `runner`, written by shtab from the command's own argparse parsers.

`runner completion bash|zsh|tcsh` prints a script: the commands, each command's options and, for
the arguments that name files or folders, the shell's file or folder completion.  The script is
generated from the same parsers the commands use, so a new option completes without another edit.

shtab knows commands, not `runner SCENARIO.yaml [options]`, the form the README leads with, where a
first word that is no command is the scenario of `runner run` (runner.cli.main).  For bash and zsh the
script ends with a function of its own that completes that form the same way: the first word is a
command or a file, and the words after a file are completed as `runner run FILE ...` would be.  tcsh's
completion is a list of rules without functions: it completes the commands, every option and the
folders of `--out`, but not a file as the first word.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping

SHELLS = ("bash", "zsh", "tcsh")
_FILES = frozenset(
    {
        "scenario",
        "files",
        "file",
        "results",
        "base",
        "new",
        "inputs",
        "output",
        "baseline",
        "histogram",
        "json",
        "hdr",
        "kcidb",
        "junit",
        "history",
        "imports",
    }
)
_FOLDERS = frozenset({"out", "resume"})

# `runner FILE ...` is completed as `runner run FILE ...`; the first word is a command or a file.
_BASH_RUN_FORM = """
# runner SCENARIO.yaml [options] is runner run SCENARIO.yaml [options]: completed as such, and the
# first word is a command or a file (added by runner.completion to shtab's script)
_runner_commands=(%(commands)s)
_runner() {
  local first="${COMP_WORDS[1]-}" line
  if (( COMP_CWORD > 1 )) && [[ $first != -* && " ${_runner_commands[*]} " != *" $first "* ]]; then
    COMP_WORDS=("${COMP_WORDS[0]}" run "${COMP_WORDS[@]:1}")
    COMP_CWORD=$((COMP_CWORD + 1))
  fi
  _shtab_runner
  if (( COMP_CWORD == 1 )) && [[ $first != -* ]]; then
    compopt -o filenames 2>/dev/null || :
    while IFS= read -r line; do COMPREPLY+=("$line"); done < <(compgen -f -- "$first")
  fi
}
complete -o bashdefault -F _runner runner
"""
_ZSH_RUN_FORM = """
# runner SCENARIO.yaml [options] is runner run SCENARIO.yaml [options]: completed as such, and the
# first word is a command or a file (added by runner.completion to shtab's script)
_runner_commands=(%(commands)s)
_runner_run_form() {
  if (( CURRENT > 2 )) && [[ ${words[2]} != -* ]] && (( ! ${_runner_commands[(Ie)${words[2]}]} )); then
    words=(${words[1]} run ${words[2,-1]})
    (( CURRENT += 1 ))
  fi
  if (( CURRENT == 2 )) && [[ ${words[2]} != -* ]]; then
    _shtab_runner_commands
    _files
    return 0
  fi
  _shtab_runner "$@"
}
"""
# where shtab's zsh script registers (sourced) or calls (autoloaded from fpath) its function
_ZSH_START = "\nif [[ $zsh_eval_context[-1] == eval ]]; then\n"
_ZSH_ENTRY = ("  compdef _shtab_runner -N runner\n", '  _shtab_runner "$@"\n')


def parser_tree(commands: Mapping[str, Callable[[], argparse.ArgumentParser]], description: str) -> argparse.ArgumentParser:
    """One parser with a subcommand per entry of `commands`, each a copy of that command's own parser."""
    import shtab

    from runner import __version__

    top = argparse.ArgumentParser(prog="runner", description=description)
    top.add_argument("--version", action="version", version=f"runner {__version__}")
    sub = top.add_subparsers(dest="command")
    for name, build in commands.items():
        own = build()
        child = sub.add_parser(name, parents=[own], add_help=False, help=own.description, description=own.description)
        for action in child._actions:  # argparse keeps no public list of a parser's arguments
            if action.nargs == 0:
                continue  # a flag takes no value to complete
            if action.dest in _FILES:
                action.complete = shtab.FILE  # type: ignore[attr-defined]  # shtab reads this attribute
            elif action.dest in _FOLDERS:
                action.complete = shtab.DIRECTORY  # type: ignore[attr-defined]
    return top


def script(commands: Mapping[str, Callable[[], argparse.ArgumentParser]], shell: str, description: str) -> str:
    """The completion script for `shell` (one of SHELLS)."""
    import shtab

    text = str(shtab.complete(parser_tree(commands, description), shell=shell))
    names = " ".join(commands)
    if shell == "bash":
        return text.rstrip("\n") + "\n" + _BASH_RUN_FORM % {"commands": names}
    if shell == "zsh":
        for entry in _ZSH_ENTRY:
            if text.count(entry) != 1:  # a shtab release that ends its script otherwise: the tests say so too
                raise RuntimeError(f"shtab's zsh script no longer has {entry.strip()!r} once: runner.completion needs an update")
            text = text.replace(entry, entry.replace("_shtab_runner", "_runner_run_form"))
        start = text.index(_ZSH_START)
        return text[:start] + _ZSH_RUN_FORM % {"commands": names} + text[start:]
    return text
