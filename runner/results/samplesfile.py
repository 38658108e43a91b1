"""A cell's per-callback samples file (`samples.csv.gz`): its columns, writing it as a stream, reading it back.

One row per callback: `scheduled_ns` is the release the callback served; `missed` the
releases it skipped just before; `latency_ns` runs from the oldest release the wake-up
answered (`scheduled_ns - missed * period`) to `wake_ns`; `slack_ns` from `end_ns` to the
next release (negative: it overran).  For programs (`kind: phases`) a row is an activation
(from a timer to the next), and `lock_wait_ns`, `cond_wait_ns` and `barrier_wait_ns` are
the time it spent blocked acquiring mutexes, in condition waits and at barriers (0 for
periodic work; files of earlier runners lack these columns).  A chain's later stage (a
program without a timer that suspends on a queue) has a row per activation too, from the
resume that released it (`scheduled_ns`) to its next suspend, with `slack_ns` empty: no
period says when its next release is due.  `chain_ns` runs from the timer release that
started the chain to the activation's end (empty outside a chain; files of earlier runners
lack it).  `period_ns` is the grid's step to the release (a program's timers may differ; 0:
released by a resume), the `period` above.  `lock_waits` splits an activation's lock wait by
mutex, as JSON (`{"m": {"wait_ns": .., "taken": .., "contended": .., "held_by": key}}`), empty
for an activation that locked none and for threads that lock no mutex.  Rows of several threads interleave in chunks, in
order within each thread; `seq` numbers a thread's callbacks from 0, so a gap shows rows
that were not written (`samples: outliers`, or a runner that fell behind).
"""

from __future__ import annotations

import csv
import gzip
import io
import os
import re
import tempfile
import zlib
from collections.abc import Collection, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO, Optional

from runner.errors import Problem, ScenarioError
from runner.results.files import INT64, show_value
from runner.safefs import FILE_MODE, check_target, sync_folder

SAMPLE_COLUMNS = (
    "thread",
    "tid",
    "seq",
    "scheduled_ns",
    "wake_ns",
    "end_ns",
    "latency_ns",
    "slack_ns",
    "burn_wall_ns",
    "nivcsw",
    "nvcsw",
    "minflt",
    "majflt",
    "cpu_start",
    "cpu_end",
    "missed",
    "lock_wait_ns",
    "cond_wait_ns",
    "barrier_wait_ns",
    "chain_ns",
    "period_ns",
    "lock_waits",
)


_BATCH = 1 << 16
"""Characters of rows collected before they are compressed: row by row, through a text wrapper, cost twice as much."""


class SamplesWriter:
    """Streams rows into a gzip'd CSV while the cell runs; the file appears under its name only when complete.

    Rows go to a temporary file beside the final one (a new file of a name of its own, never
    one that was there, nor through a link), renamed into place by `close`, which refuses a link
    at the final name; a write error (a full disk) is kept, not raised, so the run goes on (the
    figures do not depend on this file), and `close` raises it after removing the partial file.
    """

    def __init__(self, path: str):
        self.path = path
        self._tmp = ""
        self._raw: Optional[BinaryIO] = None
        self._gz: Optional[gzip.GzipFile] = None
        self._text = io.StringIO()  # rows, handed to gzip by the batch: a large cell writes a few rows per thread a tick
        self._csv: Any = None
        self.error: Optional[OSError] = None

    def _open(self) -> None:
        folder, name = os.path.split(self.path)
        fd, self._tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=folder or os.curdir)  # O_EXCL|O_NOFOLLOW
        self._raw = os.fdopen(fd, "wb")  # open across calls, closed by close() or abort()
        os.fchmod(fd, FILE_MODE)  # as any new file: not mkstemp's 0600
        self._gz = gzip.GzipFile(fileobj=self._raw, mode="wb", compresslevel=1, mtime=0)
        self._csv = csv.writer(self._text, lineterminator="\n")
        self._csv.writerow(SAMPLE_COLUMNS)

    def writerows(self, rows: Iterable[Sequence[object]]) -> None:
        if self.error is not None:
            return
        try:
            if self._csv is None:
                self._open()
            self._csv.writerows(rows)
            if self._text.tell() >= _BATCH:
                self._flush()
        except OSError as exc:
            self.error = exc
            self._discard()

    def close(self) -> None:
        """Finish the file and move it into place; raise the write error if there was one, naming the file (nothing is left behind)."""
        if self.error is None:
            try:
                if self._csv is None:
                    self._open()
                assert self._gz is not None and self._raw is not None
                self._flush()  # the header, when no row came
                self._gz.close()
                self._raw.flush()
                os.fsync(self._raw.fileno())
                self._raw.close()
                check_target(self.path)  # a link there is refused (the rename would replace it, never follow it)
                os.replace(self._tmp, self.path)
                folder = os.path.dirname(os.path.abspath(self.path))
                sync_folder(folder)  # the file's name, and its folder's (a cell's folder is made with it), last as results.json does
                sync_folder(os.path.dirname(folder))
                return
            except OSError as exc:
                self.error = exc
        self._discard()
        raise OSError(self.error.errno, self.error.strerror or str(self.error), self.path) from self.error  # named: its writes do not

    def _flush(self) -> None:
        """The rows written since the last call, compressed."""
        assert self._gz is not None
        self._gz.write(self._text.getvalue().encode())
        self._text.seek(0)
        self._text.truncate()

    def abort(self) -> None:
        """Give up on the file: remove what was written."""
        self._discard()

    def _discard(self) -> None:
        for handle in (self._gz, self._raw):
            try:
                if handle is not None:
                    handle.close()
            except OSError:
                pass
        self._gz = self._raw = self._csv = None
        self._text = io.StringIO()
        if self._tmp:
            try:
                os.unlink(self._tmp)
            except OSError:
                pass
            self._tmp = ""


