"""A cell's latency in cyclictest's own formats, so plotting scripts written for cyclictest keep working.  Pure.

`histogram_text` is what `cyclictest -h US -q` prints (the format OSADL's latency plots
read): one line per microsecond, `%06d` then one `%06d` count per thread, then the
`# Total / Min / Avg / Max Latencies / Histogram Overflows` trailer.  `json_summary` has
the shape of `cyclictest --json` as rt-tests 2.x writes it (`rt_write_json` in
src/lib/rt-utils.c, then cyclictest's `write_stats`): its `cmdline:` and `rt_test_version:`
keys (colon included), the version a number in text (`"0.10"` where cyclictest writes
`"2.40"`: the runner's major and minor, as `%1.2f` writes them), start and end times in
RFC 2822 (`Sun, 22 Nov 2026 00:48:56 +0000`, as cyclictest's `strftime("%a, %d %b %Y %T %z")`),
and `sysinfo` from the machine facts the run recorded (uname's sysname, nodename,
release, version and machine, and `realtime` 1 on a PREEMPT_RT kernel), never from the
machine the export runs on.

Both come from the native histograms of every release answered (runner/histogram.py), one
column (or `thread` entry) per periodic thread in the cell's order.  A bucket wider than a
microsecond (values above 131 us) is counted in the microsecond of its upper end, so a
latency is never shown smaller than it was; values are microseconds, truncated as
cyclictest truncates them.
"""

from __future__ import annotations

import itertools
import shlex
from datetime import datetime, timedelta
from email.utils import format_datetime
from typing import Any

from runner import __version__
from runner.errors import UsageError, did_you_mean
from runner.histogram import Histogram
from runner.results.document import CellResult, MachineInfo, RunDocument, ThreadResult

DEFAULT_HISTOGRAM_US = 1000


def pick_cell(doc: RunDocument, cell_id: str | None) -> CellResult:
    """The cell to export: the one named, or the only one."""
    if cell_id is None:
        if len({c.id for c in doc.cells}) != 1:
            raise UsageError(
                f"runner report: this run has {len(doc.cells)} cells; choose one with --cell ({', '.join(c.id for c in doc.cells)})"
            )
        return doc.cells[0]
    for cell in doc.cells:
        if cell.id == cell_id:
            return cell
    raise UsageError(f"runner report: no cell {cell_id!r}{did_you_mean(cell_id, [c.id for c in doc.cells])}")


def latency_threads(cell: CellResult) -> list[tuple[ThreadResult, Histogram]]:
    """The cell's threads with callbacks and their latency histograms, in the cell's order; refused when it has none."""
    out = [(t, t.histograms.latency) for t in cell.threads if t.has_callbacks and t.histograms and t.histograms.latency]
    if not out:
        raise UsageError(f"runner report: cell {cell.id!r} has no latency histogram (no periodic thread ran, or the results predate them)")
    return out


