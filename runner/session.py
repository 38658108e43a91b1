"""Run a scenario: permissions, output folder, one cell after another, results, exit code."""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import signal
import sys
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Optional

from . import __version__, _probe, kernel, units
from .errors import ExitCode, UsageError
from .machine import machine_info
from .preflight import check as preflight
from .results import SCHEMA, CellResult, Status, slug, worst, write_atomic
from .scenario import LoadedScenario
from .spawn import CellOptions, Interrupted, run_cell
from .terminal import render_cell


@dataclass
class RunOptions:
    duration_ns: Optional[int]
    cells: list[str]
    out: Optional[str]
    follow: bool
    allow_degraded: bool
    allow_priority_99: bool
    quiet: bool
    command: list[str]

    @classmethod
    def from_namespace(cls, ns: argparse.Namespace, env: dict[str, str]) -> "RunOptions":
        duration = None
        if ns.duration:
            try:
                duration = units.parse_duration(ns.duration)
            except units.UnitError as exc:
                raise UsageError(f"runner: --duration: {exc}") from None
            if duration < 100_000_000:
                raise UsageError("runner: --duration must be at least 100ms")
        return cls(duration, ns.cell, ns.out, ns.follow, ns.allow_degraded, ns.allow_priority_99,
                   ns.quiet or env.get("CI", "") not in ("", "0", "false"), ["runner"] + sys.argv[1:])


def exit_code(statuses: list[Status]) -> ExitCode:
    """The one place a run's outcome becomes an exit code."""
    status = worst(statuses)
    return {
        Status.PASSED: ExitCode.OK,
        Status.DEGRADED: ExitCode.OK,
        Status.FAILED: ExitCode.EXPECTATION_FAILED,
        Status.ERROR: ExitCode.RUN_ERROR,
        Status.INTERRUPTED: ExitCode.INTERRUPTED,
    }[status]


class _Progress:
    """A live line on a terminal; nothing in logs (CI), where per-cell summaries suffice."""

    def __init__(self, enabled: bool):
        self.enabled = enabled and sys.stderr.isatty()
        self.width = 0

    def __call__(self, text: str) -> None:
        if self.enabled:
            sys.stderr.write("\r" + text.ljust(self.width))
            sys.stderr.flush()
            self.width = len(text)

    def clear(self) -> None:
        if self.enabled and self.width:
            sys.stderr.write("\r" + " " * self.width + "\r")
            sys.stderr.flush()
            self.width = 0


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise Interrupted(None)


def run_scenario(loaded: LoadedScenario, options: RunOptions) -> int:
    """Run every selected cell of `loaded`; write results after each; return the exit code."""
    cells = [c for c in loaded.cells if not options.cells or any(fnmatch.fnmatchcase(c.id, g) for g in options.cells)]
    if not cells:
        raise UsageError(f"runner: no cell matches {', '.join(options.cells)}; cells: {', '.join(c.id for c in loaded.cells)}")
    start = kernel.current_settings()
    perms = preflight([c.scenario for c in cells], start, options.allow_degraded, options.allow_priority_99)
    for problem in perms.missing:
        print(f"runner: warning: {problem}; running degraded", file=sys.stderr)

    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    folder = options.out or os.path.join("reports", loaded.name, stamp)
    os.makedirs(folder, exist_ok=True)
    results_path = os.path.join(folder, "results.json")
    machine = machine_info()
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "tool": {"name": "runner", "version": __version__},
        "scenario": {"name": loaded.name, "path": loaded.path, "description": loaded.description},
        "command": options.command,
        "started_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "finished_at": None,
        "status": "running",
        "machine": machine,
        "permissions": perms.to_json(),
        "start_settings": {"policy": start.policy.value, "priority": start.priority, "nice": start.nice},
        "cells": [],
    }
    write_atomic(results_path, json.dumps(doc, indent=2))
    progress = _Progress(not options.quiet)
    follow = (lambda line: (progress.clear(), print(line, flush=True))) if options.follow else None
    old_term = signal.signal(signal.SIGTERM, _raise_interrupt)
    watchdog = _probe.Watchdog(99)  # above every scenario thread: priority 99 needs --allow-priority-99
    statuses: list[Status] = []
    print(f"{loaded.name}: {len(cells)} cell{'s' if len(cells) != 1 else ''}, results in {results_path}", flush=True)
    try:
        for cell in cells:
            duration = options.duration_ns or cell.scenario.duration
            cell_options = CellOptions(duration, options.allow_degraded, follow, progress if not options.follow else None)
            interrupted = False
            try:
                result = run_cell(cell, os.path.join(folder, "cells", slug(cell.id)), start, cell_options, watchdog)
            except Interrupted as exc:
                if not isinstance(exc.args[0], CellResult):
                    raise
                result, interrupted = exc.args[0], True
            result.machine = machine
            progress.clear()
            sys.stdout.write(render_cell(result, kernel.pid_width()))
            sys.stdout.flush()
            statuses.append(result.status)
            doc["cells"].append(result.to_json())
            write_atomic(results_path, json.dumps(doc, indent=2))
            if interrupted:
                break
    except (KeyboardInterrupt, Interrupted):
        statuses.append(Status.INTERRUPTED)
    finally:
        progress.clear()
        watchdog.close()
        signal.signal(signal.SIGTERM, old_term)
        doc["finished_at"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
        doc["status"] = worst(statuses).value
        write_atomic(results_path, json.dumps(doc, indent=2))
    code = exit_code(statuses)
    print(f"{loaded.name}: {worst(statuses).value}; results: {results_path}", flush=True)
    return int(code)
