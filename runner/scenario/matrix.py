"""Matrix expansion with the semantics of GitHub Actions `strategy.matrix`, and `${{ matrix.X }}` references.

Pure: takes plain data (and a Document only to say where a problem is), returns cells.

* Axes are every key except `include` and `exclude`; cells are their product, in
  declaration order.
* `exclude` removes every cell that matches all key/values of an entry.
* `include` adds its extra keys to every cell whose original values it does not
  contradict; an entry that fits no cell becomes a cell of its own.
* A reference that is the whole value keeps the value's type (`priority: ${{ matrix.prio }}`
  stays an integer); inside a longer string it is interpolated.

Caps hold however the cells come about: at most `MAX_CELLS` cells after exclude *and*
include, at most `MAX_ENTRIES` include and exclude entries, `MAX_KEYS` keys.  Matching uses
one bit mask per axis value, so expansion stays fast at the caps.  Matrix values end up in
cell ids, folder names and report headings: control characters (a newline) and nested
`${{ }}` references are refused.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field
from typing import Any, Union

from runner.errors import Problem, did_you_mean
from runner.scenario.model import control_character
from runner.scenario.yamlsource import Document, Path

MatrixValue = Union[str, int, float, bool]
MAX_CELLS = 4096
MAX_ENTRIES = 256  # include or exclude entries (GitHub Actions caps a whole matrix at 256 jobs)
MAX_KEYS = 64  # axes and include-only keys together
MAX_VALUE_CHARS = 256  # a matrix value is a word or a short setting, and it becomes part of cell ids
_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*")
KEY_WORDS = "a letter or _ followed by letters, digits, _ or -"
REFERENCE = re.compile(r"\$\{\{\s*(.*?)\s*\}\}")
_NAME = re.compile(r"^matrix\.([A-Za-z_][A-Za-z0-9_-]*)$")


@dataclass(frozen=True)
class Cell:
    """One combination of matrix values, with its readable, deterministic id."""

    id: str
    values: dict[str, MatrixValue]


@dataclass
class MatrixSpec:
    """The parsed `matrix:` block."""

    axes: dict[str, list[MatrixValue]] = field(default_factory=dict)
    include: list[dict[str, MatrixValue]] = field(default_factory=list)
    exclude: list[dict[str, MatrixValue]] = field(default_factory=list)

    def keys(self) -> list[str]:
        """Every key a cell can carry: axes first, then keys that only include adds."""
        out = list(self.axes)
        for entry in self.include:
            out.extend(key for key in entry if key not in out)
        return out


def format_value(value: MatrixValue) -> str:
    """How a matrix value is written in ids and interpolated strings (YAML spelling for booleans)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def cell_id(values: dict[str, MatrixValue]) -> str:
    """`policy=fifo,priority=80`; `default` for a scenario without a matrix."""
    return ",".join(f"{key}={format_value(val)}" for key, val in values.items()) or "default"


def _same(a: MatrixValue, b: MatrixValue) -> bool:
    return format_value(a) == format_value(b)


def parse(doc: Document, raw: Any, problems: list[Problem]) -> MatrixSpec:
    """Read the `matrix:` block; append problems rather than stopping at the first."""
    spec = MatrixSpec()
    base: Path = ("matrix",)
    if raw is None:
        return spec
    if not isinstance(raw, dict):
        problems.append(doc.problem(base, "expected a mapping of axes to lists of values"))
        return spec

    def scalar(value: Any, path: Path) -> bool:
        problem = value_problem(value)
        if problem is None:
            return True
        problems.append(doc.problem(path, problem))
        return False

    def key_ok(key: str, path: Path) -> bool:
        if _KEY.fullmatch(key):
            return True
        problems.append(doc.problem(path, f"matrix key {key!r} must be {KEY_WORDS}", key=True))
        return False

    for key, value in raw.items():
        path = base + (key,)
        if key in ("include", "exclude"):
            if not isinstance(value, list):
                problems.append(doc.problem(path, f"expected a list of mappings, got {type(value).__name__}"))
                continue
            if len(value) > MAX_ENTRIES:  # the entries are still read, so their keys count as defined
                problems.append(doc.problem(path, f"{len(value)} {key} entries; at most {MAX_ENTRIES}"))
            entries = spec.include if key == "include" else spec.exclude
            for i, entry in enumerate(value):
                if not isinstance(entry, dict) or not entry:
                    problems.append(doc.problem(path + (i,), "expected a non-empty mapping of matrix keys to values"))
                    continue
                for k, v in entry.items():
                    key_ok(k, path + (i, k))
                    scalar(v, path + (i, k))
                entries.append(dict(entry))  # kept even when wrong: its keys are defined, and problems stop expansion
            continue
        if not _KEY.fullmatch(key):
            problems.append(doc.problem(path, f"axis name {key!r} must be {KEY_WORDS}", key=True))
            continue
        if not isinstance(value, list) or not value:
            problems.append(doc.problem(path, "an axis needs a non-empty list of values, e.g. [fifo, rr]"))
            continue
        fine = [scalar(v, path + (i,)) for i, v in enumerate(value)]  # every bad value is reported
        if all(fine):
            seen: set[str] = set()
            for i, v in enumerate(value):
                if format_value(v) in seen:
                    problems.append(doc.problem(path + (i,), f"value {format_value(v)!r} appears twice in axis {key!r}"))
                seen.add(format_value(v))
        spec.axes[key] = list(value)  # kept even with a wrong value, so references to it are not reported too

    if len(spec.keys()) > MAX_KEYS:
        problems.append(doc.problem(base, f"the matrix has {len(spec.keys())} keys; at most {MAX_KEYS}"))
    for i, entry in enumerate(spec.exclude):
        for key in entry:
            if key not in spec.axes:
                hint = did_you_mean(key, spec.axes)
                problems.append(doc.problem(base + ("exclude", i, key), f"exclude names {key!r}, which is not an axis{hint}", key=True))
    return spec


