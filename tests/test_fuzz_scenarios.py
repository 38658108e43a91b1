"""Hostile input never makes `runner validate` or `runner FILE --list` crash, hang or print a traceback.

Hypothesis generates scenarios and mutates the shipped ones (keys, values, types, units, huge
and negative numbers, NaN, .inf, unicode and control characters, anchors, aliases, merge keys,
matrix references, include/exclude, values and keys of up to 100,000 characters, one long text
aliased into many places) and checks that both commands exit 0 or 2 within `TIME_BOUND`
seconds, with no "Traceback" and no "internal error" in what they print, and no problem line
longer than `LINE_BOUND`.

The default test run is short; `RUNNER_FUZZ_EXAMPLES=5000 pytest tests/test_fuzz_scenarios.py`
is the long run CI does.  Runs are derandomized and keep no example database, so a run is
the same on every machine and every failure reproduces.
"""

from __future__ import annotations

import glob
import os
import sys
import tempfile
import time
from typing import Any

import yaml
from conftest import SCENARIOS, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

SHIPPED = sorted(glob.glob(os.path.join(SCENARIOS, "*.yaml")))
EXAMPLES = int(os.environ.get("RUNNER_FUZZ_EXAMPLES", "0") or 0)
TIME_BOUND = 2.0  # seconds of CPU for validate and --list of one case, each: a blow-up, not the machine's load, exceeds it
LINE_BOUND = 5_000  # characters of a line on stderr, past the file's path: a problem quotes a long value cut (errors.bounded)

FUZZ = settings(
    max_examples=EXAMPLES or 60,
    derandomize=True,
    database=None,
    deadline=None,  # timing is asserted below, on the commands only
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
)

KEYS = [
    "name",
    "description",
    "duration",
    "processes",
    "background",
    "matrix",
    "expect",
    "instances",
    "memory",
    "lock",
    "prealloc",
    "stack_size",
    "main",
    "threads",
    "sched",
    "cpus",
    "apply",
    "work",
    "kind",
    "period",
    "burn",
    "burn_clock",
    "alloc",
    "offset",
    "count",
    "pin",
    "priospread",
    "distance",
    "inherit",
    "reset_on_fork",
    "hogs",
    "commands",
    "argv",
    "thread",
    "metric",
    "max",
    "min",
    "cells",
    "include",
    "exclude",
    "policy",
    "priority",
    "nice",
    "<<",
]
UNITS = ["ns", "us", "µs", "ms", "s", "m", "h", "B", "KiB", "MiB", "GiB", "TiB", "MB", "sec", ""]
WORDS = [
    "fifo",
    "rr",
    "other",
    "batch",
    "idle",
    "deadline",
    "fifo:80",
    "SCHED_RR",
    "periodic",
    "spin",
    "sleep",
    "cpus",
    "each",
    "process",
    "thread",
    "before_threads",
    "after_threads",
    "wall",
    "latency.p99",
    "callbacks",
    "0-1",
    "0b11",
    "0x3",
    "1-0",
    "app",
    "gc",
    "$\\foo$",
    "a|b",
    "`x`",
    "#c",
    "<x>",
    "${{ matrix.x }}",
    "${{ matrix.policy }}",
    "fifo:${{ matrix.prio }}",
    "${{ env.HOME }}",
    "${{ matrix. }}",
]

numbers = st.one_of(
    st.integers(min_value=-(10**6), max_value=10**6),
    st.integers(min_value=-(10**40), max_value=10**40),
    st.sampled_from([0, 1, -1, 99, 100, 1024, 1025, 2**31, 2**63, 2**64, 10**400]),
    st.floats(allow_nan=True, allow_infinity=True),
)
quantities = st.builds(
    lambda number, unit: f"{number}{unit}",
    st.one_of(
        st.integers(min_value=0, max_value=10**30).map(str),
        st.sampled_from(["1" + "0" * 400, "1.5", ".5", "1e400", "-1", "nan", "inf", "0.0000001"]),
    ),
    st.sampled_from(UNITS),
)
texts = st.one_of(
    st.sampled_from(WORDS),
    st.text(max_size=20),
    st.text(alphabet=st.characters(codec="utf-8"), max_size=12),
    st.sampled_from(["a\nb", "x\x00y", "\x1b[31m", "tab\there", "line\u2028sep", "\u202eevil", "é" * 20, " ", ""]),
)
scalars = st.one_of(numbers, quantities, texts, st.booleans(), st.none())
values: st.SearchStrategy[Any] = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6), inner, max_size=4)),
    max_leaves=12,
)


