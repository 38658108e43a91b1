"""Matrix expansion follows GitHub Actions strategy.matrix; references keep types."""

from __future__ import annotations

import re

import pytest
from conftest import run_cli

from runner.errors import ScenarioError
from runner.scenario import matrix as mx
from runner.scenario.loader import parse_scenario
from runner.scenario.yamlsource import load_text


def expand(block: dict):
    doc = load_text("x: 1\n", "f")
    problems, warnings = [], []
    spec = mx.parse(doc, block, problems)
    cells = mx.expand(doc, spec, problems, warnings)
    assert not problems, problems
    return cells, warnings


def test_product_in_declaration_order_with_readable_ids():
    cells, _ = expand({"policy": ["fifo", "rr"], "priority": [10, 80]})
    assert [c.id for c in cells] == ["policy=fifo,priority=10", "policy=fifo,priority=80", "policy=rr,priority=10", "policy=rr,priority=80"]


def test_exclude_removes_partial_matches_and_warns_when_dead():
    cells, warnings = expand({"a": [1, 2], "b": ["x", "y"], "exclude": [{"a": 1}, {"b": "z"}]})
    assert [c.id for c in cells] == ["a=2,b=x", "a=2,b=y"]
    assert len(warnings) == 1 and "matches no cell" in str(warnings[0])


def test_an_exclude_that_removes_every_cell_is_one_problem_at_the_exclude_key(write_scenario):
    """It once left the `default` cell of no matrix, whose every reference was then said to have no value."""
    path = write_scenario(
        "name: allx\nduration: 1s\nmatrix:\n  policy: [fifo, rr]\n  exclude:\n    - policy: fifo\n    - policy: rr\n"
        "processes:\n  - name: p\n    main:\n      sched: ${{ matrix.policy }}:10\n"
        "      work: {kind: periodic, period: 100ms, burn: 1ms}\n"
    )
    done = run_cli("validate", path)
    assert done.code == 2
    assert done.err == f"{path}:5:3: matrix.exclude: excludes every cell of the matrix; nothing would run\n"
    cells, _ = expand({"policy": ["fifo"], "exclude": [{"policy": "fifo"}], "include": [{"policy": "other"}]})
    assert [c.id for c in cells] == ["policy=other"], "a cell include adds is something to run"


def test_include_extends_matching_cells_and_adds_the_rest():
    # GitHub's documented example: fruit x animal with include
    cells, _ = expand(
        {
            "fruit": ["apple", "pear"],
            "animal": ["cat", "dog"],
            "include": [
                {"color": "green"},
                {"color": "pink", "animal": "cat"},
                {"fruit": "apple", "shape": "circle"},
                {"fruit": "banana"},
                {"fruit": "banana", "animal": "cat"},
            ],
        }
    )
    assert [c.values for c in cells] == [
        {"fruit": "apple", "animal": "cat", "color": "pink", "shape": "circle"},
        {"fruit": "apple", "animal": "dog", "color": "green", "shape": "circle"},
        {"fruit": "pear", "animal": "cat", "color": "pink"},
        {"fruit": "pear", "animal": "dog", "color": "green"},
        {"fruit": "banana"},
        {"fruit": "banana", "animal": "cat"},
    ]


def test_include_only_matrix():
    cells, _ = expand({"include": [{"mode": "a"}, {"mode": "b", "n": 2}]})
    assert [c.id for c in cells] == ["mode=a", "mode=b,n=2"]


def test_no_matrix_is_one_default_cell():
    cells, _ = expand(None)
    assert [c.id for c in cells] == ["default"]


def test_whole_references_keep_types_and_partial_ones_interpolate():
    data = {"p": "${{ matrix.prio }}", "s": "fifo:${{ matrix.prio }}", "b": "${{matrix.on}}", "matrix": {"keep": "${{ matrix.prio }}"}}
    out = mx.substitute(data, {"prio": 80, "on": True})
    assert out == {"p": 80, "s": "fifo:80", "b": True, "matrix": {"keep": "${{ matrix.prio }}"}}


SCENARIO = """\
name: m
matrix:
  policy: [fifo, rr]
  priority: [10, 80]
  include:
    - {policy: other, priority: 0}
processes:
  - name: app
    main:
      sched:
        policy: ${{ matrix.policy }}
        priority: ${{ matrix.priority }}
      work: {kind: periodic, period: 10ms}
expect:
  - {thread: app, metric: involuntary.per_callback_mean, max: 0.5, cells: {policy: [fifo, rr]}}
"""


def test_cells_resolve_to_typed_scenarios():
    loaded = parse_scenario(load_text(SCENARIO, "m.yaml"))
    assert [c.id for c in loaded.cells][-1] == "policy=other,priority=0"
    fifo80 = loaded.cells[1].scenario.processes[0].main.sched
    assert (fifo80.policy.value, fifo80.priority) == ("fifo", 80)
    assert len({c.spec_hash for c in loaded.cells}) == 5


def test_cell_selector_values_must_exist():
    bad = SCENARIO.replace("cells: {policy: [fifo, rr]}", "cells: {policy: [fifo, deadline]}")
    with pytest.raises(ScenarioError, match="policy=deadline matches no cell"):
        parse_scenario(load_text(bad, "m.yaml"))


def test_select():
    cells, _ = expand({"policy": ["fifo", "rr", "other"]})
    assert [c.id for c in mx.select(cells, {"policy": ["fifo", "other"]})] == ["policy=fifo", "policy=other"]


