"""Safe YAML loading that remembers where every value came from.

PyYAML's safe loader is used for tokens and scalars, but mappings and sequences are
built here from the composed node tree so that

* every key path maps to its line and column (errors point at the offending line),
* duplicate keys are an error (PyYAML silently keeps the last one),
* mapping keys are the text the user wrote (`on:` stays "on", not True),
* only plain data comes out: no tags that build objects, no timestamps,
* aliases cannot blow up: expansion is bounded in node count, in characters (one long text
  aliased a thousand times is a gigabyte to every later stage) and in nesting depth, and an
  alias (or a `<<` merge) inside the node it refers to is an error, not endless recursion,
* any text at all gives problems, never an exception: control characters, lone surrogates,
  numbers past Python's limits and tags applied to text they cannot read are all reported,
  and problems never print a raw control character (a newline would forge another line).
"""

from __future__ import annotations

import functools
import re
import unicodedata
from dataclasses import dataclass, field
from typing import Any, Union

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from runner.errors import Problem, ScenarioError, quoted, special_file

Path = tuple[Union[str, int], ...]

MAX_BYTES = 1 << 20
MAX_DEPTH = 48
MAX_NODES = 100_000
MAX_CHARS = 4 * MAX_BYTES
"""Characters of text (keys and values) the file may expand to through its aliases: four times the largest file.

A file without aliases holds fewer than MAX_BYTES; a real scenario's aliases (shared settings,
a list of CPUs) repeat a few short values.  Past this the cost is the aliases' alone: 1.6 GB and
16 s for a 0.4 MB file of one long text aliased many times, before the guard.
"""
_MERGE_TAG = "tag:yaml.org,2002:merge"
_COLLECTION_TAGS = ("tag:yaml.org,2002:map", "tag:yaml.org,2002:seq")
_PLAIN_TYPES = (str, int, float, bool, type(None))
_SCALAR_TAGS = {f"tag:yaml.org,2002:{name}" for name in ("str", "int", "float", "bool", "null", "timestamp")}
# what PyYAML's constructors raise on text that does not read as the tag says (`!!int abc`,
# `!!bool maybe`, a 5000-digit integer past Python's int/str conversion limit)
_CONSTRUCT_ERRORS = (ValueError, KeyError, AttributeError, TypeError, OverflowError, IndexError)
_UNPRINTABLE = ("Cc", "Cf", "Cs", "Zl", "Zp")


def printable(text: str) -> str:
    """`text` with control, format and line-separator characters escaped (`\\n`, `\\x1b`, `\\u2028`).

    Problems are printed one per line; a raw newline or escape sequence from a hostile key
    or value would forge lines or drive the terminal.
    """
    if text.isprintable():
        return text
    return "".join(repr(char)[1:-1] if unicodedata.category(char) in _UNPRINTABLE else char for char in text)


def _surrogate(text: str) -> str | None:
    """The first lone UTF-16 surrogate in `text` (YAML's "\\ud800" escape makes one), or None."""
    found = _SURROGATE.search(text)
    return found.group() if found else None


_SURROGATE = re.compile("[\ud800-\udfff]")


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
        return Problem(self.file, mark.line, mark.col, dotted(path), printable(message), severity)


