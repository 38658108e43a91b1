"""A cell's per-callback samples file (`samples.csv.gz`): its columns, and reading it back for plots and checks."""

from __future__ import annotations

import csv
import gzip
import zlib
from dataclasses import dataclass
from typing import Any

from runner.errors import Problem, ScenarioError
from runner.results.files import INT64, show_value

SAMPLE_COLUMNS = (
    "thread",
    "tid",
    "seq",
    "scheduled_ns",
    "wake_ns",
    "end_ns",
    "latency_ns",
    "burn_wall_ns",
    "nivcsw",
    "nvcsw",
    "minflt",
    "majflt",
    "cpu_start",
    "cpu_end",
    "missed",
)


@dataclass(frozen=True)
class SampleRow:
    """One callback of one thread, as stored in samples.csv.gz (times in ns)."""

    seq: int
    latency_ns: int
    nivcsw: int
    minflt: int
    cpu: int


def read_samples(path: str) -> dict[str, list[SampleRow]]:
    """Per-callback samples of a cell by thread key; empty when the file does not exist.

    A file that is there but unusable (not gzip, cut short, rows that are not numbers) is a
    ScenarioError naming the file and the line, not a traceback and not a silently empty plot.
    """
    out: dict[str, list[SampleRow]] = {}
    line = 1
    try:
        with gzip.open(path, "rt", encoding="utf-8", newline="") as handle:
            reader = csv.DictReader(handle)
            for record in reader:
                line = reader.line_num
                key, row = _sample_row(record)
                out.setdefault(key, []).append(row)
    except FileNotFoundError:
        return out
    except (OSError, EOFError, zlib.error) as exc:
        raise ScenarioError(
            [Problem(path, line, 1, "", f"cannot read samples: {exc}; expected a gzip'd CSV as runner writes it")]
        ) from None
    except (ValueError, csv.Error) as exc:
        raise ScenarioError([Problem(path, line, 1, "", f"not a samples row: {exc}")]) from None
    return out


def _sample_row(record: dict[Any, Any]) -> tuple[str, SampleRow]:
    """One CSV record as (thread key, SampleRow); ValueError saying which column is wrong."""

    def number(column: str) -> int:
        text = record.get(column)
        if text is None:
            raise ValueError(f"column {column} is missing; expected {', '.join(SAMPLE_COLUMNS)}")
        try:
            value = int(text)
        except ValueError:
            raise ValueError(f"{column} is {show_value(text)}; expected an integer") from None
        if not -INT64 <= value < INT64:
            raise ValueError(f"{column} is out of range; expected a 64-bit integer")
        return value

    key = record.get("thread")
    if key is None:
        raise ValueError("column thread is missing")
    return key, SampleRow(number("seq"), number("latency_ns"), number("nivcsw"), number("minflt"), number("cpu_end"))