def _shipped(index: int) -> dict[str, Any]:
    with open(SHIPPED[index % len(SHIPPED)]) as handle:
        return yaml.safe_load(handle)


def _paths(data: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [path]
    if isinstance(data, dict):
        for key, value in data.items():
            out.extend(_paths(value, path + (key,)))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            out.extend(_paths(value, path + (i,)))
    return out


def _mutate(data: Any, path: tuple[Any, ...], action: str, new: Any, key: str) -> Any:
    """`data` with one change at `path`: replaced value, dropped key, added or renamed key, or duplicated."""
    if not path:
        return new if action == "replace" else data
    parent = data
    for part in path[:-1]:
        parent = parent[part]
    last = path[-1]
    if action == "replace":
        parent[last] = new
    elif action == "drop":
        del parent[last]
    elif action == "add" and isinstance(parent, dict):
        parent[key] = new
    elif action == "rename" and isinstance(parent, dict):
        parent[key] = parent.pop(last)
    elif action == "grow" and isinstance(parent, list):
        parent.extend([parent[last]] * 40)
    return data


def _check(text: str) -> None:
    """Both commands on `text`: exit 0 or 2, in time, with no traceback or internal error."""
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "fuzz.yaml")
        with open(path, "w", encoding="utf-8", errors="surrogatepass") as handle:
            handle.write(text)
        for argv in (("validate", path), (path, "--list")):
            # in-process: the CPU the command took, whatever else the machine runs meanwhile; and without a coverage
            # tracer (CI measures coverage, which slows Python several times): the runner's own cost is bounded
            tracer = sys.gettrace()
            sys.settrace(None)
            try:
                start = time.thread_time()
                outcome = run_cli(*argv)
                took = time.thread_time() - start
            finally:
                sys.settrace(tracer)
            printed = outcome.out + outcome.err
            assert outcome.code in (0, 2), f"runner {' '.join(argv)} exited {outcome.code}:\n{printed[:2000]}"
            assert "Traceback" not in printed and "internal error" not in printed, printed[:2000]
            assert took < TIME_BOUND, f"runner {' '.join(argv)} took {took:.1f}s of CPU"
            longest = max((len(line) - len(path) for line in outcome.err.splitlines()), default=0)
            assert longest < LINE_BOUND, f"runner {' '.join(argv)} printed a line of {longest:,} characters"
            if outcome.code == 2:
                assert outcome.err.strip(), "exit 2 with no problem printed"


def _dump(data: Any) -> str:
    return yaml.safe_dump(data, allow_unicode=True, sort_keys=False, width=1_000_000)


@FUZZ
@given(
    index=st.integers(min_value=0, max_value=100),
    choice=st.integers(min_value=0, max_value=10**6),
    action=st.sampled_from(["replace", "replace", "drop", "add", "rename", "grow"]),
    new=values,
    key=st.sampled_from(KEYS) | st.text(max_size=8),
)
def test_mutated_shipped_scenarios_never_crash(index, choice, action, new, key):
    data = _shipped(index)
    paths = _paths(data)
    text = _dump(_mutate(data, paths[choice % len(paths)], action, new, key))
    _check(text)


YAML_SNIPPETS = [
    "&a ",
    "*a",
    "<<: *a\n",
    "<<: [*a, *a]\n",
    "!!int ",
    "!!float ",
    "!!str ",
    "!!binary ",
    "!!python/name:os.system ",
    "${{ matrix.policy }}",
    '"${{ matrix.x }}"',
    "1e400s",
    "1" + "0" * 400 + "B",
    ".inf",
    ".nan",
    "-.inf",
    "~",
    "\x01",
    "\x1b",
    "\t",
    "\u2028",
    "\ufeff",
    '"\\ud800"',
    "{",
    "}",
    "[",
    "]",
    ": ",
    "- ",
    "? ",
    "|\n",
    ">-\n",
    "include:\n  - {x: 1}\n",
    "exclude:\n  - {policy: fifo}\n",
    "#",
    "'",
    '"',
    "%YAML 1.1\n---\n",
    "---\n",
    "...\n",
]


@FUZZ
@given(
    index=st.integers(min_value=0, max_value=100),
    edits=st.lists(
        st.tuples(st.integers(min_value=0, max_value=10**6), st.sampled_from(YAML_SNIPPETS) | st.text(max_size=4)), min_size=1, max_size=4
    ),
)
def test_text_edits_of_shipped_scenarios_never_crash(index, edits):
    with open(SHIPPED[index % len(SHIPPED)], encoding="utf-8") as handle:
        text = handle.read()
    for at, snippet in edits:
        at %= len(text) + 1
        text = text[:at] + snippet + text[at:]
    _check(text)


