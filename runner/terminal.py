"""Everything the runner shows on a terminal, through one writer.

`say` (results, the things a user asked for) goes to stdout, `note` (progress, warnings,
problems) to stderr; both look the streams up at call time, so a caller that redirects
them (tests, `runner report -o -`) gets everything.  `Progress` keeps the live line out
of the way of both.  `render_cell` is pure: the ps-style table and a per-thread summary.

The writer is imported by every command, `runner --version` included, so the table code's
imports (tabulate, the results records and with them pydantic) wait until a cell is drawn.
"""

from __future__ import annotations

import errno
import os
import sys
from typing import TYPE_CHECKING, Optional

from runner.printable import for_terminal, lines_for_terminal

if TYPE_CHECKING:
    from runner import figures as fg
    from runner.results.document import CellResult
    from runner.runorder import Unit

_MARK = {"passed": "passed", "degraded": "DEGRADED", "failed": "FAILED", "error": "ERROR", "interrupted": "INTERRUPTED"}  # by Status value


_LOST: list[OSError] = []  # why stdout stopped taking output, once it did: a closed pipe, a full disk, no stdout at all


def say(text: str) -> None:
    """Output the user asked for (tables, reports, paths), on stdout, whole lines."""
    put(text if text.endswith("\n") else text + "\n")


def put(text: str) -> None:
    """Text as it is on stdout (a report to `-o -`, a converted file).

    Output that cannot be written never stops a command: a run whose stdout is a closed pipe
    (`runner s.yaml | head -1`) or a full disk still finishes its cells, its results and its
    report, and exits with its outcome.  Later output goes nowhere; `stdout_lost` says why.
    """
    if _LOST:
        return
    stream = sys.stdout
    try:
        if stream is None:  # started with standard output closed
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        stream.write(text)
        stream.flush()
    except OSError as exc:
        _LOST.append(exc)
        _discard(stream)


def _discard(stream: object) -> None:
    """Point the stream's descriptor at /dev/null, so what it still buffers is flushed there at exit, not reported."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        try:
            os.dup2(fd, stream.fileno())  # type: ignore[attr-defined]
        finally:
            os.close(fd)
    except (OSError, AttributeError, ValueError):
        pass


def stdout_lost() -> Optional[OSError]:
    """Why output to stdout stopped (the first error), or None while it is written."""
    return _LOST[0] if _LOST else None


def note(text: str) -> None:
    """Progress, warnings and problems, on stderr, so stdout stays clean to pipe.

    Each line as a terminal may get it (`printable.for_terminal`): a message quotes names
    from the scenario, the kernel and results files, which may hold escape sequences.
    """
    stream = sys.stderr
    if stream is None:
        return
    text = lines_for_terminal(text.removesuffix("\n"))
    try:
        stream.write(text + "\n")
        stream.flush()
    except OSError:
        pass  # nowhere left to say it; the exit code still does


def warn(text: str) -> None:
    note(f"runner: warning: {text}")


class Progress:
    """Cells done / total, ETA and the current cell: a live line on a terminal, plain lines in logs."""

    def __init__(self, total: int, settle_s: float, live: bool, quiet: bool):
        self.total, self.settle_s = total, settle_s
        self.live = live and sys.stderr.isatty()
        self.quiet = quiet
        self.done = 0
        self.spent: list[float] = []
        self.width = 0
        self.head = ""
        self.prefix = ""

    def eta(self, planned_s: float) -> str:
        left = self.total - self.done
        per = sum(self.spent) / len(self.spent) if self.spent else planned_s + 1.0
        seconds = int(left * (per + self.settle_s))
        return f"{seconds // 60}m{seconds % 60:02d}s"

    def start(self, unit: Unit, repeats: int, planned_s: float) -> None:
        rep = f" (repeat {unit.repeat + 1}/{repeats})" if repeats > 1 else ""
        self.prefix = f"[{self.done + 1}/{self.total}] {for_terminal(unit.cell)}{rep}"
        self.head = f"{self.prefix}, ETA {self.eta(planned_s)}"
        if self.live:
            self.line(self.head)
        elif not self.quiet:
            note(f"runner: {self.head}")

    def line(self, text: str) -> None:
        if self.live:
            text = text if text.startswith("[") else f"{self.prefix}: {text}"
            self._draw("\r" + text.ljust(self.width))
            self.width = len(text)

    def _draw(self, text: str) -> None:
        """The live line on the terminal; a terminal gone (SIGHUP, a closed ssh session) ends it, never the run."""
        try:
            sys.stderr.write(text)
            sys.stderr.flush()
        except (OSError, ValueError):
            self.live = False

    def finish(self, seconds: float) -> None:
        self.done += 1
        self.spent.append(seconds)
        self.clear()

    def clear(self) -> None:
        if self.live and self.width:
            self._draw("\r" + " " * self.width + "\r")
            self.width = 0


def _cell_value(value: fg.Number | None, fig: fg.Figure) -> str:
    """A figure in the terminal's table: durations in us (the header says so), means to two places."""
    from runner import figures as fg

    if value is None:
        return "-"
    if fig.is_duration:
        return f"{value / 1000:.1f}"
    if fig.unit is fg.Unit.PER_CALLBACK:
        return f"{value:.2f}"
    return f"{value:.1f}" if fig.unit is fg.Unit.PER_SECOND else str(value)


