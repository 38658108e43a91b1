"""Command line: parse arguments, call one function per command, map errors to exit codes.

No logic lives here beyond that: every command is a call into the module that owns it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Callable, Sequence

from . import __version__
from .errors import ExitCode, RunnerError, ScenarioError, UsageError

COMMANDS = ("run", "validate", "schema", "ps", "report", "compare")
_TOP_HELP = """\
usage: runner SCENARIO.yaml [options]      run a scenario (every cell of its matrix)
       runner validate FILE...             check scenario files, print every problem
       runner schema                       print the JSON Schema of the scenario format
       runner ps PID|NAME                  ps-style thread table of a live process
       runner --version

Run `runner run --help` for the run options (SCENARIO.yaml is short for `runner run SCENARIO.yaml`).

exit codes: 0 ok, 1 an expectation failed, 2 invalid input, 3 missing permission,
            4 run error (worker crash, timeout), 130 interrupted
"""


def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="runner run", description="Run a scenario file: spawn its processes and threads, measure, report.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--list", action="store_true", help="print the expanded cells with each thread's resolved settings; run nothing")
    p.add_argument("--duration", metavar="D", help="override the scenario's duration, e.g. 2s")
    p.add_argument("--cell", action="append", default=[], metavar="GLOB", help="run only cells whose id matches (repeatable)")
    p.add_argument("--out", metavar="DIR", help="results folder (default reports/<scenario>/<UTC timestamp>)")
    p.add_argument("--follow", action="store_true", help="print a line per callback, as the ros2-realtime-examples do")
    p.add_argument("--allow-degraded", action="store_true", help="run even without the rights to apply every setting; mark affected threads degraded")
    p.add_argument("--allow-priority-99", action="store_true", help="allow scenario threads at RT priority 99 (above the runner's watchdog)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `runner` console script; returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        sys.stdout.write(_TOP_HELP)
        return ExitCode.OK if args else ExitCode.INVALID_INPUT
    if args[0] == "--version":
        print(f"runner {__version__}")
        return ExitCode.OK
    command = args[0] if args[0] in COMMANDS else "run"
    rest = args[1:] if args[0] in COMMANDS else args
    handlers: dict[str, Callable[[list[str]], int]] = {
        "run": _cmd_run,
        "validate": _cmd_validate,
        "schema": _cmd_schema,
        "ps": _cmd_ps,
    }
    if command not in handlers:
        print(f"runner: '{command}' is not available in this version", file=sys.stderr)
        return ExitCode.INVALID_INPUT
    try:
        return handlers[command](rest)
    except RunnerError as exc:
        print(str(exc), file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("runner: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED
    except BrokenPipeError:
        return ExitCode.OK


def _print_warnings(warnings: Sequence[object]) -> None:
    for warning in warnings:
        print(warning, file=sys.stderr)


def _cmd_validate(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="runner validate", description="Check scenario files; print every problem as file:line:col.")
    p.add_argument("files", nargs="+", metavar="FILE")
    ns = p.parse_args(argv)
    from .scenario import load_scenario

    worst = ExitCode.OK
    for path in ns.files:
        try:
            loaded = load_scenario(path)
        except ScenarioError as exc:
            print(str(exc), file=sys.stderr)
            worst = ExitCode.INVALID_INPUT
            continue
        _print_warnings(loaded.warnings)
        count = len(loaded.cells)
        print(f"{path}: ok ({count} cell{'s' if count != 1 else ''})")
    return worst


def _cmd_schema(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="runner schema", description="Print the JSON Schema of the scenario format.")
    p.parse_args(argv)
    from .schema import scenario_schema

    print(json.dumps(scenario_schema(), indent=2))
    return ExitCode.OK


def _cmd_ps(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="runner ps", description="Thread table of live processes, as ps -L -o tid,comm,rtprio,cls,psr prints it.")
    p.add_argument("target", help="a PID, or a process name (COMMAND, as ps -C selects)")
    p.add_argument("-o", "--columns", default="tid,comm,rtprio,cls,psr", help="columns: tid,comm,rtprio,cls,psr,ni,pri,cpus,nvcsw,nivcsw")
    ns = p.parse_args(argv)
    from .kernel import find_pids, pid_width, thread_rows
    from .pstable import parse_columns, render_ps

    columns = parse_columns(ns.columns)
    pids = [int(ns.target)] if ns.target.isdigit() else find_pids(ns.target)
    rows = [row for pid in pids for row in thread_rows(pid)]
    if not rows:
        raise UsageError(f"runner ps: no live process matches {ns.target!r}")
    sys.stdout.write(render_ps(rows, columns, pid_width()))
    return ExitCode.OK


def _cmd_run(argv: list[str]) -> int:
    ns = _run_parser().parse_args(argv)
    from .scenario import load_scenario

    loaded = load_scenario(ns.scenario)
    _print_warnings(loaded.warnings)
    if ns.list:
        from .kernel import current_settings, online_cpus
        from .listing import render

        sys.stdout.write(render(loaded, current_settings(), online_cpus()))
        return ExitCode.OK
    from .session import RunOptions, run_scenario

    options = RunOptions.from_namespace(ns, env=dict(os.environ))
    return run_scenario(loaded, options)
