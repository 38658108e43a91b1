"""Reading rt-app's relaxed JSON: comments, trailing commas, keys given twice, bare keys.

A hand-written pre-pass blanks comments and trailing commas in place and gives a bare key
`:""` (`Relaxed.position` maps offsets back, so a JSON error's line and column are the
file's), then `json.loads` builds every object as `Pairs`, all its (key, value) pairs in
order.  Positions of keys are looked up again only when a problem is reported.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from runner.errors import Problem, ScenarioError
from runner.scenario.model import control_character
from runner.scenario.rtappwords import MAX_BYTES, Pairs
from runner.scenario.yamlsource import printable

# ---------------------------------------------------------------------------- reading


class JsonSyntax(Exception):
    def __init__(self, offset: int, message: str):
        super().__init__(message)
        self.offset, self.message = offset, message


BARE_VALUE = ':""'  # what a bare key (`"suspend",`) is given: workgen fills an empty suspend with the thread's name


@dataclass(frozen=True)
class Relaxed:
    """rt-app text made strict JSON, and the way back from its offsets to lines and columns of the file."""

    source: str
    json: str
    inserted: tuple[int, ...] = ()  # offsets in `json` where BARE_VALUE was inserted

    def position(self, offset: int) -> tuple[int, int]:
        """1-based line and column in the file of character `offset` of the JSON text."""
        shift = 0
        for at in self.inserted:
            if offset >= at + len(BARE_VALUE):
                shift += len(BARE_VALUE)
            elif offset >= at:
                offset = at
                break
            else:
                break
        return line_col(self.source, offset - shift)


def relax(text: str) -> Relaxed:
    """`text` as strict JSON: comments and trailing commas blanked out, bare keys given an empty value.

    Comments become spaces (their line breaks stay) and trailing commas a space, so every other
    character keeps its offset; a key written alone (`"suspend",`, as workgen allows) is followed
    by `:""`, and `Relaxed.position` takes those insertions back out.  Strings are copied as
    written: a `//` inside a string is text.
    """
    out: list[str] = []
    inserted: list[int] = []
    containers: list[str] = []  # the open { and [, innermost last
    last = ""  # the last character that is neither space nor comment
    pending_comma = -1  # offset in `out` of a comma that a closing bracket would make trailing
    i, n = 0, len(text)
    while i < n:
        char = text[i]
        if char == '"':
            end = _string_end(text, i)
            is_key = containers[-1:] == ["{"] and last in ("{", ",")
            out.extend(text[i:end])
            i, last, pending_comma = end, '"', -1
            if is_key and text[_skip_blank(text, i) : _skip_blank(text, i) + 1] in (",", "}"):
                inserted.append(len(out))
                out.extend(BARE_VALUE)
            continue
        if text.startswith("/*", i) or text.startswith("//", i):
            end = _skip_comment(text, i)
            out.extend(c if c in "\r\n" else " " for c in text[i:end])
            i = end
            continue
        if char in "}]":
            if pending_comma >= 0:
                out[pending_comma] = " "
            if containers:
                containers.pop()
        elif char in "{[":
            containers.append(char)
        if char == ",":
            pending_comma = len(out)
        elif not char.isspace():
            pending_comma = -1
        if not char.isspace():
            last = char
        out.append(char)
        i += 1
    return Relaxed(text, "".join(out), tuple(inserted))


def _string_end(text: str, start: int) -> int:
    """Offset after the string that opens at `start` (the end of the text if it never closes)."""
    i, n = start + 1, len(text)
    while i < n and text[i] != '"':
        i += 2 if text[i] == "\\" else 1
    return min(i + 1, n)


def _skip_comment(text: str, start: int) -> int:
    """Offset after the comment that opens at `start`; a /* never closed is an error."""
    if text.startswith("//", start):
        end = text.find("\n", start)
        return len(text) if end < 0 else end
    end = text.find("*/", start + 2)
    if end < 0:
        raise JsonSyntax(start, "a /* comment is never closed with */")
    return end + 2


def _skip_blank(text: str, i: int) -> int:
    """Offset of the first character from `i` on that is neither space nor comment."""
    while i < len(text):
        if text[i].isspace():
            i += 1
        elif text.startswith("/*", i) or text.startswith("//", i):
            i = _skip_comment(text, i)
        else:
            break
    return i


