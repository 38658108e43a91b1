"""Everything the runner shows on a terminal, through one writer.

`say` (results, the things a user asked for) goes to stdout, `note` (progress, warnings,
problems) to stderr; both look the streams up at call time, so a caller that redirects
them (tests, `runner report -o -`) gets everything.  `Progress` keeps the live line out
of the way of both.

The writer is imported by every command, `runner --version` included, and sits at the bottom
of the house: it imports nothing of the stages above (a cell's table is drawn by
`runner.report.cellview`, which hands its text to `say`).
"""

from __future__ import annotations

import errno
import os
import sys
from typing import TYPE_CHECKING, Optional

from runner.printable import for_terminal, lines_for_terminal

if TYPE_CHECKING:
    from runner.runorder import Unit

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