@dataclass(frozen=True)
class SampleRow:
    """One callback of one thread, as stored in samples.csv.gz (times in ns)."""

    seq: int
    latency_ns: int
    nivcsw: int
    minflt: int
    cpu: int


_READ = ("seq", "latency_ns", "nivcsw", "minflt", "cpu_end")  # the columns a SampleRow keeps, in its order


def scan_samples(path: str, threads: Optional[Collection[str]] = None) -> Iterator[tuple[str, SampleRow]]:
    """A cell's per-callback samples as (thread key, row), in the file's order; only `threads`, when given; none without a file.

    A stream: nothing is kept, so reading the samples of an hour-long run takes the memory of
    reading a second of it (the plots keep a bounded digest of what they need).  A file that is
    there but unusable (not gzip, cut short, rows that are not numbers) is a ScenarioError
    naming the file and the line, not a traceback and not a silently empty plot; rows before
    it have been yielded.  Rows of threads not asked for are checked (integers where numbers
    belong) but not turned into rows, so plotting a few threads of a 256-thread cell costs a
    third of reading them all.
    """
    line = 1
    try:
        with gzip.open(path, "rt", encoding="utf-8", newline="") as handle:
            reader = csv.reader(handle)
            header = next(reader, None) or []
            for column in ("thread", *_READ):
                if column not in header:
                    raise ValueError(f"column {column} is missing; expected {', '.join(SAMPLE_COLUMNS)}")
            key_at, at = header.index("thread"), [header.index(c) for c in _READ]
            width = len(header)
            for record in reader:
                line = reader.line_num
                if len(record) != width:
                    raise ValueError(f"{len(record)} fields; expected {width}, as in the header")
                key = record[key_at]
                if threads is None or key in threads:
                    yield key, SampleRow(*(_number(record[i], c) for i, c in zip(at, _READ)))
                elif not all(_INTEGER.fullmatch(record[i]) for i in at):
                    for i, c in zip(at, _READ):
                        _number(record[i], c)  # raises, naming the column
    except FileNotFoundError:
        return
    except (OSError, EOFError, zlib.error) as exc:
        raise ScenarioError(
            [Problem(path, line, 1, "", f"cannot read samples: {exc}; expected a gzip'd CSV as runner writes it")]
        ) from None
    except (ValueError, csv.Error) as exc:
        raise ScenarioError([Problem(path, line, 1, "", f"not a samples row: {exc}")]) from None


_INTEGER = re.compile(r"-?[0-9]{1,18}")  # surely inside 64 bits; anything else goes through _number


def _number(text: str, column: str) -> int:
    """A samples column's integer; ValueError saying which column is wrong."""
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{column} is {show_value(text)}; expected an integer") from None
    if not -INT64 <= value < INT64:
        raise ValueError(f"{column} is out of range; expected a 64-bit integer")
    return value
