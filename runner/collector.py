"""Python's cyclic garbage collector, kept from traversing the runner's records for nothing.

What the runner allocates is freed by reference counting: its records, figures and report lines
hold no reference cycles (a 5 s cell of 1,024 threads, traced, left none for the collector to
find; a 1,000-cell report, none).  But the collector's full passes traverse every live
container, over and over: 140 collections and 60 ms of a 1,024-thread cell's end (425 ms, 334
without), while its records were built; about 150 ms of a 1,000-cell report and its comparison,
walking the document read.  So the collector is paused while a cell is measured and saved, and a
document that lives on for the rest of the command is settled out of its passes.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


def settle() -> None:
    """What is alive now lives on for the rest of the command (a results document just read, or built): gc.freeze()
    moves it out of the collector's passes, which then look only at what is allocated after."""
    gc.freeze()


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
