"""Every invalid scenario of the corpus gives its line-numbered message, exit 2, no traceback."""

from __future__ import annotations

import glob
import os
import re
import subprocess
import sys

import pytest
from conftest import REPO, run_cli

from runner.errors import ScenarioError
from runner.scenario.loader import load_scenario

CORPUS = sorted(glob.glob(os.path.join(REPO, "tests", "invalid", "*.yaml")))


def expectations(path: str) -> list[str]:
    with open(path) as handle:
        return [m.group(1) for line in handle if (m := re.match(r"# expect: (.*)$", line))]


@pytest.mark.parametrize("path", CORPUS, ids=os.path.basename)
def test_each_problem_is_reported_at_its_line(path):
    wanted = expectations(path)
    assert wanted, f"{path} has no '# expect:' line"
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    reported = [str(p) for p in caught.value.problems]
    for expect in wanted:
        prefix = f"{path}:{expect}"
        assert any(r.startswith(prefix) for r in reported + [str(w) for w in []]) or any(prefix in r for r in reported), (
            f"missing {prefix!r}\nreported:\n" + "\n".join(reported)
        )


@pytest.mark.parametrize("path", CORPUS, ids=os.path.basename)
def test_validate_exits_2_with_every_problem(path):
    outcome = run_cli("validate", path)
    assert outcome.code == 2
    for expect in expectations(path):
        assert f"{path}:{expect}" in outcome.err


def test_no_traceback_in_a_real_process():
    paths = CORPUS[:3]
    proc = subprocess.run([sys.executable, "-m", "runner", "validate", *paths], capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.count(":") >= 3 * len(paths)


def test_run_of_an_invalid_file_exits_2_without_starting_anything():
    path = os.path.join(REPO, "tests", "invalid", "priority_range.yaml")
    outcome = run_cli(path)
    assert outcome.code == 2
    assert "priority 100 is out of range" in outcome.err
    assert outcome.out == ""


def test_one_invalid_process_hides_no_cross_reference_problem_and_invents_none():
    """The processes that validate are cross-checked beside the one that does not; what that one names stays unjudged."""
    path = os.path.join(REPO, "tests", "invalid", "problems_beside_an_invalid_process.yaml")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    reported = sorted(str(p).removeprefix(f"{path}:") for p in caught.value.problems)
    assert reported == sorted(expectations(path)), "exactly the problems written in the file: none about t1 or p/t1"


def test_a_typo_of_a_required_key_is_one_problem_not_two():
    """`polcy:` for `policy:` is an unknown key with its "did you mean"; pydantic's "missing 'policy'" beside it says it again."""
    path = os.path.join(REPO, "tests", "invalid", "unknown_key.yaml")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    assert [str(p).removeprefix(f"{path}:") for p in caught.value.problems] == expectations(path)


def test_a_required_key_left_out_with_no_typo_near_it_is_still_missing(write_scenario):
    path = write_scenario("name: x\nprocesses:\n  - name: app\n    main: {sched: {priority: 80, colour: red}, work: spin}\n")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    reported = [str(p).removeprefix(f"{path}:") for p in caught.value.problems]
    assert "4:19: processes[0].main.sched.policy: missing required key 'policy'" in reported, reported
    assert any("unknown key 'colour'" in r for r in reported), reported


def test_a_rule_on_phases_written_as_events_is_said_at_the_work_as_written(write_scenario):
    """`events:` directly under a work is its one phase: a rule on `phases` points at the work, never at a `phases` key
    the file does not have."""
    events = "".join("          - run: 1us\n" for _ in range(129))
    path = write_scenario(
        "processes:\n  - name: a\n    threads:\n      - name: t\n        work:\n          kind: phases\n          events:\n" + events
    )
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    assert [str(p).removeprefix(f"{path}:") for p in caught.value.problems] == [
        "6:11: processes[0].threads[0].work: 129 events in all phases; at most 128 per thread"
    ]


def test_a_policy_given_as_a_number_is_told_the_forms_a_policy_takes(write_scenario):
    path = write_scenario("processes:\n  - name: a\n    main: {sched: 80}\n")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    (problem,) = caught.value.problems
    assert str(problem).startswith(f"{path}:3:19: processes[0].main.sched: 80 is not a policy; expected other, batch, idle, fifo:1..99")
