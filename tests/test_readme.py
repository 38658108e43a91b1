"""The documentation's examples are checked against the tool, so it cannot drift from the tool unseen.

Every fenced ```yaml block of README.md and docs/*.md that is a whole scenario (a top-level `processes:` key,
the one key a scenario needs: `name` defaults to the file name) is validated as `runner validate`
validates it.  Fragments (a few top-level keys shown on their own) have no `processes:` and are
skipped; a block whose first line is `# fragment` is skipped too, and one whose first line is
`# invalid` must be refused, so an example of a mistake stays one.  A ```text block that shows
`$ runner validate FILE` shows what the tool prints for that file of the repository, exactly.
"""

from __future__ import annotations

import argparse
import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import REPO, run_cli

from runner.errors import ScenarioError
from runner.scenario.loader import load_scenario

README = os.path.join(REPO, "README.md")
# where the examples are: the README and the documentation it links to, each named as from the repository's root
DOCS = [README, *sorted(glob.glob(os.path.join(REPO, "docs", "*.md")))]
_FENCE = re.compile(r"^(?P<indent>[ \t]*)```yaml[ \t]*\n(?P<body>.*?)^(?P=indent)```", re.M | re.S)
_VALIDATE_SAMPLE = re.compile(r"^```text\n\$ runner validate (?P<args>[^\n]*)\n(?P<output>.*?)^```", re.M | re.S)


@dataclass(frozen=True)
class Block:
    """A fenced yaml block of a markdown text: its text, dedented, the line its first line is on, and its file."""

    line: int
    text: str
    file: str = "README.md"

    @property
    def marker(self) -> str:
        """`fragment`, `invalid` or '' from a first line `# fragment` / `# invalid`: how the block is meant."""
        first = self.text.split("\n", 1)[0].strip()
        return first[1:].strip().split()[0] if re.fullmatch(r"#\s*(fragment|invalid)\b.*", first) else ""

    @property
    def is_scenario(self) -> bool:
        """Whether the block is a whole scenario: it has a top-level `processes:` key."""
        return re.search(r"^processes:", self.text, re.M) is not None


def yaml_blocks(text: str, file: str = "README.md") -> list[Block]:
    """Every fenced ```yaml block of `text` (the markdown file `file`), with the 1-based line of its first line of YAML."""
    blocks = []
    for match in _FENCE.finditer(text):
        indent = match.group("indent")
        body = "".join(line[len(indent) :] if line.startswith(indent) else line for line in match.group("body").splitlines(True))
        blocks.append(Block(text.count("\n", 0, match.start("body")) + 1, body, file))
    return blocks


def scenario_blocks(text: str, file: str = "README.md") -> list[Block]:
    """The blocks of `text` that are whole scenarios and not marked as fragments."""
    return [b for b in yaml_blocks(text, file) if b.is_scenario and b.marker != "fragment"]


def problems_of(block: Block, folder: Path) -> list[str]:
    """What `runner validate` reports for `block` (the same loader, with for_run False), at its markdown file's lines."""
    path = folder / f"doc-line-{block.line}.yaml"
    path.write_text(block.text, encoding="utf-8")
    try:
        load_scenario(str(path), for_run=False)
    except ScenarioError as exc:
        return [f"{block.file}:{block.line + p.line - 1}:{p.col}: {p.path}: {p.message}" for p in exc.problems if p.severity == "error"]
    return []


def _read(path: str) -> str:
    with open(path, encoding="utf-8") as handle:
        return handle.read()


def _readme() -> str:
    return _read(README)


def _name(path: str) -> str:
    return os.path.relpath(path, REPO)


BLOCKS = [block for path in DOCS for block in scenario_blocks(_read(path), _name(path))]


def test_the_docs_have_their_scenario_examples():
    """The format, matrix, programs and command: examples are all found; an empty list would check nothing.
    The README keeps one (measure your own program), docs/scenarios.md the format's."""
    assert len(BLOCKS) >= 5, [(b.file, b.line) for b in BLOCKS]
    assert {"README.md", "docs/scenarios.md"} <= {b.file for b in BLOCKS}


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: f"{b.file}:{b.line}")
def test_each_scenario_example_of_the_docs_is_valid_as_written(block, tmp_path):
    problems = problems_of(block, tmp_path)
    if block.marker == "invalid":
        assert problems, f"the block at {block.file}:{block.line} is marked invalid, but runner validate accepts it"
    else:
        assert not problems, f"the scenario at {block.file}:{block.line} is invalid:\n" + "\n".join(problems)


