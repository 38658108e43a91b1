"""Reading results.json: refused, with every problem in `file:line:col: key.path:` form, unless well-formed."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from typing import Any, BinaryIO

from pydantic import (
    ValidationError,
)

from runner import __version__
from runner.errors import Problem, ScenarioError, special_file
from runner.results.document import LEGACY_SCHEMA, SCHEMA, CellResult, RunDocument, Status, worst
from runner.results.files import INT64, results_file, samples_path_problem, show_value
from runner.results.journal import journal_path, merge_journal
from runner.scenario.model import MAX_REPEAT
from runner.terminal import warn

# ---------------------------------------------------------------- reading a results file

MAX_DEPTH = 64  # JSON nesting a results file never needs; deeper is refused before anything recurses into it
MAX_BYTES = 512 << 20
"""The largest results.json (and cells journal) read: a larger one is refused before it is read.

A results file is read whole, and reading one takes about nine times its size in memory (a
16 MiB file of 1,000 cells of 10 threads: 145 MiB at peak), so this keeps a report, comparison
or merge under about 4.5 GiB.  A run writes 16 KiB or so per cell run of 10 threads: 30,000 such
cell runs (100 cells, 300 times each) fit.
"""
MAX_PROBLEMS = 20
_SCHEMA_NAME = re.compile(r"runner\.results/([0-9]{1,6})")


def load(path: str) -> RunDocument:
    """Read a results document, refusing anything that is not a well-formed results file.

    `path` may name the results file or the folder holding it.  A `runner.results/1` file is
    checked against its own shape and upgraded; a /2 file is read strictly.  Every refusal is a
    ScenarioError of `file:line:col: key.path: message` lines: not JSON, NaN or Infinity (never
    a figure), numbers out of range, the wrong shape or types, a newer schema, samples paths
    that leave the results folder.  What loads can be trusted by the report, comparison and merge.
    """
    path = results_file(path)
    if kind := special_file(path):
        raise ScenarioError([Problem(path, 1, 1, "", f"is {kind}, not a file; expected a results file (results.json) or its folder")])
    # The journal first: a run still going rewrites results.json with the journal's cells before it drops the
    # journal, so a journal read first never lacks cells a results.json read after it misses (its own are skipped).
    journal = journal_path(os.path.dirname(os.path.realpath(path)))
    journal_data = _journal_bytes(journal)
    try:
        with open(path, "rb") as handle:
            raw = _capped(path, handle, "a results file")
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read results: {exc.strerror}")]) from None
    data = parse_json(path, raw)
    if _schema_version(path, data) == 1:
        from runner.results.legacy import _V1File, upgrade_v1  # its models cost 17 ms to build: only for files of the first schema

        try:
            _V1File.model_validate(data)
        except ValidationError as exc:
            raise ScenarioError(validation_problems(path, exc)) from None
        data = upgrade_v1(data)
    text = _checked_text(path, data)
    try:
        doc = RunDocument.model_validate_json(text, strict=True)
    except ValidationError as exc:
        raise ScenarioError(validation_problems(path, exc)) from None
    doc.folder, doc.source = os.path.dirname(os.path.realpath(path)), path  # where the file is: a link to it (/dev/stdin) is not its folder
    if problem := _runs_asked(path, doc):
        raise ScenarioError([problem])
    journaled = journal_cells(journal, journal_data)
    problems = [
        Problem(
            journal,
            n,
            1,
            "",
            f"cell {c.id!r}{f' (repeat {c.repeat + 1})' if c.repeat else ''} is not one {path} was asked for; "
            "a journal holds the cells of the run beside it only",
        )
        for n, c in enumerate(journaled, start=1)
        if (doc.cell_ids and c.id not in doc.cell_ids) or c.repeat >= doc.plan.repeat
    ]
    if problems:
        raise ScenarioError(problems)
    doc.cells.extend(merge_journal(doc, journaled))
    problems = [
        Problem(path, 1, 1, f"cells.{c.id}.samples_file", why)
        for c in doc.cells
        if (why := samples_path_problem(c.samples_file, doc.folder))
    ]
    problems += _inconsistencies(path, doc)
    if problems:
        raise ScenarioError(problems)
    return doc


def _capped(path: str, handle: BinaryIO, what: str) -> bytes:
    """What `handle` holds, refused (ScenarioError) past MAX_BYTES: a file by its size, before any of it is read; a pipe as it is read."""
    if os.fstat(handle.fileno()).st_size > MAX_BYTES or len(raw := handle.read(MAX_BYTES + 1)) > MAX_BYTES:
        why = f"is larger than {MAX_BYTES >> 20} MiB, the most a results file or journal may be (reading one takes nine times that)"
        raise ScenarioError([Problem(path, 1, 1, "", f"{why}; is it really {what}?")])
    return raw


def _runs_asked(path: str, doc: RunDocument) -> Problem | None:
    """Why the cell runs `doc` asks for are more than any run asks for, before anything counts them one by one; None when not.

    A run refuses more than MAX_REPEAT cell runs (cells times --repeat), and a file asking for
    more (10^6 repeats of 2,000 cells in 44 KB) would have the report, comparison and merge
    count two billion of them.  A merge asks for none of its own (`RunDocument.planned_runs`).
    """
    runs = len(set(doc.cell_ids)) * doc.plan.repeat
    if doc.merged_from or runs <= MAX_REPEAT:
        return None
    why = (
        f"asks for {doc.plan.repeat:,} runs of each of {len(set(doc.cell_ids)):,} cells, {runs:,} cell runs; "
        f"no run asks for more than {MAX_REPEAT:,}"
    )
    return Problem(path, 1, 1, "plan.repeat", why)


def _inconsistencies(path: str, doc: RunDocument) -> list[Problem]:
    """What no run writes: a cell run twice, a run's status better than one of its cells'."""
    out: list[Problem] = []
    seen: set[tuple[str, int]] = set()
    for c in doc.cells:
        if (c.id, c.repeat) in seen:
            which = f" (repeat {c.repeat + 1})" if c.repeat else ""
            out.append(Problem(path, 1, 1, f"cells.{c.id}", f"cell{which} is in the file twice; a run records each cell run once"))
        seen.add((c.id, c.repeat))
    order = list(Status)
    for c in doc.cells:  # a cell is never better than its own verdicts and settings say, as the runner judges it
        failed = [v.metric + " of " + v.thread for v in c.expectations if not v.passed]
        degraded = [t.name for t in c.threads if t.degraded]
        floor = worst([Status.FAILED] * bool(failed) + [Status.DEGRADED] * bool(degraded) + [Status.PASSED])
        if order.index(c.status) > order.index(floor):
            why = f"expectation {failed[0]} failed" if failed else f"thread {degraded[0]} did not get its settings"
            out.append(Problem(path, 1, 1, f"cells.{c.id}.status", f"says {c.status.value}, but {why}; a cell is never better than that"))
    finished = doc.status in (Status.PASSED.value, Status.DEGRADED.value, Status.FAILED.value)
    if finished and (lacking := doc.missing_runs()):  # a run that finished holds every cell run it was asked for
        why = f"the run says {doc.status}, but {lacking:,} of the {len(doc.planned_runs()):,} cell runs it was asked for are not in it"
        out.append(Problem(path, 1, 1, "cells", why))
    if doc.status in {s.value for s in Status} and doc.cells:
        cells = worst([c.status for c in doc.cells])
        if list(Status).index(cells) < list(Status).index(Status(doc.status)):
            why = f"the run says {doc.status}, but a cell of it says {cells.value}; a run is never better than its cells"
            out.append(Problem(path, 1, 1, "status", why))
    return out


def _journal_bytes(path: str) -> bytes | None:
    """The journal at `path` as it is now; None when there is none."""
    if kind := special_file(path):
        raise ScenarioError([Problem(path, 1, 1, "", f"is {kind}, not a file; a cells journal is the file a run appends its cells to")])
    try:
        with open(path, "rb") as handle:
            return _capped(path, handle, "a cells journal")
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read the cells journal: {exc.strerror}")]) from None


def journal_cells(path: str, data: bytes | None = None) -> list[CellResult]:
    """The cells journaled at `path` (none if there is no journal), each line checked as strictly as results.json.

    `data`: the journal as read already.  A run appends one line at a time and syncs it before it
    writes the next, so a crash can damage the last line only, and nothing before it:
    - a last line without its newline was being written when the run died (or is being written
      now, by a run still going) and is left out, as the cell in flight always was;
    - a last line that is not JSON although it ends in a newline is what a crash can leave too (the
      line's blocks lost, the newline of a later write not): it is left out with a warning saying
      which cell, which `--resume` runs again;
    - any other line that cannot be read, and a last line that is JSON but not a cell (no crash
      writes that), is refused at its place: the journal was changed by something else than a run.
    """
    if data is None:
        data = _journal_bytes(path)
    if data is None:
        return []
    *lines, torn = data.split(b"\n")  # `torn`: what follows the last newline, b"" when the journal ends with one
    cells: list[CellResult] = []
    for number, line in enumerate(lines, start=1):
        try:
            parsed = parse_json(path, line)
        except ScenarioError as exc:
            if number == len(lines) and not torn:
                warn(f"{path}:{number}: {_dropped(line, exc.problems[0].message)}")
                break
            raise ScenarioError([dataclasses.replace(p, line=number, message=p.message + _CHANGED) for p in exc.problems]) from None
        problems = _journal_cell(path, parsed, cells)
        if problems:
            raise ScenarioError([dataclasses.replace(p, line=number) for p in problems])  # key paths are within the line's cell
    return cells


_CHANGED = (
    "; a run damages only the journal's last line, so this one was changed after it was written: restore the file, "
    "or delete the line and resume the run (--resume), which runs its cell again"
)


def _dropped(line: bytes, why: str) -> str:
    """What a warning says of a damaged last journal line: what is wrong, which cell it held (when its id can be read), what happens."""
    return (
        f"the last line is damaged ({why}; {len(line):,} bytes), as a run that died while writing it leaves it; "
        f"left out: {_damaged_cell(line)}, which runs again when the run is resumed (--resume)"
    )


_JOURNAL_ID = re.compile(rb'^\{"id":("(?:[^"\\]|\\.){1,240}")')  # a journal line starts with its cell's id (CellResult's first field)
_JOURNAL_REPEAT = re.compile(rb'"repeat":([0-9]{1,6}),"status":')


def _damaged_cell(line: bytes) -> str:
    """The cell a damaged journal line held, as far as its start can still be read (best effort: the rest may be gone)."""
    try:
        named = _JOURNAL_ID.search(line)
        cell_id = json.loads(named.group(1)) if named else None
    except ValueError:
        cell_id = None
    if not isinstance(cell_id, str):
        return "a cell whose id cannot be read"
    repeat = _JOURNAL_REPEAT.search(line)
    return f"cell {cell_id!r}" + (f" (repeat {int(repeat.group(1)) + 1})" if repeat and int(repeat.group(1)) else "")


def _journal_cell(path: str, data: Any, cells: list[CellResult]) -> list[Problem]:
    """Check one journal line's JSON as a cell and add it to `cells`; the problems found (on line 1: the caller places them)."""
    try:
        cells.append(CellResult.model_validate_json(_checked_text(path, data), strict=True))
    except ScenarioError as exc:
        return exc.problems
    except ValidationError as exc:
        return validation_problems(path, exc)
    return []


def _schema_version(path: str, data: Any) -> int:
    """1 or 2, from the file's `schema`; a newer one, or none, is refused saying what this runner reads."""
    schema = data.get("schema") if isinstance(data, dict) else None
    match = _SCHEMA_NAME.fullmatch(schema) if isinstance(schema, str) else None
    if match and int(match.group(1)) in (1, 2):
        return int(match.group(1))
    if match and int(match.group(1)) > 2:
        why = (
            f"{schema} is a newer results format than this runner ({__version__}) reads ({LEGACY_SCHEMA} and "
            f"{SCHEMA}); read it with a newer runner"
        )
    else:
        why = f"expected a {SCHEMA} (or {LEGACY_SCHEMA}) results file, got {show_value(schema)}"
    raise ScenarioError([Problem(path, 1, 1, "schema", why)])


def parse_json(path: str, raw: bytes) -> Any:
    """Strict JSON: UTF-8, no NaN/Infinity, numbers a float can hold, nesting at most MAX_DEPTH."""

    def where(exc: json.JSONDecodeError) -> Problem:
        return Problem(path, exc.lineno, exc.colno, "", f"not valid JSON: {exc.msg}")

    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ScenarioError([Problem(path, line, 1, "", "not UTF-8 text; expected a runner results.json")]) from None
    try:
        data = json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except json.JSONDecodeError as exc:
        raise ScenarioError([where(exc)]) from None
    except _NotANumber as exc:
        raise ScenarioError([Problem(path, 1, 1, "", str(exc))]) from None
    except (ValueError, RecursionError) as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"not a usable number or structure: {exc}")]) from None
    if _depth(data) > MAX_DEPTH:
        raise ScenarioError([Problem(path, 1, 1, "", f"nested more than {MAX_DEPTH} levels deep; not a results file")])
    return data


