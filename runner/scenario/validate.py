"""Turn the issues of a model check into `file:line:col: key.path: message` problems.

An issue's path is the model's: it follows the data after a shorthand was read into its mapping
form (`events:` under a work is `phases[0].events`, `sched: fifo:80` is a mapping).  This module
maps it back onto the data as written, and so onto source lines.
"""

from __future__ import annotations

from typing import Any, cast

from runner.errors import Problem
from runner.scenario.typed import Invalid
from runner.scenario.yamlsource import Document, Path


def _events_shorthand(node: Any, rest: tuple[Any, ...]) -> bool:
    """Whether `rest` (from `phases`) points into a work written with `events:` directly, as its one phase."""
    return rest[:1] == ("phases",) and isinstance(node, dict) and "phases" not in node and "events" in node and rest[1:3] == (0, "events")


def written_path(data: Any, path: tuple[Any, ...]) -> tuple[Any, ...]:
    """A model path as the file writes it: `work.phases[0].events` is `work.events` where the file uses that shorthand."""
    node: Any = data
    for i, elem in enumerate(path):
        if _events_shorthand(node, path[i:]):
            return path[:i] + path[i + 2 :]
        if isinstance(node, dict):
            node = node.get(elem)
        elif isinstance(node, list) and isinstance(elem, int) and 0 <= elem < len(node):
            node = node[elem]
        else:
            break
    return path


def data_path(data: Any, path: tuple[Any, ...]) -> Path:
    """Where a model path points in the data as written: as far as the data goes, plus the key a mapping lacks.

    A key the model's mapping form has but the written form does not (`samples.last` of `samples: last 0`,
    written as text) is left out: the problem is at what was written.
    """
    out: list[str | int] = []
    node: Any = data
    rest = tuple(written_path(data, path))
    for elem in rest:
        if (isinstance(node, dict) and elem in node) or (isinstance(node, list) and isinstance(elem, int) and 0 <= elem < len(node)):
            node = cast(Any, node)[elem]  # a key of this dict or an index of this list, as just checked
            out.append(elem)
        elif isinstance(node, dict):
            out.append(elem)  # a missing or unknown key: named, at its mapping
            break
        else:
            break
    return tuple(out)


def problems_from(exc: Invalid, doc: Document, data: Any, prefix: Path = ()) -> list[Problem]:
    """One Problem per issue of `exc`, located in `doc` (`data` is what was checked, at `prefix` in the document)."""
    return [doc.problem(prefix + data_path(data, issue.path), issue.message, key=issue.key) for issue in exc.issues]
