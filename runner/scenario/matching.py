"""Which expectations judge a cell, and which planned threads an expectation names.

Pure.  Validation asks it (an expectation that names threads which can never have its
figure is refused: loader.py) and so does a run's evaluation (runner/run/evaluate.py), so
both read a scenario's `expect:` the same way.
"""

from __future__ import annotations

from collections.abc import Mapping

from runner.scenario import matrix as mx
from runner.scenario.model import Scenario
from runner.scenario.plan import PlannedThread


def expectations_for(scenario: Scenario, matrix: Mapping[str, mx.MatrixValue]) -> list[int]:
    """Indexes of the scenario's expectations that apply to the cell of these matrix values."""
    probe = mx.Cell("x", dict(matrix))
    return [i for i, exp in enumerate(scenario.expect) if not exp.cells or mx.select([probe], exp.cells)]


def match_threads(planned: list[PlannedThread], target: str) -> list[PlannedThread]:
    """Threads an expectation's `thread` names: `name` or `process/name`; numbered threads match their base name.

    Which of them an expectation judges: `loader.measure_problem` (validation) and `evaluate.judged_threads` (a run).
    """
    proc, sep, name = target.rpartition("/")
    return [t for t in planned if (not sep or t.process == proc) and name in (t.name, t.spec_name)]
