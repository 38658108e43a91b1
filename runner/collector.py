"""Python's cyclic garbage collector, paused while the runner builds or walks many records at once.

What the runner allocates is freed by reference counting: its records, figures and report lines
hold no reference cycles (a 5 s cell of 1,024 threads, traced, left none for the collector to
find; a 1,000-cell report, none).  But the collector's full passes traverse every live
container, over and over: 140 collections and 60 ms of a 1,024-thread cell's end (425 ms, 334
without) while its records were built; about 150 ms of a 1,000-cell report or of the comparison
after it, walking the document read.  So the collector is paused while a cell is measured and
saved, while a report is rendered, and through the commands that read documents (report,
compare, merge); it runs again after.  Paused, not frozen: gc.freeze() would also keep for good
whatever cyclic garbage was pending (a plot's matplotlib figure, an exception's frames).
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """The cyclic collector off for the block, back as it was after (on, unless someone else had paused it)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
