"""Shell completion for `runner`, written by shtab from the command's own argparse parsers.

`runner completion bash|zsh|tcsh` prints a script: the commands, each command's options and, for
the arguments that name files or folders, the shell's file or folder completion.  The script is
generated from the same parsers the commands use, so a new option completes without another edit.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping

SHELLS = ("bash", "zsh", "tcsh")
_FILES = frozenset({"scenario", "files", "file", "results", "base", "new", "inputs", "output", "baseline", "histogram", "json", "junit"})
_FOLDERS = frozenset({"out", "resume"})


def parser_tree(commands: Mapping[str, Callable[[], argparse.ArgumentParser]], description: str) -> argparse.ArgumentParser:
    """One parser with a subcommand per entry of `commands`, each a copy of that command's own parser."""
    import shtab

    top = argparse.ArgumentParser(prog="runner", description=description)
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

    return str(shtab.complete(parser_tree(commands, description), shell=shell))