def test_blocks_are_found_at_their_line_and_fragments_are_told_apart():
    text = "intro\n\n```yaml\nname: a\nprocesses: []\n```\n\n  ```yaml\n  latency_bound: 1ms\n  ```\n```yaml\n# fragment\nprocesses:\n```\n"
    blocks = yaml_blocks(text)
    assert [(b.line, b.is_scenario, b.marker) for b in blocks] == [(4, True, ""), (9, False, ""), (12, True, "fragment")]
    assert blocks[1].text == "latency_bound: 1ms\n"
    assert scenario_blocks(text) == blocks[:1]


def test_a_problem_is_reported_at_its_readme_line(tmp_path):
    (block,) = yaml_blocks("\n\n```yaml\nname: a\nprocesses:\n  - name: app\n    main: {sched: fifo:100}\n```\n")
    (problem,) = problems_of(block, tmp_path)
    assert problem.startswith("README.md:7:") and "priority 100 is out of range" in problem, problem


VALIDATE_SAMPLES = [(m.group("args"), m.group("output")) for path in DOCS for m in _VALIDATE_SAMPLE.finditer(_read(path))]


def test_the_docs_show_a_validate_sample():
    assert VALIDATE_SAMPLES, "the docs' sample of runner validate's output was not found"


@pytest.mark.parametrize("args, shown", VALIDATE_SAMPLES, ids=[a for a, _ in VALIDATE_SAMPLES])
def test_the_docs_validate_sample_is_what_the_tool_prints(args, shown, monkeypatch):
    """The sample is run from the repository's root, as its relative paths are written."""
    monkeypatch.chdir(REPO)
    done = run_cli("validate", *args.split())
    assert done.out + done.err == shown


def _synopsis() -> dict[str, str]:
    """The `## Commands` block's entries by command (`run` for `runner SCENARIO.yaml`, `` for `runner --help`),
    each entry's lines joined, comments left out."""
    from runner.cli import COMMANDS

    commands = _readme().split("\n## Commands\n", 1)[1]
    block = commands.split("```text\n", 1)[1].split("```", 1)[0]
    entries: dict[str, str] = {}
    command = ""
    for line in block.splitlines():
        text = line.split("#", 1)[0]
        if line.startswith("runner "):
            word = text.split()[1]
            command = word if word in COMMANDS else "" if word.startswith("-") else "run"
        entries[command] = entries.get(command, "") + " " + text
    return entries


def _options(text: str) -> set[str]:
    return set(re.findall(r"(?<![\w-])(--?[a-z][a-z0-9-]*)", text))


def test_the_synopsis_of_commands_is_what_help_says():
    """Every option each command's --help lists is in README's synopsis and the synopsis has none the command lacks;
    the arguments are named as the usage names them (SCENARIO.yaml, PID|NAME).  The synopsis had left out
    --no-trace and --allow-priority-99 of a run, report's --threshold and --no-plots, compare's -o, merge's
    --threshold and --no-plots."""
    from runner.cli import _PARSERS

    synopsis = _synopsis()
    assert set(synopsis) == {*_PARSERS, ""}, sorted(synopsis)
    assert _options(synopsis[""]) == {"--help", "--version"} and run_cli("--version").code == 0
    wrong = []
    for command, build in _PARSERS.items():
        actions = [a for a in build()._actions if a.help != argparse.SUPPRESS and "--help" not in a.option_strings]
        written = _options(synopsis[command])
        for action in actions:
            if action.option_strings and not written & set(action.option_strings):
                wrong.append(f"runner {command}: {'/'.join(action.option_strings)} is not in the synopsis")
            name = str(action.metavar or action.dest)  # what the usage calls the argument
            if not action.option_strings and not re.search(rf"(?<!\S){re.escape(name)}(?:\.\.\.)?(?!\S)", synopsis[command]):
                wrong.append(f"runner {command}: its argument {name} is not named so in the synopsis")
        known = {o for a in actions for o in a.option_strings}
        wrong += [f"runner {command}: the synopsis has {o}, which --help does not" for o in sorted(written - known)]
    assert not wrong, "\n".join(wrong)


def test_the_readmes_own_programs_are_the_shipped_scenarios():
    """README's "Measure your own program" and "Your ROS 2 node" show scenarios/own_program.yaml and
    scenarios/ros2/minimal_scheduling_main_thread.yaml as shipped (their descriptions left out), so a user who copies
    one gets the file the tests check."""
    import glob

    import yaml

    shipped = {}
    for path in glob.glob(os.path.join(REPO, "scenarios", "**", "*.yaml"), recursive=True):
        data = yaml.safe_load(_read(path))
        del data["description"]
        shipped[data["name"]] = data
    blocks = [yaml.safe_load(b.text) for b in BLOCKS if b.file == "README.md" and "command:" in b.text]
    assert [b["name"] for b in blocks] == ["own_program", "ros2_main_thread"]
    for block in blocks:
        assert block == shipped[block["name"]]