class _NotANumber(ValueError):
    """A JSON number runner never writes: NaN, Infinity, or one beyond what a float holds."""


def _refuse_constant(name: str) -> Any:
    raise _NotANumber(f"{name} is not a number; a figure is a number or null")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NotANumber(f"{text} is out of range for a number")
    return value


def _depth(data: Any) -> int:
    """How deeply `data` nests, counted a level at a time (a hostile file must not exhaust the stack).

    Stops counting past MAX_DEPTH: anything deeper is refused whatever its depth.
    """
    depth, level = 0, [data] if isinstance(data, (dict, list)) else []
    while level and depth <= MAX_DEPTH:
        depth += 1
        below: list[Any] = []
        for item in level:
            below.extend([v for v in (item.values() if isinstance(item, dict) else item) if isinstance(v, (dict, list))])
        level = below
    return depth


# the shortest integer beyond 64 bits has 19 digits (a float or a string with such a run only costs the walk)
_LONG_DIGITS = re.compile(r"[0-9]{19}")


def _checked_text(path: str, data: Any) -> str:
    """`data` as JSON text for strict validation; a ScenarioError if an integer in it is out of 64-bit range.

    An integer past Python's digit limit for text (a v1 figure scaled to ns) cannot become
    text at all; it is out of range too, and `range_problems` walks `data` to name it.
    """
    try:
        text: str | None = json.dumps(data)
    except ValueError:
        text = None
    problems = range_problems(path, data, text)
    if problems or text is None:
        raise ScenarioError(problems or [Problem(path, 1, 1, "", "holds a number too large to read; not a results file")])
    return text