axes = st.dictionaries(
    st.sampled_from(["policy", "prio", "x", "lock", "size", "n"]) | st.text(max_size=5),
    st.lists(scalars, min_size=0, max_size=5),
    max_size=4,
)
entries = st.lists(st.dictionaries(st.sampled_from(["policy", "prio", "x", "extra"]), scalars, max_size=3), max_size=6)
threads = st.lists(
    st.fixed_dictionaries(
        {"name": texts},
        optional={"count": numbers, "sched": scalars, "cpus": scalars, "work": values, "inherit": scalars},
    ),
    max_size=4,
)


@FUZZ
@given(
    axes=axes,
    include=entries,
    exclude=entries,
    name=texts,
    instances=numbers,
    memory=st.fixed_dictionaries({}, optional={"lock": scalars, "prealloc": quantities, "stack_size": quantities}),
    main=st.fixed_dictionaries({}, optional={"sched": scalars, "work": values, "cpus": scalars}),
    threads=threads,
    duration=scalars,
    expect=st.lists(
        st.fixed_dictionaries({"thread": texts, "metric": texts}, optional={"max": scalars, "min": scalars, "cells": values}), max_size=3
    ),
)
def test_generated_scenarios_never_crash(axes, include, exclude, name, instances, memory, main, threads, duration, expect):
    matrix: dict[str, Any] = dict(axes)
    if include:
        matrix["include"] = include
    if exclude:
        matrix["exclude"] = exclude
    process = {"name": name, "instances": instances, "memory": memory, "main": main, "threads": threads}
    scenario: dict[str, Any] = {"name": "fuzz", "duration": duration, "processes": [process], "expect": expect}
    if matrix:
        scenario["matrix"] = matrix
        process["main"] = {**main, "sched": "${{ matrix.policy }}"}
    _check(_dump(scenario))


LONG = st.builds(
    lambda unit, n: unit * n,
    st.sampled_from(["y", "é", "线", "a b ", "'", '"', "\\", "${{ matrix.x }}", "0"]),
    st.integers(min_value=500, max_value=100_000),
)


@FUZZ
@given(
    index=st.integers(min_value=0, max_value=100),
    choice=st.integers(min_value=0, max_value=10**6),
    long=LONG,
    as_key=st.booleans(),
)
def test_long_values_and_keys_give_bounded_problems(index, choice, long, as_key):
    """A value or key of up to 100,000 characters anywhere: every problem about it still fits a line."""
    data = _shipped(index)
    paths = _paths(data)
    path = paths[choice % len(paths)]
    text = _dump(_mutate(data, path, "rename" if as_key else "replace", long, long[:100_000]))
    _check(text[: 1 << 20])  # a file of at most 1 MiB: past it, the size alone is refused


@settings(FUZZ, max_examples=EXAMPLES or 20)  # each example loads up to 4 million characters: fewer in the short run
@given(
    index=st.integers(min_value=0, max_value=100),
    choice=st.integers(min_value=1, max_value=10**6),
    length=st.integers(min_value=1, max_value=100_000),
    copies=st.integers(min_value=1, max_value=200),
    nested=st.booleans(),
)
def test_a_long_text_aliased_into_many_places_is_bounded(index, choice, length, copies, nested):
    """One text anchored once, aliased `copies` times (or copies squared, through an aliased list) where a value was.

    A 0.4 MB file of this kind took 16 s and 1.6 GB and printed its text once per alias: the loader
    bounds what aliases expand to (yamlsource.MAX_CHARS) and every problem quotes the text cut.
    """
    data = _shipped(index)
    paths = [p for p in _paths(data) if p and p[0] != "description"]
    data = _mutate(data, paths[choice % len(paths)], "replace", "ZZALIASESZZ", "")
    data = {"description": "ZZTEXTZZ", **{k: v for k, v in data.items() if k != "description"}}  # anchored before any alias
    aliases = ", ".join(["*big"] * copies)
    uses = f"[&many [{aliases}], " + ", ".join(["*many"] * copies) + "]" if nested else f"[{aliases}]"
    text = _dump(data).replace("ZZTEXTZZ", '&big "' + "x" * length + '"', 1).replace("ZZALIASESZZ", uses, 1)
    _check(text)
