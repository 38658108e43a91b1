"""GitHub Actions workflow annotations for a run or a comparison: `::error file=...,line=...::message`.  Pure.

When a job's output has these lines, GitHub shows them on the run's summary and, for the
file and line given, beside the scenario in the pull request's diff:

- a failed expectation is an `error` at the line of the scenario that declares it (the
  results keep each expectation's line and column); one annotation per expectation, naming
  every cell it failed in, since a matrix repeats the same line;
- a cell that could not run, or was cut short, is an `error` on the scenario file;
- a regression against the baseline is a `warning` on the scenario file (no line declares
  a figure), one per compared figure, naming the cells;
- a cell's warnings and degraded settings are `warning`s on the scenario file.

GitHub shows at most 10 error and 10 warning annotations of a step; past that the tenth
says how many more there are, so the first failures are never drowned by the rest.
Escaping is GitHub's (actions/toolkit's `command.ts`): `%`, CR and LF in the message;
those and `:` and `,` in property values.  Before that, every line of a message and every
property is shown as a terminal may get it (`printable.for_terminal`): a thread's name
from the kernel may hold a newline, which would forge a line of the message, or an escape
sequence, which the job's log would interpret.  A message of several lines is made of
lines each made so.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

from runner.errors import Problem
from runner.printable import for_terminal, lines_for_terminal

if TYPE_CHECKING:  # the outcomes (and the report they word things as) load only when there is a run to annotate
    from runner.history.judge import NightVerdict
    from runner.report.compare import Comparison
    from runner.report.outcomes import CellChecks, Kind, Outcome
    from runner.results.document import RunDocument

PER_LEVEL = 10  # annotations GitHub shows per step and level


def escape_data(text: str) -> str:
    """A message as a workflow command carries it: `%`, CR and LF percent-encoded."""
    return text.replace("%", "%25").replace("\r", "%0D").replace("\n", "%0A")


def escape_property(text: str) -> str:
    """A property value (file, title): as `escape_data`, and `:` and `,`, which end a value."""
    return escape_data(text).replace(":", "%3A").replace(",", "%2C")


@dataclass(frozen=True)
class Annotation:
    """One workflow command: its level (`error`, `warning`, `notice`), where, a title and the message."""

    level: str
    message: str
    file: Optional[str] = None
    line: Optional[int] = None
    col: Optional[int] = None
    title: Optional[str] = None

    def command(self) -> str:
        """`::error file=scenarios/x.yaml,line=36,col=5,title=...::message`, escaped."""
        props = [
            f"{key}={escape_property(for_terminal(str(value)))}"
            for key, value in (("file", self.file), ("line", self.line), ("col", self.col), ("title", self.title))
            if value is not None and value != ""
        ]
        message = escape_data(lines_for_terminal(self.message))
        return f"::{self.level} {','.join(props)}::{message}" if props else f"::{self.level}::{message}"


def enabled(env: dict[str, str]) -> bool:
    """Annotations are printed inside GitHub Actions (`GITHUB_ACTIONS=true`) unless `RUNNER_ANNOTATIONS=off`."""
    return env.get("GITHUB_ACTIONS", "") == "true" and env.get("RUNNER_ANNOTATIONS", "").lower() not in ("off", "0", "false", "no")


def workspace_path(path: Optional[str], cwd: str, workspace: Optional[str]) -> Optional[str]:
    """`path` (as given on the command line, relative to `cwd`) as GitHub places annotations: relative to
    the workspace (the checkout) when inside it, else as given."""
    if not path:
        return None
    full = os.path.normpath(os.path.join(cwd, path))
    if workspace:
        root = os.path.normpath(workspace)
        if os.path.commonpath([full, root]) == root:
            return os.path.relpath(full, root)
    return path


def _cells(cells: Sequence[str]) -> str:
    return f"cell {cells[0]}" if len(cells) == 1 else f"{len(cells)} cells"


def for_run(
    doc: RunDocument, comparison: Optional[Comparison], file: Optional[str], run: bool = True, history: Optional[NightVerdict] = None
) -> list[Annotation]:
    """Every annotation of a run (`run` False: of the comparison alone), errors first, capped per level."""
    from runner.report.outcomes import Kind, Outcome, cell_checks

    suites = cell_checks(doc, comparison, run, history)
    errors = _grouped(suites, Kind.EXPECTATION, Outcome.FAILED, "error", "expectation failed", file)
    errors += [
        Annotation(
            "error", for_terminal(check.message), file, title=f"cell {suite.title}: {suite.status.value if suite.status else 'error'}"
        )
        for suite in suites
        for check in suite.checks
        if check.outcome is Outcome.ERROR
    ]
    warnings = _grouped(suites, Kind.BASELINE, Outcome.FAILED, "warning", "regression", file)
    warnings += _grouped(suites, Kind.HISTORY, Outcome.FAILED, "warning", "regression against the history", file)
    warnings += [Annotation("warning", for_terminal(note), file, title=f"cell {suite.title}") for suite in suites for note in suite.notes]
    return _capped(errors, "error") + _capped(warnings, "warning")


def _grouped(suites: Sequence[CellChecks], kind: Kind, outcome: Outcome, level: str, what: str, file: Optional[str]) -> list[Annotation]:
    """One annotation per check name and place, listing the cells it happened in (a matrix repeats a line)."""
    groups: dict[tuple[str, Optional[int], Optional[int]], list[tuple[str, str]]] = {}  # (name, line, col): [(cell, message)]
    for suite in suites:
        for check in suite.checks:
            if check.kind is kind and check.outcome is outcome:
                groups.setdefault((check.name, check.line, check.col), []).append((suite.title, check.message))
    out = []
    for (name, line, col), where in groups.items():
        cells = [title for title, _ in where]
        message = "\n".join(for_terminal(f"cell {title}: {text}") for title, text in where)  # a line each, whatever the names
        out.append(Annotation(level, message, file, line, col, f"{what} in {_cells(cells)}: {name}"))
    return out


def _capped(items: list[Annotation], level: str) -> list[Annotation]:
    if len(items) <= PER_LEVEL:
        return items
    rest = items[PER_LEVEL - 1 :]
    more = Annotation(
        level,
        f"{len(rest)} more {level} annotation(s), not shown (GitHub shows {PER_LEVEL} per step): "
        + "; ".join(a.title or a.message for a in rest[:20])
        + ("; ..." if len(rest) > 20 else "")
        + ". The report and the JUnit file have every one.",
        rest[0].file,
        title=f"{len(rest)} more",
    )
    return items[: PER_LEVEL - 1] + [more]


def for_problem(problem: Problem, file: Optional[str] = None) -> Annotation:
    """A problem in a file (`file:line:col: key.path: message`) as an annotation at its place; `file` as the workspace
    names it (`workspace_path`), when given."""
    level = {"warning": "warning", "note": "notice"}.get(problem.severity, "error")
    message = f"{problem.path}: {problem.message}" if problem.path else problem.message
    return Annotation(level, message, file or problem.file, problem.line, problem.col)
