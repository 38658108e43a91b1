"""How the runner starts its own Python children (workers, the guard): the same interpreter and the same package.

A child imports exactly the `runner` package this process imported: its folder goes on
the child's PYTHONPATH, the user site is skipped (`-s`), and the child starts in `/`, so
neither the folder a user runs from nor a stray `runner/` directory in it can shadow it.
"""

from __future__ import annotations

import os
import signal
import sys

import runner

PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(runner.__file__)))


def python_module(module: str) -> list[str]:
    """The command line that runs `python -m module` with this interpreter."""
    return [sys.executable, "-s", "-m", module]


def child_env(**extra: str) -> dict[str, str]:
    """This process's environment, with the package's folder first on PYTHONPATH (and `extra`)."""
    path = os.environ.get("PYTHONPATH")
    return {**os.environ, "PYTHONPATH": PACKAGE_PARENT + (os.pathsep + path if path else ""), **extra}


def signal_name(number: int) -> str:
    """A signal as kill -l names it (`SIGKILL`, `SIGRTMIN+1`), or `signal N`: Python names only some real-time ones."""
    try:
        return signal.Signals(number).name
    except ValueError:
        if signal.SIGRTMIN <= number <= signal.SIGRTMAX:
            return f"SIGRTMIN+{number - signal.SIGRTMIN}"
        return f"signal {number}"
