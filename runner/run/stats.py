"""Order statistics for latency samples.  Pure, no I/O."""

from __future__ import annotations

import math
from collections.abc import Sequence

QUANTILES = {"p50": 0.50, "p90": 0.90, "p99": 0.99, "p999": 0.999}


def nearest_rank(ordered: Sequence[float], q: float) -> float:
    """The q-quantile by the nearest-rank method (a value that was actually observed)."""
    if not ordered:
        raise ValueError("no samples")
    rank = max(1, math.ceil(q * len(ordered)))
    return ordered[min(rank, len(ordered)) - 1]


def summarize(values: Sequence[float]) -> dict[str, float] | None:
    """min, p50, p90, p99, p999, max of `values`, or None when there are none."""
    if not values:
        return None
    ordered = sorted(values)
    out = {"min": ordered[0]}
    out.update({name: nearest_rank(ordered, q) for name, q in QUANTILES.items()})
    out["max"] = ordered[-1]
    return out


def mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None
