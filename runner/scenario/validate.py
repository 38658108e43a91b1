"""Turn pydantic validation errors into `file:line:col: key.path: message` problems.

Pydantic reports locations as tuples that mix data keys with union tags; this
module maps them back onto the user's data (and so onto source lines), and
rewrites the messages users meet most (unknown keys, wrong choices) with the
expected values and a "did you mean".
"""

from __future__ import annotations

import types
import typing
from typing import Any, Union, cast, get_args, get_origin

from pydantic import BaseModel, ValidationError

from runner.errors import Problem, closest, did_you_mean
from runner.scenario.model import PROGRAM_TAG, WORKERS_TAG, KeyProblem, ProcessSpec, ProgramSpec
from runner.scenario.yamlsource import Document, Path

_SCALARS = (str, int, float, bool)
PROCESS_TAGS: dict[str, type[BaseModel]] = {PROGRAM_TAG: ProgramSpec, WORKERS_TAG: ProcessSpec}


def _data_path(data: Any, loc: tuple[Any, ...]) -> tuple[Path, Any]:
    """Follow `loc` through `data`, skipping union tags; return the path and the value found."""
    path: list[str | int] = []
    node: Any = data
    skip = 0
    tagged = False  # the union tag of this node is passed: `kind: phases` with a key `phases` as well
    for n, elem in enumerate(loc):
        if skip:
            skip -= 1
            continue
        if _events_shorthand(node, loc[n:]):
            skip = 1  # `events:` written directly under the work is its one phase: phases[0].events is events
            continue
        if isinstance(node, dict) and not tagged and node.get("kind") == elem:
            tagged = True  # pydantic names a tagged union's member right after the field: a tag, not the key
            continue
        if (isinstance(node, dict) and isinstance(elem, str) and elem in node) or (
            isinstance(node, list) and isinstance(elem, int) and 0 <= elem < len(node)
        ):
            node = cast(Any, node)[elem]  # a key of this dict or an index of this list, as just checked
            path.append(elem)
            tagged = False
        elif isinstance(node, dict) and isinstance(elem, str) and not _is_tag(elem, node):
            path.append(elem)  # a missing or unknown key: point at the parent
            node = None
        # otherwise a union tag such as 'periodic' or 'list[int]': not part of the data
    return tuple(path), node


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


def _existing(value: Any, path: Path) -> Path:
    """The longest start of `path` that exists in `value`: where a KeyProblem can point."""
    out: list[str | int] = []
    for elem in path:
        if (isinstance(value, dict) and elem in value) or (isinstance(value, list) and isinstance(elem, int) and 0 <= elem < len(value)):
            value = cast(Any, value)[elem]  # a key of this dict or an index of this list, as just checked
        else:
            break
        out.append(elem)
    return tuple(out)


def _is_tag(elem: str, node: dict[str, Any]) -> bool:
    return node.get("kind") == elem or "[" in elem or elem.startswith("function-")


def _unwrap(tp: Any) -> Any:
    while get_origin(tp) is typing.Annotated:
        tp = get_args(tp)[0]
    if get_origin(tp) in (Union, types.UnionType):
        members = [a for a in get_args(tp) if a is not type(None)]
        if len(members) == 1:
            return _unwrap(members[0])
    return tp


def _fields_at(root: type[BaseModel], loc: tuple[Any, ...]) -> list[str] | None:
    """Field names of the model found at `loc`, or None where it cannot be told."""
    tp: Any = root
    for elem in loc:
        tp = _unwrap(tp)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            if isinstance(elem, str) and elem in tp.model_fields:
                tp = tp.model_fields[elem].annotation
                continue
            return None
        origin = get_origin(tp)
        if origin in (list, tuple) and isinstance(elem, int):
            tp = get_args(tp)[0]
        elif origin is dict:
            tp = get_args(tp)[1]
        elif origin in (Union, types.UnionType) and elem in PROCESS_TAGS:
            tp = PROCESS_TAGS[elem]
        elif origin in (Union, types.UnionType):
            for member in get_args(tp):
                member = _unwrap(member)
                if isinstance(member, type) and issubclass(member, BaseModel):
                    kind = member.model_fields.get("kind")
                    if kind is not None and kind.default == elem:
                        tp = member
                        break
            else:
                return None
        else:
            return None
    tp = _unwrap(tp)
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return list(tp.model_fields)
    return None


