"""results.json and its journal: every finished cell is durable at once, at a cost that does not grow with the run.

Rewriting results.json whole after every cell made a matrix quadratic: a 1,000-cell run of
34 KB cells ends with a 34 MB file, and rewriting it after each cell wrote about 17 GB and
took minutes.  Now results.json is rewritten after every cell only while it is small; beyond,
each finished cell is appended, as one JSON line, to `cells.jsonl` beside it and synced, and
results.json is rewritten (and the journal emptied) once the journal has grown by as much as
results.json last held, so the bytes written stay within a few times the final file.  The
last save of a run writes results.json whole and removes the journal.

Readers (`runner.results.read.load`) add the journal's cells that results.json does not hold
yet, so a run killed between two rewrites still shows every finished cell.  Each line is synced
before the next is written, so a crash can damage the last line only: without its newline, or
with one but not JSON, it is the cell that was being written when the run died and is left out
(the second with a warning), as the cell in flight always was; `--resume` runs it again.  Damage
anywhere before the last line is no crash's, and is refused at its line (`read.journal_cells`).

No line is ever appended to such a tail: a run (resumed or not) begins by writing results.json
whole and removing the journal, and an append that finds the journal not ending in a newline
(a failed write whose truncation failed too) cuts the torn bytes first.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

from runner.results.document import CellResult, RunDocument
from runner.results.files import JOURNAL
from runner.safefs import FILE_MODE, open_write, sync_folder, write_all

REWRITE_BELOW = 1 << 16
"""results.json is rewritten after every cell while it is smaller than this; beyond, at doubling.

A few cells: under 1 MiB, a policy_matrix run rewrote its 0.2 MB whole after each of its
cells, 2.4 ms for the first and 10.8 for the fifth, where a journal line costs 1.5 to 2 ms.
"""


def journal_path(folder: str) -> str:
    """The journal beside the results.json of `folder`."""
    return os.path.join(folder, JOURNAL)


def cell_key(cell: CellResult) -> tuple[str, int]:
    """What names a cell run within one results folder: its id and its repeat."""
    return cell.id, cell.repeat


def merge_journal(doc: RunDocument, journaled: list[CellResult]) -> list[CellResult]:
    """The journal's cells that `doc` does not hold yet, in the order they finished (pure)."""
    held = {cell_key(c) for c in doc.cells}
    out: list[CellResult] = []
    for cell in journaled:
        if cell_key(cell) not in held:
            held.add(cell_key(cell))
            out.append(cell)
    return out


def rewrite_due(saved_bytes: int, pending_bytes: int) -> bool:
    """Whether results.json should be rewritten whole now (pure).

    `saved_bytes`: its size when last written; `pending_bytes`: what the journal gained since.
    Small files are rewritten every time; larger ones once the journal holds as much again,
    which bounds all rewrites together to about twice the final size.
    """
    return saved_bytes < REWRITE_BELOW or pending_bytes >= saved_bytes


@dataclass
class ResultsStore:
    """A run's results.json and journal, written in the order that keeps every finished cell on disk."""

    results_path: str
    saved_bytes: int = 0
    pending_bytes: int = 0

    @property
    def journal(self) -> str:
        """Beside results.json (which is never a link: the run refuses one, safefs.write_atomic), where readers look for it."""
        return journal_path(os.path.dirname(self.results_path))

    def begin(self, doc: RunDocument) -> None:
        """Write `doc` whole (it holds whatever an earlier segment of the run journaled) and start an empty journal."""
        self.rewrite(doc)

    def add(self, doc: RunDocument, cell: CellResult) -> None:
        """Store `cell`, already the last of `doc.cells`: results.json rewritten if that is due, else a journal line.

        An OSError (a full disk) leaves results.json whole and the journal without a line for
        `cell`: readers see the cells before it.
        """
        if rewrite_due(self.saved_bytes, self.pending_bytes):
            self.rewrite(doc)
        else:
            self.pending_bytes += self._append(cell)

    def finish(self, doc: RunDocument) -> None:
        """Write `doc` whole, which leaves the journal nothing to hold."""
        self.rewrite(doc)

    def rewrite(self, doc: RunDocument) -> None:
        """Write `doc` whole, then drop the journal, whose cells it now holds (a reader skips those it already has)."""
        self.saved_bytes = doc.save(self.results_path)
        self.pending_bytes = 0
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.journal)

    def _append(self, cell: CellResult) -> int:
        line = (cell.model_dump_json(by_alias=True) + "\n").encode("utf-8")
        try:
            fd = open_write(self.journal, os.O_RDWR | os.O_APPEND | os.O_CREAT, FILE_MODE)  # never through a link
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), self.journal) from exc
        try:
            size = _whole_lines(fd, os.fstat(fd).st_size)
            try:
                write_all(fd, line)
                os.fsync(fd)
                if size == 0:  # a journal just made: its name in the folder must last too
                    sync_folder(os.path.dirname(self.journal))
            except OSError:
                with contextlib.suppress(OSError):  # a torn line must not be followed by the next one
                    os.ftruncate(fd, size)
                raise
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), self.journal) from exc
        finally:
            os.close(fd)
        return len(line)


def _whole_lines(fd: int, size: int) -> int:
    """The journal open at `fd` cut back to its last newline (its size, `size` bytes now, after that).

    A torn line followed by the next one would be one damaged line in the middle of the journal,
    which readers refuse: its bytes, never a cell any reader took, are dropped instead.
    """
    end = size
    while end and os.pread(fd, 1, end - 1) != b"\n":
        chunk = os.pread(fd, min(end, 1 << 16), max(0, end - (1 << 16)))
        newline = chunk.rfind(b"\n")
        end = end - len(chunk) + newline + 1 if newline >= 0 else end - len(chunk)
    if end != size:
        os.ftruncate(fd, end)
    return end