def test_include_cannot_grow_the_matrix_past_its_cap():
    doc = load_text("x: 1\n", "f")
    problems, warnings = [], []
    block = {f"a{i}": ["x", "y"] for i in range(12)}
    block["include"] = [{"a0": "z"}]
    cells = mx.expand(doc, mx.parse(doc, block, problems), problems, warnings)
    assert cells == [] and [p.message for p in problems] == ["the matrix has 4097 cells with its include entries; at most 4096"]


@pytest.mark.parametrize(
    "block, message",
    [
        ({"include": [{"x": i} for i in range(257)]}, "257 include entries; at most 256"),
        ({"a": [1], "exclude": [{"a": 2}] * 257}, "257 exclude entries; at most 256"),
        ({"a": ["x\ny"]}, r"matrix value 'x\\ny' contains the control character '\\n'"),
        ({"include": [{"a": "\x1b[2J"}]}, r"contains the control character '\\x1b'"),
        ({"include": [{"bad key": 1}]}, "matrix key 'bad key' must be a letter"),
        ({"a": ["${{ matrix.b }}"]}, "matrix values are not expanded again"),
        ({"a": [float("nan")]}, "is not a finite number"),
        ({f"k{i}": [1] for i in range(65)}, "the matrix has 65 keys; at most 64"),
    ],
)
def test_matrix_block_problems(block, message):
    doc = load_text("x: 1\n", "f")
    problems = []
    mx.parse(doc, block, problems)
    assert any(re.search(message, p.message) for p in problems), problems


def _big_matrix(axes: int) -> str:
    """A scenario of 2**axes cells: one thread per axis, whose burn the axis sets, and one expectation selecting cells."""
    keys = "".join(f"  a{i}: [{2 * i + 1}ms, {2 * i + 2}ms]\n" for i in range(axes))
    threads = "".join(
        f"      - {{name: t{i}, work: {{kind: periodic, period: 100ms, burn: '${{{{ matrix.a{i} }}}}'}}}}\n" for i in range(axes)
    )
    return (
        f"name: big\nmatrix:\n{keys}processes:\n  - name: app\n    threads:\n{threads}"
        "expect:\n  - {thread: t0, metric: latency.p99, max: 2ms, cells: {a0: [1ms]}}\n"
    )


def test_validation_is_linear_in_cells(monkeypatch):
    """4096 cells used to take 37 s: cross checks searched every cell for every cell.

    Counted, not timed (a timed bound failed on a slow VM): the matrix's per-value and per-cell
    steps a validation makes grow with the cells' values, cells times axes (4x the cells with 10
    axes instead of 8: at most 1.25x the steps per value, where searching every cell for every
    cell made 4x).
    """
    from runner.scenario import loader as sc

    steps = [0]

    def counted(real):
        def step(*args, **kwargs):
            steps[0] += 1
            return real(*args, **kwargs)

        return step

    for module, name in ((mx, "format_value"), (mx, "select"), (sc, "_check_cell")):
        monkeypatch.setattr(module, name, counted(getattr(module, name)))
    per_value = []
    for axes in (8, 10):
        steps[0] = 0
        assert len(parse_scenario(load_text(_big_matrix(axes), "big.yaml")).cells) == 2**axes
        per_value.append(steps[0] / (2**axes * axes))
    assert per_value[0] >= 1 and per_value[1] <= 1.25 * per_value[0], per_value


def test_cells_that_resolve_alike_are_validated_once(monkeypatch):
    from runner.scenario import loader as sc

    calls = []
    real = sc._check_cell
    monkeypatch.setattr(sc, "_check_cell", lambda *a: calls.append(1) or real(*a))
    # `label` only names the cells (and selects them); `p` changes what runs
    text = (
        "name: m\nmatrix:\n  include:\n    - {label: a, p: 10}\n    - {label: b, p: 10}\n    - {label: c, p: 20}\n"
        "processes:\n  - name: app\n    main: {sched: 'fifo:${{ matrix.p }}', work: {kind: periodic, period: 10ms}}\n"
        "expect:\n  - {thread: app, metric: callbacks, min: 1, cells: {label: [a, c]}}\n"
    )
    loaded = parse_scenario(load_text(text, "m.yaml"))
    assert [c.id for c in loaded.cells] == ["label=a,p=10", "label=b,p=10", "label=c,p=20"]
    assert len(calls) == 2
    assert loaded.cells[0].spec_hash == loaded.cells[1].spec_hash != loaded.cells[2].spec_hash


def test_a_large_matrix_of_a_file_with_a_long_text_takes_the_memory_of_the_file(tmp_path):
    """Cells were told apart by their whole resolved file: 4,096 cells of a 0.2 MB file held 830 MB, of a 1 MiB one 4 GiB."""
    import tracemalloc

    from runner.scenario.loader import load_scenario

    path = tmp_path / "m.yaml"
    path.write_text(
        "name: m\nmatrix:\n  a: [" + ", ".join(str(i) for i in range(1, 33)) + "]\n  b: [" + ", ".join(map(str, range(32))) + "]\n"
        "processes:\n  - name: p\n    main: {work: sleep, sched: 'fifo:${{ matrix.a }}'}\n"
        "    threads: [{name: t, sched: '${{ matrix.b }}', work: sleep}]\n"
        '  - name: q\n    command: [/bin/true, "' + "x" * 200_000 + '"]\n',
        encoding="utf-8",
    )
    tracemalloc.start()
    try:
        with pytest.raises(ScenarioError, match=r"in 32 of 1024 cells"):  # sched: '5' is no policy, in every cell with b=5
            load_scenario(str(path), for_run=False)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 40 * 2**20, f"{peak / 2**20:.0f} MiB for 1,024 cells of a 0.2 MB file"
