"""Durations, sizes, CPU sets and whole numbers as users write them, and back again.

Pure functions, no I/O.  Durations are integer nanoseconds, sizes integer bytes,
CPU sets sorted tuples of CPU numbers: the internal units never change, only the
way they are written does.  A number is written in ASCII digits: Python's int() also takes
other scripts' digits (`٣` is 3) and raises past 4,300 digits, so every number a user gives
is matched as 0-9 and its length bounded before it is converted.  A bare number for a duration or a size is refused on
purpose: `period: 500` is ambiguous (ms? us?) and a wrong guess silently turns a
500 ms period into a 500 ns one.  Zero is the exception: 0 is 0 in every unit.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Any

from runner.errors import quoted, shorten

NS_PER = {
    "ns": 1,
    "us": 1_000,
    "µs": 1_000,
    "ms": 1_000_000,
    "s": 1_000_000_000,
    "m": 60_000_000_000,
    "h": 3_600_000_000_000,
}
BYTES_PER = {
    "B": 1,
    "KiB": 1 << 10,
    "MiB": 1 << 20,
    "GiB": 1 << 30,
    "TiB": 1 << 40,
}
_SI_SIZE_HINT = {"KB": "KiB", "kB": "KiB", "K": "KiB", "MB": "MiB", "M": "MiB", "GB": "GiB", "G": "GiB"}
_NUMBER = r"(?:[0-9]+(?:\.[0-9]+)?|\.[0-9]+)"
_QUANTITY = re.compile(rf"^\s*({_NUMBER})\s*([A-Za-zµ]+)\s*$")
MAX_DIGITS = 24  # no duration or size needs more; longer numbers are refused before any arithmetic
MAX_CPUS = 8192  # CONFIG_NR_CPUS at its largest
PID_MAX = (1 << 31) - 1  # pid_t's range: a larger number names no process on any system

DURATION_EXPECTED = "a duration with a unit, such as 500ms, 200us, 1.5s or 10m"
SIZE_EXPECTED = "a size with a unit, such as 50MiB, 200KiB or 0B"
CPUS_EXPECTED = "CPUs as a list [0, 1], a cpulist '0-1,3' (also '0-7:2', '0-7:2/4', 'all'), or a mask '0b1100' / '0x3'"

# The written forms as regular expressions that mean the same in Python and in JavaScript (ECMA-262 with
# the `u` flag, as editors compile JSON Schema patterns): no inline flags, no lookbehind, no \Z.  The
# parsers below and the JSON Schema (runner.scenario.model) both use them, so the two cannot drift.
DURATION_PATTERN = rf"^\s*(?:0|{_NUMBER}\s*(?:{'|'.join(NS_PER)}))\s*$"
SIZE_PATTERN = rf"^\s*{_NUMBER}\s*(?:{'|'.join(BYTES_PER)})\s*$"
_REGION = r"([0-9]+)(?:-([0-9]+)(?::([0-9]+)(?:/([0-9]+))?)?)?"
"""One region of a cpulist: `N`, `N-M`, taskset's stride `N-M:S`, the kernel's groups `N-M:USED/GROUP`."""
_ALL = "[aA][lL][lL]"
_MASK = r"0[bB][01_]+|0[xX][0-9a-fA-F_]+"
CPUS_PATTERN = rf"^\s*(?:{_REGION}(?:\s*,\s*{_REGION})*|{_ALL}|{_MASK})\s*$"
"""A CPU set as text: a cpulist as the kernel and taskset -c read one (spaces after commas allowed), `all`, or a mask."""


class UnitError(ValueError):
    """A value that does not parse as the quantity expected; the message says what is expected."""


def parse_duration(value: object) -> int:
    """Parse `500ms`, `200us`, `1.5s`, `10m` into integer nanoseconds; a bare 0 is 0 in every unit."""
    if (value == 0 and not isinstance(value, bool)) or (isinstance(value, str) and value.strip() == "0"):
        return 0
    if isinstance(value, (bool, int, float)):
        raise UnitError(f"bare number {value!r} has no unit; expected {DURATION_EXPECTED}")
    if not isinstance(value, str):
        raise UnitError(f"expected {DURATION_EXPECTED}, got {type(value).__name__}")
    match = _QUANTITY.match(value)
    if not match:
        raise UnitError(f"cannot read {quoted(value, 40)}; expected {DURATION_EXPECTED}")
    number, unit = match.groups()
    if unit not in NS_PER:
        hint = _did_you_mean(unit, NS_PER)
        raise UnitError(f"unknown duration unit {unit!r}{hint}; expected one of ns, us, ms, s, m, h")
    return _scaled(number, NS_PER[unit], value, DURATION_EXPECTED)


def parse_size(value: object) -> int:
    """Parse `50MiB`, `200KiB`, `0B` into integer bytes."""
    if isinstance(value, (bool, int, float)):
        raise UnitError(f"bare number {value!r} has no unit; expected {SIZE_EXPECTED}")
    if not isinstance(value, str):
        raise UnitError(f"expected {SIZE_EXPECTED}, got {type(value).__name__}")
    match = _QUANTITY.match(value)
    if not match:
        raise UnitError(f"cannot read {quoted(value, 40)}; expected {SIZE_EXPECTED}")
    number, unit = match.groups()
    if unit not in BYTES_PER:
        if unit in _SI_SIZE_HINT:
            raise UnitError(f"unit {unit!r} is ambiguous (1000 or 1024?); did you mean {_SI_SIZE_HINT[unit]!r}?")
        hint = _did_you_mean(unit, BYTES_PER)
        raise UnitError(f"unknown size unit {unit!r}{hint}; expected one of B, KiB, MiB, GiB, TiB")
    return _scaled(number, BYTES_PER[unit], value, SIZE_EXPECTED)


_WHOLE = re.compile(r"\s*([-+]?)([0-9]+)\s*")


def parse_whole(text: str, low: int, high: int, what: str = "") -> int:
    """A whole number written in ASCII digits (a sign allowed, spaces around), from `low` to `high`.

    The digits are counted before int() sees them, so a number of a million digits is out of
    range, not a ValueError; `٣` and `²` are no digits here.  `what` names the number in the
    message (`--repeat 0`); by default, the text quoted.
    """
    match = _WHOLE.fullmatch(text)
    what = what or quoted(text.strip(), 40)
    if match is None:
        raise UnitError(f"{what} is not a whole number (digits 0-9); expected {low:,} to {high:,}")
    sign, digits = match.group(1), match.group(2).lstrip("0") or "0"
    if len(digits) > len(str(max(abs(low), abs(high)))) or not low <= int(sign + digits) <= high:
        raise UnitError(f"{what} is out of range; expected {low:,} to {high:,}")
    return int(sign + digits)


def parse_pid(text: str) -> int | None:
    """The PID `text` names when it is written in ASCII digits, else None (it may be a process's name, `٣` too).

    A number no PID can be (beyond pid_t's range) is a UnitError saying so.
    """
    if not text.isascii() or not text.isdigit():
        return None
    return parse_whole(text, 0, PID_MAX, f"PID {shorten(text, 40)}")


def _scaled(number: str, scale: int, written: str, expected: str) -> int:
    """`number` (decimal digits) times `scale`, exactly, rounded to an integer.

    Floats would overflow (a 400-digit size is infinity) or round (1.000000001s); integers
    are exact, and the digit limit keeps the arithmetic and its messages small.  Halves round
    to even, as Python's round() does.
    """
    if len(number.replace(".", "").lstrip("0")) > MAX_DIGITS:
        raise UnitError(f"the number in {quoted(written, 40)} has more than {MAX_DIGITS} digits; expected {expected}")
    whole, _, decimals = number.partition(".")
    digits = (whole + decimals).lstrip("0") or "0"  # int() refuses more than 4,300 digits, leading zeros too
    quotient, remainder = divmod(int(digits) * scale, 10 ** len(decimals))
    twice = 2 * remainder
    return quotient + (twice > 10 ** len(decimals) or (twice == 10 ** len(decimals) and quotient % 2 == 1))


def parse_cpus(value: object, every: tuple[int, ...] | None = None) -> tuple[int, ...]:
    """Parse a CPU set: a list of ints, a cpulist `0-1,3` / `0-7:2` / `0-7:2/4`, `all`, or a mask `0b1100` / `0x3`.

    `all` (any case, as the kernel reads it) is `every`: the CPUs the runner may use, which the caller
    knows; without them `all` is refused.  `N-M:S` takes every S-th CPU from N to M (taskset -c);
    `N-M:U/G` the first U of every group of G from N (the kernel's cpulist, e.g. isolcpus=).
    """
    cpus: set[int] = set()
    if isinstance(value, bool):
        raise UnitError(f"expected {CPUS_EXPECTED}, got {value!r}")
    if isinstance(value, int):
        cpus.add(value)
    elif isinstance(value, list):
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int):
                raise UnitError(f"CPU list items must be integers, got {item!r}; expected {CPUS_EXPECTED}")
            cpus.add(item)
    elif isinstance(value, str):
        if not re.fullmatch(CPUS_PATTERN, value):
            raise UnitError(f"cannot read CPUs {quoted(value, 40)}; expected {CPUS_EXPECTED}")
        text = value.strip()
        if re.fullmatch(_ALL, text):
            if not every:
                raise UnitError("'all' stands for the CPUs the runner may use, which are not known here; name the CPUs")
            cpus.update(every)
        elif re.fullmatch(_MASK, text):
            try:
                mask = int(text.replace("_", ""), 0)
            except ValueError:  # a prefix with no digit after it: 0b_, 0x
                why = "a mask needs digits after its 0b or 0x"
                raise UnitError(f"cannot read CPUs {quoted(value, 40)}: {why}; expected {CPUS_EXPECTED}") from None
            if mask.bit_length() > MAX_CPUS:
                raise UnitError(f"mask {quoted(value, 40)} names CPU {mask.bit_length() - 1} or more; Linux supports {MAX_CPUS} CPUs")
            cpus.update(bit for bit in range(mask.bit_length()) if mask >> bit & 1)
        else:
            for part in text.split(","):
                cpus.update(_region(part.strip()))
    else:
        raise UnitError(f"expected {CPUS_EXPECTED}, got {type(value).__name__}")
    if not cpus:
        raise UnitError("the CPU set is empty; name at least one CPU")
    if min(cpus) < 0:
        raise UnitError(f"CPU numbers start at 0, got {min(cpus)}")
    if max(cpus) >= MAX_CPUS:
        raise UnitError(f"CPU {max(cpus)} is beyond what Linux supports ({MAX_CPUS} CPUs)")
    return tuple(sorted(cpus))


def _region(part: str) -> range | list[int]:
    """The CPUs of one cpulist region (`3`, `0-7`, `0-7:2`, `0-7:2/4`), checked before anything is expanded."""
    match = re.fullmatch(_REGION, part)
    assert match is not None  # the whole text matched CPUS_PATTERN
    low, high, step, group = match.groups()
    if max(len(low), len(high or "")) > len(str(MAX_CPUS)) + 1:
        raise UnitError(f"CPU number in {quoted(part, 40)} is beyond what Linux supports ({MAX_CPUS} CPUs)")
    first, last = int(low), int(high or low)
    if last < first:
        raise UnitError(f"range {part!r} runs backwards; write {last}-{first}")
    if last >= MAX_CPUS:
        raise UnitError(f"CPU {last} is beyond what Linux supports ({MAX_CPUS} CPUs)")
    if step is None:
        return range(first, last + 1)
    used = min(int(step), MAX_CPUS)
    if group is None:  # taskset -c: every used-th CPU
        if used == 0:
            raise UnitError(f"stride 0 in {part!r}; write N-M:S with S of 1 or more (every S-th CPU)")
        return range(first, last + 1, used)
    size = min(int(group), MAX_CPUS)
    if size == 0 or used == 0 or used > size:
        raise UnitError(f"groups in {part!r}: write N-M:USED/GROUP with 1 <= USED <= GROUP (the first USED CPUs of every GROUP)")
    return [cpu for cpu in range(first, last + 1) if (cpu - first) % size < used]


def parse_cpu_list(value: Any) -> Any:
    """A stored CPU list (`0-1,3`) as CPU numbers; "" is none.  Anything not text is left to the type check."""
    if isinstance(value, list):
        return tuple(value)
    if not isinstance(value, str):
        return value
    if not value:
        return ()
    try:
        return tuple(parse_cpus(value))
    except UnitError as exc:
        raise ValueError(str(exc)) from None


def format_duration(ns: int) -> str:
    """Write nanoseconds back in the largest unit that keeps the value exact (`100ms`, `1.5s`, `-2ms`)."""
    if ns == 0:
        return "0s"
    if ns < 0:
        return "-" + format_duration(-ns)
    for unit in ("h", "m", "s", "ms", "us"):
        scale = NS_PER[unit]
        if ns % scale == 0:
            return f"{ns // scale}{unit}"
        if ns >= scale and (ns * 10) % scale == 0 and unit in ("s", "ms", "us"):
            return f"{ns / scale:g}{unit}"
    return f"{ns}ns"


def human_duration(ns: float) -> str:
    """A duration in ns, in the unit that reads best (`56.6 µs`, `142 µs`, `6.12 ms`, `1.20 s`), signed (`−118 ms`)."""
    sign = "\u2212" if ns < 0 else ""
    us = abs(ns) / 1000
    if us < 1000:
        return f"{sign}{us:.1f} µs" if us < 100 else f"{sign}{us:.0f} µs"
    if us < 1_000_000:
        return f"{sign}{us / 1000:.2f} ms"
    return f"{sign}{us / 1_000_000:.2f} s"


def format_size(nbytes: int) -> str:
    """Write bytes back in the largest binary unit that keeps the value exact (`50MiB`)."""
    for unit in ("TiB", "GiB", "MiB", "KiB"):
        if nbytes and nbytes % BYTES_PER[unit] == 0:
            return f"{nbytes // BYTES_PER[unit]}{unit}"
    return f"{nbytes}B"


def format_cpus(cpus: tuple[int, ...] | list[int] | frozenset[int] | set[int]) -> str:
    """Write a CPU set taskset-style, runs folded: (0, 1, 2, 5) -> `0-2,5`."""
    runs: list[list[int]] = []
    for cpu in sorted(cpus):
        if runs and cpu == runs[-1][1] + 1:
            runs[-1][1] = cpu
        else:
            runs.append([cpu, cpu])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def _did_you_mean(word: str, choices: Iterable[str]) -> str:
    import difflib  # here: only a mistake needs it

    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""
