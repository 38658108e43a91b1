from __future__ import annotations

import pytest
import yaml

from runner.errors import ScenarioError
from runner.scenario.yamlsource import load_file, load_text


def test_positions_of_keys_and_values():
    doc = load_text("a:\n  b: [1, 2]\n  c: x\n", "f.yaml")
    assert doc.data == {"a": {"b": [1, 2], "c": "x"}}
    assert doc.mark(("a", "b", 1)).line == 2
    assert (doc.mark(("a", "c")).line, doc.mark(("a", "c")).col) == (3, 6)
    assert (doc.mark(("a", "c"), key=True).line, doc.mark(("a", "c"), key=True).col) == (3, 3)


def test_keys_stay_the_text_written():
    assert load_text("on: 1\nno: 2\n", "f").data == {"on": 1, "no": 2}


def test_duplicate_keys_are_errors_not_overwrites():
    with pytest.raises(ScenarioError, match=r"f:3:1: b: duplicate key 'b' \(first at line 2\)"):
        load_text("a: 1\nb: 2\nb: 3\n", "f")


def test_merge_keys_and_aliases_work():
    doc = load_text("base: &b {x: 1, y: 2}\nthing:\n  <<: *b\n  y: 3\n", "f")
    assert doc.data["thing"] == {"x": 1, "y": 3}


@pytest.mark.parametrize("text", ["a: !!python/name:os.system x\n", "a: !custom 3\n", "a: !!python/tuple [1]\n"])
def test_object_tags_are_refused(text):
    with pytest.raises(ScenarioError, match="unsupported YAML tag"):
        load_text(text, "f")


def test_timestamps_are_not_silently_dates():
    with pytest.raises(ScenarioError, match="quote it"):
        load_text("a: 2024-01-01\n", "f")


def test_absurd_nesting_is_refused_quickly():
    with pytest.raises(ScenarioError, match="nesting is too deep"):
        load_text("a: " + "[" * 200 + "]" * 200 + "\n", "f")


def test_empty_file():
    with pytest.raises(ScenarioError, match="the file is empty"):
        load_text("", "f")


def test_binary_and_hex_literals_keep_their_spelling():
    # YAML 1.1 would read 0b1100 as 12, which as a CPU set means CPU 12, not CPUs 2 and 3
    assert load_text("cpus: 0b1100\nm: 0x3\nn: 12\n", "f").data == {"cpus": "0b1100", "m": "0x3", "n": 12}


# libyaml (PyPI's PyYAML) refuses a lone surrogate while it scans; PyYAML's own parser lets the loader say it
LONE_SURROGATE = (
    ('a: "\\ud800"\n', r"f:1:7: invalid YAML: .*invalid Unicode character escape code; .* a lone UTF-16 surrogate such as \\ud800")
    if yaml.__with_libyaml__
    else ('a: "\\ud800"\n', r"f:1:4: a: '\\ud800' is not a character")
)


@pytest.mark.parametrize(
    "text, message",
    [
        ("name: x\x01\n", r"f:1:8: invalid YAML: character '\\x01' is not allowed"),
        ("name: é\x01\n", r"f:1:8: invalid YAML: character '\\x01' is not allowed"),  # libyaml counts bytes: 1:9 unless converted
        ("a: 1\nname: ééé\x01\n", r"f:2:10: invalid YAML: character '\\x01' is not allowed"),
        ("a: 1\nb: x\ud800\n", r"f:2:5: invalid YAML: '\\ud800' is not a character \(a lone UTF-16 surrogate\)"),
        ("r: &r\n  <<: *r\n", r"f:1:4: r: an alias refers to a node that contains it"),
        ("r: &r\n  <<: [*r]\n", r"f:1:4: r: an alias refers to a node that contains it"),
        ("a: &a [1, *a]\n", r"f:1:4: a\[1\]: an alias refers to a node that contains it"),
        ("a: !!int abc\n", r"f:1:4: a: 'abc' cannot be read as int"),
        ("a: !!bool maybe\n", r"f:1:4: a: 'maybe' cannot be read as bool"),
        ("a: !!timestamp x\n", r"f:1:4: a: 'x' cannot be read as timestamp"),
        ("a: " + "1" * 5000 + "\n", r"f:1:4: a: '11111111111111111111…1111111111' cannot be read as int"),
        LONE_SURROGATE,
        ("a: !!binary aGk=\n", r"unsupported YAML tag 'tag:yaml.org,2002:binary'"),
    ],
)
def test_hostile_text_gives_problems_not_exceptions(text, message):
    with pytest.raises(ScenarioError, match=message):
        load_text(text, "f")