def _per_us(hist: Histogram) -> dict[int, int]:
    """Counts per whole microsecond that has any, ascending: as many entries as buckets, however long the worst value."""
    out: dict[int, int] = {}
    for _low, high, n in hist.buckets:
        us = max(0, min(high, hist.max) // 1000)
        out[us] = out.get(us, 0) + n
    return out


def _bins(hist: Histogram, size: int) -> tuple[list[int], int]:
    """Counts per whole microsecond below `size`, and the count at or above it (overflows)."""
    counts = [0] * size
    over = 0
    for us, n in _per_us(hist).items():
        if us < size:
            counts[us] += n
        else:
            over += n
    return counts, over


def _avg_us(t: ThreadResult, hist: Histogram) -> float:
    mean = t.figures.latency_ns.mean if t.figures.latency_ns else None
    return (mean if mean is not None else hist.quantile(0.5)) / 1000


def histogram_text(cell: CellResult, size: int = DEFAULT_HISTOGRAM_US) -> str:
    """The cell's latency as `cyclictest -h SIZE -q` prints it."""
    threads = latency_threads(cell)
    columns = [_bins(h, size) for _, h in threads]
    lines = ["# Histogram"]
    for us in range(size):
        lines.append(f"{us:06d} " + "\t".join(f"{counts[us]:06d}" for counts, _ in columns))
    lines.append("# Total: " + " ".join(f"{sum(counts):09d}" for counts, _ in columns))
    lines.append("# Min Latencies: " + " ".join(f"{h.min // 1000:05d}" for _, h in threads))
    lines.append("# Avg Latencies: " + " ".join(f"{int(_avg_us(t, h)):05d}" for t, h in threads))
    lines.append("# Max Latencies: " + " ".join(f"{h.max // 1000:05d}" for _, h in threads))
    lines.append("# Histogram Overflows: " + " ".join(f"{over:05d}" for _, over in columns))
    lines.append("# Histogram Overflow at cycle number:")
    lines.extend(f"# Thread {i}:" for i in range(len(threads)))  # the histograms do not keep which cycles overflowed
    return "\n".join(lines) + "\n"


def rt_test_version(version: str = __version__) -> str:
    """A runner version as the number cyclictest's `rt_test_version:` holds: `0.1.0` -> `"0.10"`, `1.12.3` -> `"1.12"`.

    rt-tests writes its version with `%1.2f` (`2.4` -> `"2.40"`), so scripts read the field as a
    number; the runner's major and minor read as the same number (`float("0.10") == 0.1`).
    """
    major, _, rest = version.partition(".")

    def digits(text: str) -> str:  # a results file's version is text: `0.1.0rc1`, or anything
        return "".join(itertools.takewhile(lambda c: "0" <= c <= "9", text))[:9]

    return f"{int(digits(major) or 0)}.{(digits(rest) or '0').ljust(2, '0')}"


def rfc2822(iso: str, later_ns: int = 0) -> str:
    """An ISO 8601 time the results hold (`2026-11-22T00:48:56+00:00`), `later_ns` after, as cyclictest writes
    times: RFC 2822 (`Sun, 22 Nov 2026 00:48:56 +0000`); "" when the results hold none."""
    if not iso:
        return ""
    try:
        when = datetime.fromisoformat(iso)
    except ValueError:
        return ""
    return format_datetime(when + timedelta(microseconds=later_ns // 1000))


def sysinfo(machine: MachineInfo) -> dict[str, Any]:
    """cyclictest's `sysinfo` (uname, and whether the kernel is PREEMPT_RT) from the facts a run recorded."""
    return {
        "sysname": "Linux",  # the runner runs on Linux only (its uname's sysname)
        "nodename": machine.hostname or "",
        "release": machine.kernel or "",
        "version": machine.kernel_version,
        "machine": machine.arch or "",
        "realtime": int(machine.preempt_rt),
    }


def json_summary(doc: RunDocument, cell: CellResult) -> dict[str, Any]:
    """The cell's latency in the shape of `cyclictest --json` (microseconds), with the runner's thread names beside."""
    threads = latency_threads(cell)
    out: dict[str, Any] = {
        "file_version": 1,
        "cmdline:": shlex.join(doc.command),
        "rt_test_version:": rt_test_version(doc.tool.version),
        "runner_version": doc.tool.version,
        "start_time": rfc2822(cell.started_at),
        "end_time": rfc2822(cell.started_at, cell.duration_ns),
        "return_code": 0 if cell.status.value in ("passed", "degraded") else 1,
        "sysinfo": sysinfo(cell.machine or doc.machine),
        "num_threads": len(threads),
        "resolution_in_ns": 0,
        "thread": {},
    }
    for i, (t, hist) in enumerate(threads):
        out["thread"][str(i)] = {
            "histogram": {str(us): n for us, n in _per_us(hist).items()},  # a 1 h worst value once listed 3.6e9 slots
            "cycles": hist.count,
            "min": hist.min // 1000,
            "max": hist.max // 1000,
            "avg": round(_avg_us(t, hist), 2),
            "cpu": t.figures.cpus_seen[0] if len(t.figures.cpus_seen) == 1 else -1,
            "node": 0,
            "name": t.key,
        }
    return out
