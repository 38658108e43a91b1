"""The converted scenario: plain data written as readable YAML, its problems located in the rt-app file.

`Conversion` is what `runner.scenario.rtapp.convert` gives: the scenario, the notes on what
did not map exactly (a comment header of the YAML), and where each part came from, so that
a problem of the scenario is said at the line of the JSON to edit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Optional

import yaml

from runner.errors import Problem
from runner.scenario.rtappevents import At
from runner.scenario.yamlsource import Document, Mark, Path, dotted, load_text, printable


@dataclass(frozen=True)
class Conversion:
    """An rt-app workload as a scenario (plain data, as a YAML file holds it) and what did not map exactly."""

    scenario: dict[str, Any]
    notes: list[str]
    source: str = ""
    origins: dict[Path, At] = field(default_factory=dict)  # where each thread, work, phase, event and resource came from
    locate: Optional[Callable[[At], tuple[int, int]]] = None  # the line and column of a place in the file

    def document(self, file: str) -> Document:
        """The scenario loaded from its YAML, its problems located in the rt-app file `file` (a direct run of the JSON)."""
        doc = load_text(self.yaml(), f"{file} (as `runner import-rtapp` converts it)")
        if self.locate is None:
            return doc
        return _JsonDocument(file, doc.data, origins=self.origins, locate=self.locate)

    def yaml(self) -> str:
        """The scenario as readable YAML, with the notes as a comment header."""
        origin = f" from {printable(self.source)}" if self.source else ""
        head = [f"# Converted{origin} by `runner import-rtapp` (rt-app workload -> runner scenario)."]
        if self.notes:
            head.append("# What rt-app does that this scenario does differently, or not at all:")
            head.extend(f"#   - {printable(note)}" for note in self.notes)
        body = yaml.dump(_flowing(self.scenario), Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=120, allow_unicode=True)
        return "\n".join(head) + "\n" + body


@dataclass
class _JsonDocument(Document):
    """A converted scenario whose problems are located in the rt-app file it came from.

    A problem the scenario's checks find (a mutex held from one phase into the next) is said at
    the line of the task, phase or event it came from, by the file's key path, with the path of
    the scenario it converts to: that is the line to edit, not one of a text the user never saw."""

    origins: dict[Path, At] = field(default_factory=dict)
    locate: Callable[[At], tuple[int, int]] = lambda at: (1, 1)

    def _origin(self, path: Path) -> At:
        path = tuple(path)
        while path and path not in self.origins:
            path = path[:-1]
        return self.origins.get(path, At())

    def mark(self, path: Path, *, key: bool = False) -> Mark:
        return Mark(*self.locate(self._origin(path)))

    def problem(self, path: Path, message: str, *, key: bool = False, severity: str = "error") -> Problem:
        at = self._origin(path)
        line, col = self.locate(at)
        scenario = dotted(tuple(path))
        text = f"{message} (the converted scenario's {scenario})" if scenario else message
        return Problem(self.file, line, col, str(at), printable(text), severity)


class _Flow(dict[str, Any]):
    """A mapping written on one line (`{run: 10ms}`), for events and resources."""


class _Dumper(yaml.SafeDumper):
    pass


def _represent_str(dumper: yaml.SafeDumper, value: str) -> yaml.Node:
    style = "|" if "\n" in value else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=style)


def _represent_flow(dumper: yaml.SafeDumper, value: _Flow) -> yaml.Node:
    return dumper.represent_mapping("tag:yaml.org,2002:map", value.items(), flow_style=True)


_Dumper.add_representer(str, _represent_str)
_Dumper.add_representer(_Flow, _represent_flow)


def _flowing(value: Any, parent: str = "") -> Any:
    """A copy of the scenario with events and resource definitions marked to be written on one line."""
    if isinstance(value, dict):
        if parent == "resources":
            return {k: _Flow(v) if isinstance(v, dict) else v for k, v in value.items()}
        return {k: _flowing(v, k) for k, v in value.items()}
    if isinstance(value, list):
        if parent == "events":
            return [_Flow(e) if isinstance(e, dict) else e for e in value]
        return [_flowing(v) for v in value]
    return value