def test_problems_never_print_raw_control_characters():
    with pytest.raises(ScenarioError) as caught:
        load_text('"a\\nb": [1\n', "f")
    doc = load_text('"a\\nb\\e": 1\n', "f")
    problem = doc.problem(("a\nb\x1b",), "value 'x\ny' is wrong")
    assert str(problem).endswith(": ['a\\nb\\x1b']: value 'x\\ny' is wrong")
    assert "\n" not in str(caught.value.problems[0])


def test_own_keys_win_over_merged_ones_wherever_the_merge_is():
    doc = load_text("base: &b {x: 1, y: 2}\nthing:\n  y: 3\n  <<: *b\n", "f")
    assert doc.data["thing"] == {"x": 1, "y": 3}
    assert doc.mark(("thing", "y")).line == 3


def test_libyaml_is_used_only_where_it_refuses_deep_nesting_itself(monkeypatch):
    """libyaml builds nodes by recursion in compiled code: one without its own nesting limit (before 0.2.6) is not used."""
    from runner.scenario import yamlsource

    class Unlimited(yaml.SafeLoader):  # composes anything, as an older libyaml would, without recursing here
        def get_single_node(self):
            return None

    try:
        yamlsource._loader_class.cache_clear()
        assert yamlsource._loader_class() is (yaml.CSafeLoader if yaml.__with_libyaml__ else yaml.SafeLoader)
        yamlsource._loader_class.cache_clear()
        monkeypatch.setattr(yaml, "CSafeLoader", Unlimited)
        assert yamlsource._loader_class() is yaml.SafeLoader
        yamlsource._loader_class.cache_clear()
        monkeypatch.delattr(yaml, "CSafeLoader")
        assert yamlsource._loader_class() is yaml.SafeLoader
        assert load_text("a: [1, {b: 2}]\n", "f").data == {"a": [1, {"b": 2}]}
    finally:
        monkeypatch.undo()
        yamlsource._loader_class.cache_clear()


def test_a_byte_that_is_not_utf8_is_reported_at_its_line_and_column(tmp_path):
    """A Latin-1 é in a comment on line 5 was once reported at 1:1."""
    path = tmp_path / "s.yaml"
    path.write_bytes(b"name: x\nprocesses:\n  - name: app\n    main: {work: {kind: periodic, period: 10ms}}\n# caf\xe9\n")
    with pytest.raises(ScenarioError) as err:
        load_file(str(path))
    assert str(err.value.problems[0]) == f"{path}:5:6: not UTF-8 text: byte 0xe9 (invalid continuation byte)"


def _scenario(tmp_path, name: str, body: str) -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text("name: t\nprocesses:\n  - name: p\n" + body, encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(
    "name, body",
    [
        ("value", "    main: {work: sleep, sched: '" + "y" * 100_000 + "'}\n"),
        ("key", "    main:\n      work: sleep\n      ? " + "k" * 100_000 + "\n      : 1\n"),  # YAML's explicit key: no 1,024 limit
        ("tag", "    main: {work: sleep, sched: !" + "t" * 100_000 + " x}\n"),
        ("spaced", "    main: {work: sleep, sched: '" + "a b " * 25_000 + "'}\n"),
        (
            "repeated",
            "    main: {work: sleep}\n    threads:\n" + "".join(f"      - {{name: t{i}, sched: '{'z' * 1000}'}}\n" for i in range(100)),
        ),
        (
            "aliased",
            "    main: {work: sleep, sched: &a '"
            + "w" * 100_000
            + "'}\n    threads:\n"
            + "".join(f"      - {{name: t{i}, sched: *a}}\n" for i in range(30)),  # 3 MB: short of the aliases' bound
        ),
    ],
)
def test_problems_quote_long_values_cut_to_a_readable_line(tmp_path, name, body):
    """A 0.1 MB file printed 100 MB: each problem quoted its value whole, and an aliased one in every place it went."""
    from conftest import run_cli

    path = _scenario(tmp_path, name, body)
    done = run_cli("validate", path)
    assert done.code == 2 and "Traceback" not in done.err
    lines = done.err.splitlines()
    assert lines and all(len(line) < len(path) + 1_000 for line in lines), max(map(len, lines))
    assert len(done.err) < 120_000 and "…" in done.err


def test_a_problem_cuts_long_quoted_values_but_not_its_words():
    from runner.errors import Problem

    long = "x" * 500
    said = Problem("f", 1, 1, "a", f"the thread's {long} and {long!r} is not 'ok'; expected 'fifo:80'").message
    assert said.startswith(f"the thread's {long} and 'xxxx") and "…" in said and said.endswith(" is not 'ok'; expected 'fifo:80'")
    assert len(said) < 700
    assert Problem("f", 1, 1, "a", "x" * 10_000).message.count("x") < 4_000  # no quote at all: the whole is bounded
