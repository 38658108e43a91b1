"""The command-line options several commands take, each declared once (as pip-tools' options.py declares its options).

An option's flags, the kind of value it takes (action, metavar, default) and so its name in
the parsed namespace are the same in every command that takes it: `runner run --junit F`
and `runner merge --junit F` cannot drift apart.  Its help is its own words, which a
command may say in its own where the option means something particular there
(`runner compare --junit` writes the comparison, not the outcome).  cli.py attaches them:
`OUT.add(parser, help=...)`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Union

Parser = Union[argparse.ArgumentParser, "argparse._ArgumentGroup"]


@dataclass(frozen=True)
class Option:
    """One option: its flags and value (`settings`: add_argument's keywords), its help (text, or a function that builds it)."""

    flags: tuple[str, ...]
    help: str | Callable[[], str] = ""
    settings: dict[str, Any] = field(default_factory=dict)

    def add(self, parser: Parser, help: str | None = None, **settings: Any) -> argparse.Action:
        """Add the option to `parser` (or an argument group), in this command's words if `help` is given.

        `settings` adds to the declared ones what one command alone asks (merge's `required` --out).
        """
        words = help if help is not None else self.help if isinstance(self.help, str) else self.help()
        return parser.add_argument(*self.flags, help=words, **{**self.settings, **settings})


def threshold_help() -> str:
    """--threshold's help, its defaults as the figure registry declares them (built only with a parser that has it)."""
    from runner.report.compare import DEFAULT_THRESHOLDS

    defaults = ", ".join(f"{t.figure} {t.describe()}" for t in DEFAULT_THRESHOLDS)
    return (
        "regression threshold FIGURE=LIMIT, e.g. latency.p99=+20%,+10us or involuntary.per_callback_mean=+0.5 "
        f"or latency.p99=off (repeatable; defaults: {defaults})"
    ).replace("%", "%%")


LAVA_HELP = "report each cell as a LAVA test set: lava-test-set and lava-test-case when on PATH, their lines otherwise"

OUT = Option(("--out",), settings={"metavar": "DIR"})
OUTPUT = Option(("-o", "--output"), settings={"metavar": "FILE"})
CELLS = Option(("--cell",), "only cells whose id matches (repeatable)", {"action": "append", "default": [], "metavar": "GLOB"})
BASELINE = Option(("--baseline",), settings={"metavar": "RESULTS"})
THRESHOLD = Option(("--threshold",), threshold_help, {"action": "append", "default": [], "metavar": "FIGURE=LIMIT"})
HISTORY = Option(
    ("--history",),
    "judge each figure against its own past nights on this host in the history FILE (SQLite, made when absent) or "
    "postgresql://URL, then add this night to it; a regression makes the exit code 1",
    {"metavar": "FILE|URL"},
)
JUNIT = Option(
    ("--junit",),
    "also write the outcome as JUnit XML to FILE (one test suite per cell; for GitLab, Jenkins, colcon, GitHub reporters)",
    {"metavar": "FILE"},
)
NO_PLOTS = Option(("--no-plots",), "no SVG plots", {"action": "store_true"})
NO_TRACE = Option(("--no-trace",), settings={"action": "store_true"})
LAVA = Option(("--lava",), LAVA_HELP, {"action": "store_true"})
ALLOW_PRIORITY_99 = Option(("--allow-priority-99",), settings={"action": "store_true"})