def _typo_targets(errors: list[Any], root: type[BaseModel]) -> set[tuple[Any, ...]]:
    """The required keys an unknown key is a typo of: each as the location pydantic says it is missing at.

    `sched: {polcy: fifo}` is one mistake that pydantic reports twice: an unknown key `polcy` and a
    missing key `policy` in the same mapping.  The unknown key's "did you mean 'policy'?" already
    says both, so the missing key's error is redundant there (and only there: a required key left out
    with no typo near it is still reported).
    """
    targets: set[tuple[Any, ...]] = set()
    for err in errors:
        if err["type"] == "extra_forbidden":
            loc = tuple(err["loc"])
            meant = closest(str(loc[-1]), _fields_at(root, loc[:-1]) or [])
            if meant is not None:
                targets.add((*loc[:-1], meant))
    return targets


def problems_from(exc: ValidationError, doc: Document, data: Any, root: type[BaseModel], prefix: Path = ()) -> list[Problem]:
    """One Problem per pydantic error, located in `doc`; a missing key that an unknown key is a typo of is left out."""
    out: list[Problem] = []
    errors = exc.errors(include_url=False)
    typos = _typo_targets(errors, root)
    for err in errors:
        loc = tuple(err["loc"])
        if err["type"] == "missing" and loc in typos:
            continue  # said by the unknown key's "did you mean"
        path, value = _data_path(data, loc)
        full = prefix + path
        kind = err["type"]
        given = err.get("input")
        ctx = err.get("ctx") or {}
        key = False
        if kind == "extra_forbidden":
            name = str(loc[-1])
            fields = _fields_at(root, loc[:-1]) or []
            hint = did_you_mean(name, fields)
            expected = f"; expected one of: {', '.join(fields)}" if fields and not hint else ""
            message = f"unknown key {name!r}{hint}{expected}"
            key = True
        elif kind == "missing":
            message = f"missing required key {str(loc[-1])!r}"
        elif kind in ("union_tag_invalid", "union_tag_not_found"):
            tags = [t.strip("' ") for t in str(ctx.get("expected_tags", "")).split(",") if t.strip()]
            if kind == "union_tag_not_found":
                message = f"missing 'kind'; expected one of: {', '.join(tags)}"
            else:
                tag = ctx.get("tag")
                message = f"unknown kind {tag!r}{did_you_mean(str(tag), tags)}; expected one of: {', '.join(tags)}"
            if isinstance(value, dict) and "kind" in value:
                full = full + ("kind",)
        elif kind == "enum":
            choices = [c.strip("' ") for c in str(ctx.get("expected", "")).replace(" or ", ", ").split(",") if c.strip()]
            message = f"{given!r} is not valid{did_you_mean(str(given), choices)}; expected one of: {', '.join(choices)}"
        elif kind == "value_error":
            error = ctx.get("error")
            message = str(error if error is not None else err["msg"])
            if isinstance(error, KeyProblem):
                full = full + _existing(value, error.path)  # a rule checked on the whole object, caused by this key
        else:
            message = err["msg"][0].lower() + err["msg"][1:]
            if isinstance(given, _SCALARS) and not isinstance(given, dict):
                message += f", got {given!r}"
            if kind == "string_type" and isinstance(given, bool):  # YAML 1.1 reads yes/no/on/off as booleans
                message += "; YAML reads an unquoted yes, no, on, off, true or false as a boolean: quote it ('off') to keep the word"
        out.append(doc.problem(full, message, key=key))
    return out