def dotted(path: Path) -> str:
    """`('processes', 0, 'main', 'sched')` -> `processes[0].main.sched`; odd keys are quoted: `a['x\\ny']`."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        elif str(part).isprintable() and str(part) and not any(c in str(part) for c in ".[]'\" "):
            out += ("." if out else "") + str(part)
        else:
            out += f"[{quoted(part)}]"
    return out


_Loader = Union[yaml.SafeLoader, yaml.CSafeLoader]


@functools.cache
def _loader_class() -> type[_Loader]:
    """The safe loader, used only to compose nodes and to construct scalars: libyaml's where it is safe.

    libyaml's parser (PyPI's PyYAML has it) composes a scenario 15 times faster than
    PyYAML's Python one, but it builds nodes by recursion in compiled code: only a libyaml
    that refuses nesting past 1,000 levels itself (0.2.6 on) cannot be made to overflow the
    stack by a file of `[`s.  An older one, or none, leaves PyYAML's parser, whose recursion
    Python bounds.
    """
    fast = getattr(yaml, "CSafeLoader", None)
    if fast is None:
        return yaml.SafeLoader
    try:
        yaml.compose("[" * 1001 + "]" * 1001, Loader=fast)
    except yaml.YAMLError:
        return fast
    return yaml.SafeLoader


def load_text(text: str, file: str) -> Document:
    """Load one YAML document from `text`; raise ScenarioError with every problem found."""
    try:
        size = len(text.encode("utf-8"))
    except UnicodeEncodeError as exc:  # a lone surrogate: no parser reads one, libyaml's cannot even be handed the text
        line, col = _position(text, exc.start)
        message = f"{text[exc.start]!r} is not a character (a lone UTF-16 surrogate); write the character itself"
        raise ScenarioError([Problem(file, line, col, "", f"invalid YAML: {message}")]) from None
    if size > MAX_BYTES:
        raise _too_large(file)
    loader_class = _loader_class()
    try:
        loader = loader_class(text)
        node = loader.get_single_node()
    except yaml.reader.ReaderError as exc:
        at = exc.position
        if loader_class is not yaml.SafeLoader:  # libyaml counts bytes of the UTF-8 text, PyYAML characters
            at = len(text.encode("utf-8")[:at].decode("utf-8", "ignore"))
        line, col = _position(text, at)
        raise ScenarioError(
            [
                Problem(
                    file,
                    line,
                    col,
                    "",
                    (
                        f"invalid YAML: character {chr(exc.character) if isinstance(exc.character, int) else exc.character!r}"
                        " is not allowed in YAML text; remove it, or write it as an escape inside double quotes"
                    ),
                )
            ]
        ) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        lines = text.splitlines()
        if "invalid Unicode character escape" in what:
            what += "; a \\u escape must name a character, and a lone UTF-16 surrogate such as \\ud800 is not one"
        if mark and mark.line < len(lines) and "${{" in lines[mark.line]:
            what += "; inside [...] or {...} quote a ${{ matrix.X }} reference, or use block style"
        raise ScenarioError([Problem(file, line, col, "", printable(f"invalid YAML: {what}"))]) from None
    except yaml.YAMLError as exc:
        raise ScenarioError([Problem(file, 1, 1, "", printable(f"invalid YAML: {exc}"))]) from None
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


def _position(text: str, offset: int) -> tuple[int, int]:
    """1-based line and column of character `offset` in `text`."""
    before = text[:offset]
    return before.count("\n") + 1, offset - (before.rfind("\n") + 1) + 1


def load_file(path: str) -> Document:
    """Read and load a YAML file; unreadable files are reported like any other problem."""
    if kind := special_file(path):
        raise ScenarioError([Problem(path, 1, 1, "", f"is {kind}, not a file; expected a scenario file (YAML)")])
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read file: {exc.strerror}")]) from None
    if len(raw) > MAX_BYTES:
        raise _too_large(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, col = byte_position(raw, exc.start)
        raise ScenarioError([Problem(path, line, col, "", f"not UTF-8 text: byte {raw[exc.start]:#04x} ({exc.reason})")]) from None
    return load_text(text, path)


def _too_large(file: str) -> ScenarioError:
    return ScenarioError([Problem(file, 1, 1, "", f"file is larger than {MAX_BYTES} bytes; is it really a scenario?")])


def byte_position(raw: bytes, offset: int) -> tuple[int, int]:
    """The 1-based line and column (in characters) of byte `offset` of `raw`, for a problem at a byte that is not text."""
    line_start = raw.rfind(b"\n", 0, offset) + 1
    return raw.count(b"\n", 0, offset) + 1, len(raw[line_start:offset].decode("utf-8", "replace")) + 1


class _Builder:
    def __init__(self, loader: _Loader, doc: Document):
        self.loader = loader
        self.doc = doc
        self.problems: list[Problem] = []
        self.nodes = 0
        self.chars = 0  # of the keys and scalars built, aliases counted each time they are used
        self.expanded = False  # past MAX_NODES or MAX_CHARS: said once, nothing more is built
        self.active: set[int] = set()  # ids of the collection nodes being built: an alias to one of them is a cycle

    def _mark(self, node: Node) -> Mark:
        return Mark(node.start_mark.line + 1, node.start_mark.column + 1)

    def _fail(self, node: Node, path: Path, message: str) -> None:
        mark = self._mark(node)
        self.problems.append(Problem(self.doc.file, mark.line, mark.col, dotted(path), printable(message)))

    def build(self, node: Node, path: Path, depth: int = 0) -> Any:
        """Plain data for `node`, counting nodes and depth and refusing an alias inside its own anchor."""
        if id(node) in self.active:
            self._fail(
                node,
                path,
                "an alias refers to a node that contains it (a recursive alias); an alias must refer to a complete node outside itself",
            )
            return None
        if isinstance(node, (MappingNode, SequenceNode)):
            self.active.add(id(node))
            try:
                return self._build(node, path, depth)
            finally:
                self.active.discard(id(node))
        return self._build(node, path, depth)

    def _build(self, node: Node, path: Path, depth: int) -> Any:
        self.nodes += 1
        if isinstance(node, ScalarNode):
            self.chars += len(node.value)
        elif isinstance(node, MappingNode):
            self.chars += sum(len(key.value) for key, _ in node.value if isinstance(key, ScalarNode))
        if self.nodes > MAX_NODES or self.chars > MAX_CHARS:
            if not self.expanded:
                self.expanded = True
                what = f"{MAX_NODES:,} values" if self.nodes > MAX_NODES else f"{MAX_CHARS:,} characters"
                why = "its aliases repeat too much (an alias bomb?); a scenario needs far less, write the values out or alias fewer"
                self._fail(node, (), f"the file expands to more than {what}; {why}")
            return None
        if depth > MAX_DEPTH:
            self._fail(node, path, f"nesting is too deep; at most {MAX_DEPTH} levels")
            return None
        self.doc.marks.setdefault(path, self._mark(node))
        if isinstance(node, (MappingNode, SequenceNode)) and node.tag not in _COLLECTION_TAGS:
            self._fail(node, path, f"unsupported YAML tag {quoted(node.tag)}; only plain data is allowed")
            return None
        if isinstance(node, MappingNode):
            return self._mapping(node, path, depth)
        if isinstance(node, SequenceNode):
            return [self.build(item, path + (i,), depth + 1) for i, item in enumerate(node.value)]
        assert isinstance(node, ScalarNode), node
        return self._scalar(node, path)

    def _scalar(self, node: ScalarNode, path: Path) -> Any:
        bad = _surrogate(node.value)
        if bad is not None:
            self._fail(node, path, f"{bad!r} is not a character (a lone UTF-16 surrogate); write the character itself")
            return None
        if node.tag == "tag:yaml.org,2002:int" and node.value.lower().lstrip("+-").startswith(("0b", "0x")):
            return node.value  # a CPU mask such as 0b1100 keeps its spelling; YAML would make it 12
        if node.tag not in _SCALAR_TAGS:
            self._fail(node, path, f"unsupported YAML tag {quoted(node.tag)}; only plain data is allowed")
            return None
        try:
            value = self.loader.construct_object(node, deep=True)
        except yaml.constructor.ConstructorError as exc:
            self._fail(node, path, f"unsupported YAML tag {quoted(node.tag)}: {exc.problem}; only plain data is allowed")
            return None
        except _CONSTRUCT_ERRORS:
            kind = node.tag.rpartition(":")[2]
            why = f"cannot be read as {kind} (too long, or not written as one); quote it to make it a string"
            self._fail(node, path, f"{quoted(node.value, 40)} {why}")
            return None
        if not isinstance(value, _PLAIN_TYPES):
            self._fail(node, path, f"value {quoted(node.value)} reads as a {type(value).__name__}; quote it to make it a string")
            return None
        return value

    def _mapping(self, node: MappingNode, path: Path, depth: int) -> dict[str, Any]:
        out: dict[str, Any] = {}
        own: set[str] = set()
        # merges first: a mapping's own keys win over merged ones, and so do their positions
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE_TAG:
                self._merge(value_node, path, depth, out, own)
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE_TAG:
                continue
            if not isinstance(key_node, ScalarNode):
                self._fail(key_node, path, "mapping keys must be plain strings")
                continue
            key = str(key_node.value)
            bad = _surrogate(key)
            if bad is not None:
                self._fail(key_node, path, f"key {quoted(key)} contains {bad!r}, which is not a character (a lone surrogate)")
                continue
            child = path + (key,)
            if key in own:
                first = self.doc.key_marks.get(child)
                where = f" (first at line {first.line})" if first else ""
                self._fail(key_node, child, f"duplicate key {quoted(key)}{where}; each key may appear once")
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
            merged = self.build(source, path, depth + 1)  # counted and cycle-checked like any node
            if not isinstance(merged, dict):
                continue
            for key, value in merged.items():
                if key not in own:
                    out.setdefault(key, value)
