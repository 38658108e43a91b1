"""Which cells a run does, and in what order: shards, repeats, shuffling, resuming.  Pure, no I/O.

A shard takes every N-th cell of the scenario's expansion order (cell i goes to
shard i mod N + 1), so the shards of a matrix are disjoint, cover it, stay
balanced, and need nothing but the scenario file to agree.
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Optional

from runner import units
from runner.errors import UsageError, quoted
from runner.scenario.matrix import MAX_CELLS


@dataclass(frozen=True)
class Shard:
    index: int  # 1-based
    count: int

    @classmethod
    def parse(cls, text: str) -> Shard:
        m = re.fullmatch(r"\s*([0-9]+)\s*/\s*([0-9]+)\s*", text)  # ASCII digits: \d takes `٣` too
        if not m:
            raise UsageError(f"runner: --shard {quoted(text)}: expected K/N, e.g. 1/4")
        try:
            k, n = (units.parse_whole(m.group(i), 0, MAX_CELLS) for i in (1, 2))
        except units.UnitError:
            raise UsageError(f"runner: --shard {quoted(text)}: K and N are at most {MAX_CELLS:,}, the cells a matrix may have") from None
        if n < 1 or not 1 <= k <= n:
            raise UsageError(f"runner: --shard {quoted(text)}: K must be between 1 and N (N >= 1)")
        return cls(k, n)

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    def take(self, ids: Sequence[str]) -> list[str]:
        """This shard's part of `ids` (the scenario's full cell list, in expansion order)."""
        return [cell for i, cell in enumerate(ids) if i % self.count == self.index - 1]


@dataclass(frozen=True)
class Unit:
    """One cell run once: `repeat` counts from 0."""

    cell: str
    repeat: int


def plan_units(
    cells: Sequence[str], repeat: int = 1, shuffle_seed: Optional[int] = None, done: Iterable[tuple[str, int]] = ()
) -> list[Unit]:
    """Every (cell, repeat) still to run: repeats of a cell are spread out (round by round), then
    shuffled when a seed is given (the same seed gives the same order, so a resumed run keeps it)."""
    units = [Unit(cell, r) for r in range(repeat) for cell in cells]
    if shuffle_seed is not None:
        random.Random(shuffle_seed).shuffle(units)
    finished = set(done)
    return [u for u in units if (u.cell, u.repeat) not in finished]