def value_problem(value: Any) -> str | None:
    """What is wrong with `value` as a matrix value, or None if it is fine."""
    if isinstance(value, (bool, int)):
        return None
    if isinstance(value, float):
        return None if math.isfinite(value) else f"matrix value {value!r} is not a finite number"
    if not isinstance(value, str):
        return f"matrix values must be strings, numbers or booleans, got {value!r}"
    char = control_character(value)
    if char is not None:
        return f"matrix value {value!r} contains the control character {char!r}; it would break cell ids and report headings"
    if "${{" in value:
        return f"matrix value {value!r} contains a '${{{{' reference; matrix values are not expanded again"
    if len(value) > MAX_VALUE_CHARS:
        return f"matrix value of {len(value)} characters; at most {MAX_VALUE_CHARS}"
    return None


def _masks(combos: list[dict[str, MatrixValue]], axes: list[str]) -> dict[tuple[str, str], int]:
    """For each (axis, written value), the bit mask of the combos holding it."""
    masks: dict[tuple[str, str], int] = {}
    for n, combo in enumerate(combos):
        for axis in axes:
            key = (axis, format_value(combo[axis]))
            masks[key] = masks.get(key, 0) | 1 << n
    return masks


def _matching(masks: dict[tuple[str, str], int], every: int, rule: dict[str, MatrixValue], axes: dict[str, Any]) -> int:
    """Bit mask of the combos matching every axis key of `rule` (other keys are ignored)."""
    hit = every
    for key, value in rule.items():
        if key in axes:
            hit &= masks.get((key, format_value(value)), 0)
    return hit


def expand(doc: Document, spec: MatrixSpec, problems: list[Problem], warnings: list[Problem]) -> list[Cell]:
    """All cells of the matrix, in a deterministic order; dead excludes become warnings, and excludes that
    leave no cell (and no include adds one) a problem.

    The cap holds on the result, so include cannot grow a matrix past it; matching is by
    bit masks (one per axis value), O(entries x keys) big-integer operations.
    """
    combos: list[dict[str, MatrixValue]] = []
    if spec.axes:
        size = 1
        for values in spec.axes.values():
            size *= len(values)
        if size > MAX_CELLS:
            problems.append(doc.problem(("matrix",), f"the matrix has {size} cells; at most {MAX_CELLS}"))
            return []
        combos = [dict(zip(spec.axes, combo)) for combo in itertools.product(*spec.axes.values())]
    axes = list(spec.axes)
    masks = _masks(combos, axes)
    every = (1 << len(combos)) - 1
    excluded = 0
    for i, rule in enumerate(spec.exclude):
        hit = _matching(masks, every, rule, spec.axes)
        if not hit:
            warnings.append(doc.problem(("matrix", "exclude", i), "this exclude matches no cell", severity="warning"))
        excluded |= hit
    kept = [combo for n, combo in enumerate(combos) if not excluded >> n & 1]

    originals = _masks(kept, axes)
    every = (1 << len(kept)) - 1
    for entry in spec.include:
        fitted = _matching(originals, every, entry, spec.axes)
        extra = {k: v for k, v in entry.items() if k not in spec.axes}
        rest = fitted
        while rest:
            low = rest & -rest
            kept[low.bit_length() - 1].update(extra)
            rest ^= low
        if not fitted:
            kept.append(dict(entry))
    if combos and not kept:  # not `default`, the one cell of no matrix: its references would each be said to have no value
        problems.append(doc.problem(("matrix", "exclude"), "excludes every cell of the matrix; nothing would run", key=True))
        return []
    if len(kept) > MAX_CELLS:
        problems.append(
            doc.problem(("matrix", "include"), f"the matrix has {len(kept)} cells with its include entries; at most {MAX_CELLS}")
        )
        return []

    cells: list[Cell] = []
    seen: dict[str, int] = {}
    for combo in kept:
        ident = cell_id(combo)
        if ident in seen:
            problems.append(doc.problem(("matrix",), f"two cells have the same id {ident!r}; make include entries distinct"))
            continue
        seen[ident] = len(cells)
        cells.append(Cell(ident, combo))
    return cells or [Cell("default", {})]