def render_cell(cell: CellResult, pid_width: int = 5) -> str:
    """Thread table, per-thread summary (the registry's figures that have a column), verdicts and degradations.

    Every name and reason in it (from the scenario, the kernel, a results file) as `for_terminal` shows it.
    """
    from tabulate import tabulate

    from runner import figures as fg
    from runner.report.fmt import fmt_figure, samples_words
    from runner.report.selection import TERMINAL_ROWS, lines_shown, ps_rows_shown, threads_shown, verdicts_shown
    from runner.results.pstable import render_ps

    warned = f", {len(cell.warnings)} warning{'s' if len(cell.warnings) > 1 else ''}" if cell.warnings else ""
    reason = f" - {cell.reason}" if cell.reason else ""
    out = [for_terminal(f"cell {cell.id}: {_MARK[cell.status.value]}{warned} ({cell.duration_s:.1f}s){reason}")]
    picked = threads_shown(cell, TERMINAL_ROWS)
    if cell.thread_table:
        ps_rows, _ = ps_rows_shown(cell.thread_table, picked)
        out.append("")
        out.extend("  " + line for line in render_ps(ps_rows, pid_width=pid_width).splitlines())
    periodic = [t for t in picked.threads if t.has_callbacks]
    if periodic:
        overloaded = not all(fg.kept_up(t.figures) for t in periodic)
        shown = [f for f in fg.REGISTRY if f.column and (overloaded or not f.overload)]
        headers = ["thread", "tid", "applied"] + [f"{f.column} us" if f.is_duration else str(f.column) for f in shown]
        rows = [
            [
                for_terminal(f"{t.name}{' (main)' if t.index == 0 else ''}"),
                str(t.tid),
                ", ".join(s.label() for s in t.callback_settings()) or "?",  # as read back where its callbacks ran
            ]
            + [_cell_value(fg.value(t.figures, f), f) for f in shown]
            for t in periodic
        ]
        out.append("")
        out.extend("  " + line for line in tabulate(rows, headers=headers, tablefmt="simple", disable_numparse=True).splitlines())
    if picked.hidden:
        out.append(f"  ({picked.note()})")
    verdicts, more = verdicts_shown(cell.expectations, TERMINAL_ROWS)
    for v in verdicts:
        if v.unmeasured:  # said in place of the value: "measured not measured" reads as nothing
            said = f"{v.thread}: {v.metric} {v.limit}: {v.unmeasured}"
        else:
            measured = fmt_figure(v.measured, v.figure.unit)
            if v.samples is not None:
                measured += f", of {samples_words(v.figure, v.samples)}"
            said = f"{v.thread}: {v.metric} {v.limit} (measured {measured}){' - ' + v.note if v.note else ''}"
        out.append(f"  {'ok  ' if v.passed else 'FAIL'} {for_terminal(said)}")
    if more:
        failed = sum(not v.passed for v in cell.expectations) - sum(not v.passed for v in verdicts)
        out.append(f"  ... {more:,} more verdicts ({failed:,} of them failed): see the report or results.json")
    degraded, more = lines_shown([f"{t.process}/{t.name}: {why}" for t in cell.threads for why in t.degraded], TERMINAL_ROWS)
    out.extend(f"  DEGRADED {for_terminal(line)}" for line in degraded)
    if more:
        out.append(f"  ... {more:,} more degraded settings: see the report or results.json")
    warnings, more = lines_shown(cell.warnings, TERMINAL_ROWS)
    out.extend(f"  WARNING {for_terminal(text)}" for text in warnings)
    if more:
        out.append(f"  ... {more:,} more warnings: see the report or results.json")
    return "\n".join(out) + "\n"