def range_problems(path: str, data: Any, text: str | None = None) -> list[Problem]:
    """Integers a 64-bit field cannot hold, wherever they are: runner never writes one, and no reader should meet one.

    `text`, when given, is `data` as JSON: a document with no run of 19 digits in it holds no
    such integer, which spares the walk below (a string with such a run only costs the walk).
    """
    if text is not None and not _LONG_DIGITS.search(text):
        return []
    out: list[Problem] = []
    stack: list[tuple[Any, tuple[Any, ...]]] = [(data, ())]
    while stack and len(out) < MAX_PROBLEMS:
        item, loc = stack.pop()
        if isinstance(item, dict):
            stack.extend((v, loc + (k,)) for k, v in item.items())
        elif isinstance(item, list):
            stack.extend((v, loc + (i,)) for i, v in enumerate(item))
        elif isinstance(item, int) and not isinstance(item, bool) and not -INT64 <= item < INT64:
            out.append(Problem(path, 1, 1, _key_path(loc), f"{show_value(item)} is out of range; expected a 64-bit integer"))
    return sorted(out)


def validation_problems(path: str, exc: ValidationError) -> list[Problem]:
    """pydantic's errors as problems in `path` (key path, message, the value found); at most MAX_PROBLEMS."""
    problems = sorted({Problem(path, 1, 1, _key_path(err["loc"]), _message(err)) for err in exc.errors()})
    if len(problems) > MAX_PROBLEMS:
        last, more = problems[MAX_PROBLEMS - 1], len(problems) - MAX_PROBLEMS
        problems[MAX_PROBLEMS - 1] = dataclasses.replace(last, message=f"{last.message} (and {more} more problems)")
        del problems[MAX_PROBLEMS:]
    return problems


_TYPE_TAG = re.compile(r"(str|int|float|bool|list|dict|tuple)(\[.*\])?|function-.*|constrained-.*|json-or-python.*")


def _key_path(loc: tuple[Any, ...]) -> str:
    """pydantic's error location as a key path (`cells[0].threads[1].callbacks`), without its union tags."""
    out = ""
    for part in loc:
        if isinstance(part, str) and _TYPE_TAG.fullmatch(part):
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _message(err: Any) -> str:
    msg = str(err.get("msg", "invalid"))
    msg = msg[0].lower() + msg[1:] if msg else "invalid"
    msg = msg.removeprefix("value error, ")
    return msg if err.get("type") == "missing" else f"{msg}; got {show_value(err.get('input'))}"