def _no_constant(word: str) -> Any:
    raise JsonSyntax(-1, f"{word} is not a number rt-app can read")


def parse_relaxed(text: str, file: str) -> tuple[Any, Relaxed]:
    """rt-app's relaxed JSON as plain data (objects as `Pairs`), and the strict text it was read from.

    Raises ScenarioError with the line and column of the first syntax problem.
    """
    if len(text.encode("utf-8", "surrogatepass")) > MAX_BYTES:
        raise ScenarioError([Problem(file, 1, 1, "", f"file is larger than {MAX_BYTES} bytes; is it really an rt-app workload?")])
    text = " " + text[1:] if text.startswith("\ufeff") else text
    if not text.strip():
        raise ScenarioError([Problem(file, 1, 1, "", 'the file is empty; expected an rt-app workload: {"tasks": {...}}')])
    try:
        relaxed = relax(text)
    except JsonSyntax as exc:
        line, col = line_col(text, exc.offset)
        raise ScenarioError([Problem(file, line, col, "", exc.message)]) from None
    try:
        data = json.loads(relaxed.json, object_pairs_hook=Pairs, parse_constant=_no_constant)
    except JsonSyntax as exc:
        raise ScenarioError([Problem(file, 1, 1, "", exc.message)]) from None
    except json.JSONDecodeError as exc:
        line, col = relaxed.position(exc.pos)
        message = f"not JSON, even with comments, trailing commas and bare keys allowed: {exc.msg}"
        raise ScenarioError([Problem(file, line, col, "", message)]) from None
    except RecursionError:
        raise ScenarioError([Problem(file, 1, 1, "", "nesting is too deep for an rt-app workload")]) from None
    except ValueError as exc:  # a number past Python's limit on digits
        raise ScenarioError([Problem(file, 1, 1, "", printable(f"cannot read the file: {exc}"))]) from None
    return data, relaxed


def line_col(text: str, offset: int) -> tuple[int, int]:
    return text.count("\n", 0, offset) + 1, offset - (text.rfind("\n", 0, offset) + 1) + 1


_WS = re.compile(r"[ \t\n\r]*")


def locate_steps(clean: str, steps: tuple[int, ...]) -> int:
    """Offset of the key (in an object) or item (in an array) that `steps` lead to: pair and item indexes."""
    decoder = json.JSONDecoder()

    def ws(i: int) -> int:
        match = _WS.match(clean, i)
        return match.end() if match else i

    def skip_pairs(i: int, count: int) -> int:
        for _ in range(count):
            _, i = decoder.raw_decode(clean, i)  # the key, a JSON string
            _, i = decoder.raw_decode(clean, ws(ws(i) + 1))
            i = ws(ws(i) + 1)
        return i

    try:
        i = at = ws(0)
        for step in steps:
            if clean[i] == "{":
                i = at = skip_pairs(ws(i + 1), step)
                _, i = decoder.raw_decode(clean, i)  # the key, a JSON string
                i = ws(ws(i) + 1)
            elif clean[i] == "[":
                i = ws(i + 1)
                for _ in range(step):
                    _, i = decoder.raw_decode(clean, i)
                    i = ws(ws(i) + 1)
                at = i
            else:
                break
        return at
    except (IndexError, ValueError, RecursionError):
        return 0


def _comments(text: str) -> Iterator[str]:
    """The comments of rt-app text, in order, without their markers."""
    i, n = 0, len(text)
    while i < n:
        char = text[i]
        if char == '"':
            i += 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
        elif text.startswith("/*", i):
            end = text.find("*/", i + 2)
            end = n if end < 0 else end
            yield text[i + 2 : end]
            i = end + 1
        elif text.startswith("//", i):
            end = text.find("\n", i)
            end = n if end < 0 else end
            yield text[i + 2 : end]
            i = end
        i += 1


def first_comment(text: str) -> str:
    """The file's first comment as plain lines (its ` * ` margins removed), or empty."""
    for comment in _comments(text):
        lines = [re.sub(r"^\s*\*? ?", "", line).rstrip() for line in comment.splitlines()]
        body = "\n".join(lines).strip()
        body = "".join(c for c in body if c in "\n\t" or not control_character(c))
        if body:
            return body
    return ""
