"""A cell's wake-up latency as an HdrHistogram log, so HdrHistogram's log processors and plotters read runner results.  Pure.

The format is the one HdrHistogram's `HistogramLogWriter` writes (log format 1.3): a
comment with the format version, the `#[StartTime: ...]` and `#[BaseTime: ...]` lines, the
legend, then one interval line per histogram, `[Tag=NAME,]start,length,max,payload`: start
(seconds after BaseTime) and length of the interval, its largest value divided by
1,000,000 (the writer's default ratio: nanoseconds shown as milliseconds), and the
histogram itself in HdrHistogram's V2 compressed encoding, base64.

The cell's interval is its measured window (the cell's start and length).  Its first line
is untagged and holds every periodic thread's latency together (the cell as a whole: what
`HistogramLogProcessor` reads by default); each thread follows on a line of its own, tagged
with its name as the lab formats write it (runner/report/labs.py; HdrHistogram's tags hold no
comma, space or line break), for `HistogramLogProcessor -tag NAME`.  A reader that adds every
line of the file without looking at tags counts each value twice.

No conversion loses anything: the native core's buckets are laid out as HdrHistogram's
with 2 significant digits and a lowest discernible value of 1 (runner/histogram.py), so a
bucket's counts go to the same bucket in the log, in nanoseconds.  Only the native core's
last bucket (from 2^40 - 2^32 ns, about 18 minutes, up) is wider than HdrHistogram's: its values
are logged at the largest value the cell saw, so none is shown smaller than it was.

The V2 encoding, as HdrHistogram's encoding specification and `encodeIntoCompressedByteBuffer`
describe it: a big-endian payload of the cookie 0x1c849313, the length of the counts that
follow, the normalizing index offset (0), the significant digits (2), the lowest discernible
and the highest trackable value (64 bits each), the integer-to-double conversion ratio (1.0,
a double), then the counts from the first bucket to the last that is not empty, each as a
ZigZag LEB128 number, a run of several empty buckets as its negated length.  That payload
is zlib-compressed behind the cookie 0x1c849314 and the compressed length.  Written here
rather than taken from the `hdrhistogram` package, which is not in the core install (the
tests decode these logs with it).
"""

from __future__ import annotations

import base64
import struct
import time
import zlib
from collections.abc import Iterator
from datetime import datetime
from typing import Optional

from runner.histogram import BUCKETS, Histogram, hdr_index, index, merge
from runner.report.export import latency_threads
from runner.report.labs import cell_tokens, several_instances
from runner.results.document import CellResult, RunDocument

FORMAT_VERSION = "1.3"
SIGNIFICANT_DIGITS = 2  # 256 sub-buckets, half of them per power of two above 256: the native core's layout
MAX_VALUE_UNIT_RATIO = 1_000_000  # Interval_Max in ms, from values in ns: HistogramLogWriter's default
_ENCODING_COOKIE = 0x1C849303 | 0x10  # V2, word size 8 (the `| 0x10`), as HdrHistogram writes it
_COMPRESSION_COOKIE = 0x1C849304 | 0x10
_LARGEST = 1 << 56  # a ZigZag LEB128 number of 8 bytes at most: the 9-byte form's last byte is never needed


def _zigzag_leb128(value: int) -> bytes:
    """`value` (|value| < 2^55) as HdrHistogram's ZigZag LEB128: the sign in the lowest bit, 7 bits a byte, low first."""
    number = value << 1 if value >= 0 else (-value << 1) - 1
    out = bytearray()
    while True:
        low = number & 0x7F
        number >>= 7
        if not number:
            out.append(low)
            return bytes(out)
        out.append(low | 0x80)


def _counts(positions: dict[int, int]) -> Iterator[int]:
    """The counts from index 0 to the largest one held, a run of several empty ones as its negated length."""
    last = max(positions)
    at = 0
    while at <= last:
        count = positions.get(at, 0)
        if count:
            yield count
            at += 1
            continue
        run = 1
        while at + run <= last and not positions.get(at + run, 0):
            run += 1
        yield -run if run > 1 else 0
        at += run


def _positions(hist: Histogram) -> tuple[dict[int, int], int]:
    """The histogram's counts by HdrHistogram counts index, and the largest value they stand for.

    A bucket's counts go to the bucket itself; the native core's last bucket, which holds every
    value from 2^40 ns up, goes to where the largest value the histogram saw lies.
    """
    out: dict[int, int] = {}
    top = 0
    for low, high, n in hist.buckets:
        value = hist.max if index(max(low, 0)) == BUCKETS - 1 else max(0, min(high, hist.max))
        at = hdr_index(value)
        out[at] = out.get(at, 0) + n
        top = max(top, value)
    return out, top


def encode(hist: Histogram) -> str:
    """`hist` (non-negative values in ns) in HdrHistogram's V2 compressed encoding, base64 (`HISTF...`)."""
    positions, top = _positions(hist)
    if any(n >= _LARGEST for n in positions.values()):
        raise ValueError("a count above 2^56 does not fit HdrHistogram's encoding")
    counts = b"".join(map(_zigzag_leb128, _counts(positions)))
    highest = max(2, top)  # HdrHistogram needs at least twice the lowest discernible value (1)
    payload = struct.pack(">Iiiiqqd", _ENCODING_COOKIE, len(counts), 0, SIGNIFICANT_DIGITS, 1, highest, 1.0)
    packed = zlib.compress(payload + counts)
    return base64.b64encode(struct.pack(">Ii", _COMPRESSION_COOKIE, len(packed)) + packed).decode("ascii")


def _interval(tag: Optional[str], start_s: float, length_s: float, hist: Histogram) -> str:
    prefix = f"Tag={tag}," if tag else ""
    return f"{prefix}{start_s:.3f},{length_s:.3f},{hist.max / MAX_VALUE_UNIT_RATIO:.3f},{encode(hist)}"


def _epoch_seconds(iso: str) -> Optional[float]:
    if not iso:
        return None
    try:
        return datetime.fromisoformat(iso).timestamp()
    except ValueError:
        return None


def hdr_log(doc: RunDocument, cell: CellResult) -> str:
    """The log of `cell`'s wake-up latency: the cell's interval untagged, then each thread's, tagged with its name.

    A cell without a latency histogram is refused (UsageError), as by the cyclictest formats.
    """
    threads = latency_threads(cell)
    start = _epoch_seconds(cell.started_at)
    lines = [
        f"#[Logged by runner {doc.tool.version}: wake-up latency of every release answered, in ns; the cell untagged, each thread tagged]",
        f"#[Histogram log format version {FORMAT_VERSION}]",
    ]
    if start is not None:
        shown = time.strftime("%a %b %d %H:%M:%S UTC %Y", time.gmtime(start))
        lines.append(f"#[StartTime: {start:.3f} (seconds since epoch), {shown}]")
        lines.append(f"#[BaseTime: {start:.3f} (seconds since epoch)]")
    lines.append('"StartTimestamp","Interval_Length","Interval_Max","Interval_Compressed_Histogram"')
    length = cell.duration_ns / 1e9
    whole = merge(h for _, h in threads)
    if whole is not None:
        lines.append(_interval(None, 0.0, length, whole))
    tags = cell_tokens(cell, several_instances(doc.cells))
    for t, hist in threads:
        lines.append(_interval(tags[t.key], 0.0, length, hist))
    return "\n".join(lines) + "\n"
