"""The results folder on disk: cell folder names and the rule that stored paths stay inside it (writes: runner/safefs.py)."""

from __future__ import annotations

import hashlib
import os
import re
from typing import Any

INT64 = 2**63


SLUG_MAX = 120  # characters of the readable part; a file name stays well under NAME_MAX (255 bytes)
JOURNAL = "cells.jsonl"  # beside results.json: the cells a run finished since it last wrote results.json whole (results/journal.py)
_UNSAFE = re.compile(r"[^A-Za-z0-9_.=,+-]")


def slug(exact: str) -> str:
    """A file-system safe name that stands for `exact` alone: deterministic, injective, bounded.

    An id that is already a safe name (letters, digits and `_.=,+-`, not starting with a dot,
    at most SLUG_MAX characters) is its own name, so folders read as the cell ids they hold.
    Any other id keeps a readable version (unsafe characters as `_`, cut to SLUG_MAX) and adds
    `~` and a hash of the exact id: `a/b`, `a_b` and `a:b` get three folders, never one.
    Names of the first kind never contain `~`, so the two kinds cannot meet.
    """
    if exact and len(exact) <= SLUG_MAX and not exact.startswith(".") and not _UNSAFE.search(exact):
        return exact
    readable = _UNSAFE.sub("_", exact)[:SLUG_MAX].lstrip(".") or "_"
    digest = hashlib.sha256(exact.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return f"{readable}~{digest}"


def cell_dir(cell_id: str, repeat: int, repeated: bool) -> str:
    """A cell run's folder, relative to the results folder: `cells/<id>`, or `cells/<id>/repeat-<n>` with repeats."""
    base = os.path.join("cells", slug(cell_id))
    return os.path.join(base, f"repeat-{repeat + 1}") if repeated else base


def results_file(path: str) -> str:
    """The results.json that `path` names: the file itself, or the one inside a results folder."""
    return os.path.join(path, "results.json") if os.path.isdir(path) else path


def samples_path_problem(relative: str | None, folder: str) -> str:
    """Why a stored samples path may not be followed ("" when it may): it must stay in `folder`.

    Pure (no file access): absolute paths and `..` that climbs out are refused here; a symlink
    that leads out is caught when the file is about to be opened (`RunDocument.samples_path`).
    """
    if not relative:
        return ""
    expected = f"expected a path inside {folder or os.curdir}"
    if "\x00" in relative:
        return f"contains a NUL character; {expected}"
    if os.path.isabs(relative):
        return f"{relative!r} is an absolute path; {expected}"
    if os.path.normpath(relative).split(os.sep)[0] == os.pardir:
        return f"{relative!r} leaves the results folder; {expected}"
    return ""


def show_value(value: Any) -> str:
    """A value as a message quotes it: repr, or `dict of 3`, cut to 60 characters."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value).bit_length() > 64 * 8:
        return f"an integer of about {int(abs(value).bit_length() * 0.30103) + 1:,} digits"  # repr refuses past 4,300 digits
    text = repr(value) if not isinstance(value, (dict, list)) else f"{type(value).__name__} of {len(value)}"
    return text if len(text) <= 60 else text[:57] + "..."
