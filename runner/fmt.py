"""How figures read in reports: latencies in the unit that reads best, counts with separators.  Pure."""

from __future__ import annotations

from typing import Optional


def fmt_us(value: Optional[float]) -> str:
    """A latency given in microseconds, in the unit that reads best: `56.6 µs`, `6.12 ms`, `1.20 s`."""
    if value is None:
        return "–"
    if value < 1000:
        return f"{value:.1f} µs" if value < 100 else f"{value:.0f} µs"
    if value < 1_000_000:
        return f"{value / 1000:.2f} ms"
    return f"{value / 1_000_000:.2f} s"


def fmt_mean(value: Optional[float]) -> str:
    return "–" if value is None else ("0" if value == 0 else f"{value:.2f}")


def fmt_int(value: Optional[int]) -> str:
    return "–" if value is None else f"{value:,}"


def fmt_bytes(value: Optional[int]) -> str:
    if value is None:
        return "–"
    if value < 0:
        return "unlimited"
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if value >= size:
            return f"{value / size:.1f} {unit}".replace(".0 ", " ")
    return f"{value} B"


def fmt_figure(value: Optional[float], unit: str) -> str:
    """A compared figure: a latency (unit "us") or a count."""
    if unit == "us":
        return fmt_us(value)
    return "–" if value is None else f"{value:g}"
