"""Safe YAML loading that remembers where every value came from.

PyYAML's safe loader is used for tokens and scalars, but mappings and sequences are
built here from the composed node tree so that

* every key path maps to its line and column (errors point at the offending line),
* duplicate keys are an error (PyYAML silently keeps the last one),
* mapping keys are the text the user wrote (`on:` stays "on", not True),
* only plain data comes out: no tags that build objects, no timestamps,
* aliases cannot blow up: expansion is bounded in node count and nesting depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Union

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from .errors import Problem, ScenarioError

Path = tuple[Union[str, int], ...]

MAX_BYTES = 1 << 20
MAX_DEPTH = 48
MAX_NODES = 100_000
_MERGE_TAG = "tag:yaml.org,2002:merge"
_COLLECTION_TAGS = ("tag:yaml.org,2002:map", "tag:yaml.org,2002:seq")
_PLAIN_TYPES = (str, int, float, bool, type(None))


@dataclass(frozen=True)
class Mark:
    """A 1-based line and column in a source file."""

    line: int
    col: int


@dataclass
class Document:
    """Plain data loaded from YAML, with the source position of every key path."""

    file: str
    data: Any
    marks: dict[Path, Mark] = field(default_factory=dict)
    key_marks: dict[Path, Mark] = field(default_factory=dict)

    def mark(self, path: Path, *, key: bool = False) -> Mark:
        """Position of `path` (its key if `key`), or of its nearest known ancestor."""
        path = tuple(path)
        while True:
            if key and path in self.key_marks:
                return self.key_marks[path]
            if path in self.marks:
                return self.marks[path]
            if not path:
                return Mark(1, 1)
            path = path[:-1]

    def problem(self, path: Path, message: str, *, key: bool = False, severity: str = "error") -> Problem:
        """A Problem located at `path` in this document."""
        mark = self.mark(path, key=key)
        return Problem(self.file, mark.line, mark.col, dotted(path), message, severity)


def dotted(path: Path) -> str:
    """`('processes', 0, 'main', 'sched')` -> `processes[0].main.sched`."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


class _Loader(yaml.SafeLoader):
    """SafeLoader used only to compose nodes and to construct scalars."""


def load_text(text: str, file: str) -> Document:
    """Load one YAML document from `text`; raise ScenarioError with every problem found."""
    if len(text.encode("utf-8", "surrogateescape")) > MAX_BYTES:
        raise ScenarioError([Problem(file, 1, 1, "", f"file is larger than {MAX_BYTES} bytes; is it really a scenario?")])
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        lines = text.splitlines()
        if mark and mark.line < len(lines) and "${{" in lines[mark.line]:
            what += "; inside [...] or {...} quote a ${{ matrix.X }} reference, or use block style"
        raise ScenarioError([Problem(file, line, col, "", f"invalid YAML: {what}")]) from None
    except yaml.YAMLError as exc:
        raise ScenarioError([Problem(file, 1, 1, "", f"invalid YAML: {exc}")]) from None
    except RecursionError:
        raise ScenarioError([Problem(file, 1, 1, "", f"nesting is too deep; at most {MAX_DEPTH} levels")]) from None
    doc = Document(file, None)
    if node is None:
        raise ScenarioError([Problem(file, 1, 1, "", "the file is empty; expected a scenario mapping")])
    builder = _Builder(loader, doc)
    data = builder.build(node, ())
    loader.dispose()
    if builder.problems:
        raise ScenarioError(builder.problems)
    doc.data = data
    return doc


def load_file(path: str) -> Document:
    """Read and load a YAML file; unreadable files are reported like any other problem."""
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read file: {exc.strerror}")]) from None
    except UnicodeDecodeError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"not UTF-8 text: {exc.reason}")]) from None
    return load_text(text, path)


class _Builder:
    def __init__(self, loader: _Loader, doc: Document):
        self.loader = loader
        self.doc = doc
        self.problems: list[Problem] = []
        self.nodes = 0

    def _mark(self, node: Node) -> Mark:
        return Mark(node.start_mark.line + 1, node.start_mark.column + 1)

    def _fail(self, node: Node, path: Path, message: str) -> None:
        mark = self._mark(node)
        self.problems.append(Problem(self.doc.file, mark.line, mark.col, dotted(path), message))

    def build(self, node: Node, path: Path, depth: int = 0) -> Any:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            if self.nodes == MAX_NODES + 1:
                self._fail(node, (), f"document expands to more than {MAX_NODES} values (alias bomb?)")
            return None
        if depth > MAX_DEPTH:
            self._fail(node, path, f"nesting is too deep; at most {MAX_DEPTH} levels")
            return None
        self.doc.marks.setdefault(path, self._mark(node))
        if isinstance(node, (MappingNode, SequenceNode)) and node.tag not in _COLLECTION_TAGS:
            self._fail(node, path, f"unsupported YAML tag {node.tag!r}; only plain data is allowed")
            return None
        if isinstance(node, MappingNode):
            return self._mapping(node, path, depth)
        if isinstance(node, SequenceNode):
            return [self.build(item, path + (i,), depth + 1) for i, item in enumerate(node.value)]
        return self._scalar(node, path)

    def _scalar(self, node: ScalarNode, path: Path) -> Any:
        if node.tag == "tag:yaml.org,2002:int" and node.value.lower().lstrip("+-").startswith(("0b", "0x")):
            return node.value  # a CPU mask such as 0b1100 keeps its spelling; YAML would make it 12
        try:
            value = self.loader.construct_object(node, deep=True)
        except yaml.constructor.ConstructorError as exc:
            self._fail(node, path, f"unsupported YAML tag {node.tag!r}: {exc.problem}; only plain data is allowed")
            return None
        if not isinstance(value, _PLAIN_TYPES):
            self._fail(node, path, f"value {node.value!r} reads as a {type(value).__name__}; quote it to make it a string")
            return None
        return value

    def _mapping(self, node: MappingNode, path: Path, depth: int) -> dict[str, Any]:
        out: dict[str, Any] = {}
        own: set[str] = set()
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE_TAG:
                self._merge(value_node, path, depth, out, own)
                continue
            if not isinstance(key_node, ScalarNode):
                self._fail(key_node, path, "mapping keys must be plain strings")
                continue
            key = str(key_node.value)
            child = path + (key,)
            if key in own:
                first = self.doc.key_marks.get(child)
                where = f" (first at line {first.line})" if first else ""
                self._fail(key_node, child, f"duplicate key {key!r}{where}; each key may appear once")
                continue
            own.add(key)
            self.doc.key_marks[child] = self._mark(key_node)
            self.doc.marks[child] = self._mark(value_node)
            out[key] = self.build(value_node, child, depth + 1)
        return out

    def _merge(self, value_node: Node, path: Path, depth: int, out: dict[str, Any], own: set[str]) -> None:
        sources = value_node.value if isinstance(value_node, SequenceNode) else [value_node]
        for source in sources:
            if not isinstance(source, MappingNode):
                self._fail(source, path, "a '<<' merge takes a mapping or a list of mappings")
                continue
            merged = self._mapping(source, path, depth + 1)
            for key, value in merged.items():
                if key not in own:
                    out.setdefault(key, value)
