"""What an editor shows on a scenario file: yaml-language-server's language service, as VS Code's YAML extension runs it.

The service is driven by .ci/yamlls.cjs (installed from npm by .ci/run; these tests are skipped with the reason
where it is not, and fail in CI).  Each buffer is known by a path in scenarios/, as an editor knows the file it
edits, and no schema is configured: the schema checked against is the one the buffer's first-line modeline
names, read from disk.  Without the modeline an editor checks nothing, which is what five shipped scenarios did.
"""

from __future__ import annotations

import glob
import os
import re
from typing import Any

from conftest import SCENARIOS, editor_answers

from runner import units
from runner.scenario.model import SCHED_FORMS, SCHED_PATTERN
from runner.scenario.schema import scenario_schema

MODELINE = "# yaml-language-server: $schema=../runner.schema.json"
SHIPPED = sorted(glob.glob(os.path.join(SCENARIOS, "*.yaml")))
NEW = os.path.join(SCENARIOS, "new.yaml")  # a buffer not yet saved, beside the shipped ones
HEAD = f"{MODELINE}\nname: new\nprocesses:\n"


def test_every_shipped_scenario_names_the_schema_on_its_first_line():
    assert SHIPPED
    missing = [os.path.basename(p) for p in SHIPPED if open(p, encoding="utf-8").readline().rstrip("\n") != MODELINE]
    assert not missing, f"no `{MODELINE}` on the first line of: {', '.join(missing)}"


def _mistyped(text: str) -> str:
    """`text` with its top-level `duration:` key written `duraton:`."""
    typo, count = re.subn(r"^duration:", "duraton:", text, count=1, flags=re.MULTILINE)
    assert count == 1
    return typo


def test_a_mistyped_key_in_every_shipped_scenario_is_underlined_at_its_line(tmp_path):
    texts = {path: open(path, encoding="utf-8").read() for path in SHIPPED}
    requests: list[dict[str, object]] = []
    for path, text in texts.items():
        typo = _mistyped(text)
        bare = "".join(typo.splitlines(keepends=True)[1:])  # the modeline left out: the editor knows no schema
        requests += [{"file": path, "text": text}, {"file": path, "text": typo}, {"file": path, "text": bare}]
    answers = iter(editor_answers(requests, tmp_path))
    wrong = []
    for path, text in texts.items():
        name = os.path.basename(path)
        as_written, typo, bare = (next(answers)["diagnostics"] for _ in range(3))
        line = next(i for i, x in enumerate(_mistyped(text).splitlines()) if x.startswith("duraton:"))
        if as_written:
            wrong.append(f"{name} as shipped: {as_written}")
        if [(d["line"], "duraton" in d["message"]) for d in typo] != [(line, True)]:
            wrong.append(f"{name} with duraton: {typo}")
        if bare:
            wrong.append(f"{name} without its modeline is checked against something: {bare}")
    assert not wrong, "\n".join(wrong)


def _items(answer: dict[str, Any]) -> list[dict[str, str]]:
    (items,) = answer["completions"]
    return list(items)


def test_a_new_process_is_offered_the_program_form(tmp_path):
    """`command:` was offered for an empty list item, but not once `name:` was written: the runner's own form fits
    `{name: app}` first, and yaml-language-server completes the keys of the form that fits."""
    named, empty = editor_answers(
        [
            {"file": NEW, "text": HEAD + "  - name: app\n    \n", "complete": [[4, 4]]},
            {"file": NEW, "text": HEAD + "  - \n", "complete": [[3, 4]]},
        ],
        tmp_path,
    )
    inserted = [i["insertText"] for i in _items(named)]
    assert any(text.startswith("command:\n") for text in inserted), inserted
    assert "main" in [i["label"] for i in _items(named)]  # the runner's own form's keys stay offered
    assert any(re.match(r"name: .*\n\s+command:\n", text) for text in (i["insertText"] for i in _items(empty)))


def test_sched_completions_are_labelled_as_written(tmp_path):
    (answer,) = editor_answers([{"file": NEW, "text": HEAD + "  - name: app\n    main:\n      sched: \n", "complete": [[5, 13]]}], tmp_path)
    labels = [i["label"] for i in _items(answer)]
    assert "[object Object]" not in labels and {"fifo:80", "{policy: other, nice: -5}"} <= set(labels), labels
    (snippet,) = [i["insertText"] for i in _items(answer) if i["label"] == "{policy: other, nice: -5}"]
    assert snippet.split() == ["policy:", "other", "nice:", "-5"]


WORDS = [
    ("sched: fifo:200", "main", SCHED_FORMS),
    ("sched: SCHED_FIFIO:80", "main", SCHED_FORMS),
    ("cpus: 1-x", "main", units.CPUS_EXPECTED),
    ("work: {kind: periodic, period: 10 msec}", "main", units.DURATION_EXPECTED),
    ("prealloc: 50MB", "memory", units.SIZE_EXPECTED),
]


def test_a_value_that_misses_its_pattern_is_told_in_words(tmp_path):
    """`sched: fifo:200` showed the 500-character pattern of every sched form; the words are runner validate's own."""
    texts = [HEAD + f"  - name: app\n    {holder}:\n      {line}\n" for line, holder, _ in WORDS]
    answers = editor_answers([{"file": NEW, "text": text} for text in texts], tmp_path)
    for (line, _, expected), answer in zip(WORDS, answers):
        assert [(d["line"], d["message"]) for d in answer["diagnostics"]] == [(5, f"expected {expected}")], line


def _walk(node: Any, inside: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], dict[str, Any]]]:
    """Every schema object of `node` with the keywords above it."""
    found: list[tuple[tuple[str, ...], dict[str, Any]]] = []
    if isinstance(node, dict):
        found.append((inside, node))
        for key, value in node.items():
            found += _walk(value, inside + (key,))
    elif isinstance(node, list):
        for value in node:
            found += _walk(value, inside)
    return found


def test_no_example_is_a_mapping():
    """yaml-language-server labels a mapping example `[object Object]`: mappings are snippets with a label of their own."""
    examples = [(inside, node["examples"]) for inside, node in _walk(scenario_schema()) if isinstance(node.get("examples"), list)]
    assert examples
    assert not [(inside, e) for inside, values in examples for e in values if isinstance(e, dict)]
    snippets = [s for _, node in _walk(scenario_schema()) for s in node.get("defaultSnippets", [])]
    assert all(isinstance(s["label"], str) and "body" in s for s in snippets) and len(snippets) >= 5


def test_every_pattern_an_editor_reports_has_words():
    """A pattern's own text is what an editor shows otherwise; those under `if` (a condition) and `not` report nothing."""
    bare = [
        "/".join(inside)
        for inside, node in _walk(scenario_schema())
        if "pattern" in node
        and "if" not in inside
        and "not" not in inside
        and not str(node.get("patternErrorMessage", "")).startswith("expected ")
    ]
    assert not bare, bare


def test_the_words_of_a_pattern_are_those_of_its_declaration():
    words = {
        units.DURATION_PATTERN: units.DURATION_EXPECTED,
        units.SIZE_PATTERN: units.SIZE_EXPECTED,
        units.CPUS_PATTERN: units.CPUS_EXPECTED,
        SCHED_PATTERN: SCHED_FORMS,
    }
    seen = {pattern: 0 for pattern in words}
    for _, node in _walk(scenario_schema()):
        if node.get("pattern") in words:
            assert node["patternErrorMessage"] == f"expected {words[node['pattern']]}"
            seen[node["pattern"]] += 1
    assert all(seen.values()), seen