def references(data: Any, path: Path = ()) -> list[tuple[Path, str]]:
    """Every `${{ ... }}` expression in `data` with its path, outside the matrix block itself."""
    found: list[tuple[Path, str]] = []
    if isinstance(data, dict):
        for key, value in data.items():
            if path == () and key == "matrix":
                continue
            found.extend(references(value, path + (key,)))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            found.extend(references(value, path + (i,)))
    elif isinstance(data, str):
        found.extend((path, expr) for expr in REFERENCE.findall(data))
    return found


def referenced_keys(data: Any) -> list[str]:
    """The matrix keys `data` refers to (`${{ matrix.x }}`), sorted: what `substitute` reads of a cell's values."""
    return sorted({m.group(1) for _, expr in references(data) if (m := _NAME.match(expr))})


def check_references(doc: Document, data: Any, spec: MatrixSpec, problems: list[Problem]) -> None:
    """Every reference names a defined key; every axis is referenced somewhere."""
    keys = spec.keys()
    referenced: set[str] = set()
    for path, expr in references(data):
        match = _NAME.match(expr)
        if not match:
            problems.append(doc.problem(path, f"unsupported expression '${{{{ {expr} }}}}'; only '${{{{ matrix.NAME }}}}' is allowed"))
            continue
        name = match.group(1)
        referenced.add(name)
        if name not in keys:
            known = ", ".join(keys) if keys else "none (there is no matrix)"
            problems.append(doc.problem(path, f"matrix.{name} is not defined{did_you_mean(name, keys)}; defined: {known}"))
    for axis in spec.axes:
        if axis not in referenced:
            problems.append(
                doc.problem(
                    ("matrix", axis),
                    f"axis {axis!r} is not referenced anywhere; use it as '${{{{ matrix.{axis} }}}}' or remove it",
                    key=True,
                )
            )


def substitute(data: Any, values: dict[str, MatrixValue], path: Path = ()) -> Any:
    """A copy of `data` with references replaced by this cell's values.

    A reference missing from this cell (an include-only key) is left in place; the
    caller reports it for the cell.
    """
    if isinstance(data, dict):
        return {k: (v if path == () and k == "matrix" else substitute(v, values, path + (k,))) for k, v in data.items()}
    if isinstance(data, list):
        return [substitute(v, values, path + (i,)) for i, v in enumerate(data)]
    if isinstance(data, str) and "${{" in data:
        whole = REFERENCE.fullmatch(data.strip())
        if whole:
            match = _NAME.match(whole.group(1))
            if match and match.group(1) in values:
                return values[match.group(1)]

        def repl(m: re.Match[str]) -> str:
            name = _NAME.match(m.group(1))
            if name and name.group(1) in values:
                return format_value(values[name.group(1)])
            return m.group(0)

        return REFERENCE.sub(repl, data)
    return data


def unresolved(data: Any, path: Path = ()) -> list[tuple[Path, str]]:
    """References still present after substitution (keys this cell does not have)."""
    return references(data, path)


def select(cells: list[Cell], where: dict[str, Any]) -> list[Cell]:
    """Cells whose values match `where` (a value or a list of accepted values per key)."""
    out = []
    for cell in cells:
        ok = True
        for key, wanted in where.items():
            accepted = wanted if isinstance(wanted, list) else [wanted]
            if key not in cell.values or not any(_same(cell.values[key], a) for a in accepted):
                ok = False
                break
        if ok:
            out.append(cell)
    return out
