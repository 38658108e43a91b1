"""The scenario schema says what `runner validate` says, in the validators editors and CI tools use.

Every shipped scenario, every file of the accepted-forms corpus (tests/valid) and every file of the
invalid corpus (tests/invalid) is judged three ways: by the loader as `runner validate` runs it, by
Python's jsonschema, and by ajv (JavaScript, strict mode, the schema's draft; the YAML read by the
`yaml` package yaml-language-server uses), installed from npm by .ci/run.  The verdicts must agree
file by file.  A file the YAML parser refuses counts as refused: the editor underlines it all the same.

The few files whose only problems a JSON Schema cannot express are listed in CANNOT_EXPRESS with the
reason; for them the test holds that both validators accept the file, so the list stays true.
"""

from __future__ import annotations

import glob
import json
import os

import jsonschema
from conftest import REPO, ajv_verdicts

from runner.errors import ScenarioError
from runner.scenario.limits import MachineLimits
from runner.scenario.loader import load_scenario, parse_scenario
from runner.scenario.schema import scenario_schema
from runner.scenario.yamlsource import load_file, load_text

FILES = sorted(
    glob.glob(os.path.join(REPO, "scenarios", "*.yaml"))
    + glob.glob(os.path.join(REPO, "tests", "valid", "*.yaml"))
    + glob.glob(os.path.join(REPO, "tests", "invalid", "*.yaml"))
)
MACHINE = MachineLimits(cpus=(0, 1), online=(0, 1))  # the 2-CPU machine the shipped scenarios are written for

CANNOT_EXPRESS = {
    "burn_exceeds_period.yaml": "burn < period compares two durations, each written with its own unit",
    "deadline_rules.yaml": "a deadline thread creating threads, or pinned inside its root domain, spans sched, apply and cpus",
    "huge_numbers.yaml": "the 24-digit limit counts digits without leading zeros and the decimal point; a pattern cannot",
    "matrix_cell_error.yaml": "the policy and priority come from the matrix: only a cell, with its values substituted, is wrong",
    "program_memory.yaml": "memory_max's minimum compares a size written with its own unit (4MiB, 4096KiB, 0.5GiB)",
    "matrix_include_cap.yaml": "the cell count is the product of the axes plus what include adds",
    "matrix_undefined_reference.yaml": "whether matrix.prio is an axis is a reference from one part of the file to another",
    "priospread_below_1.yaml": "priospread, pin and count span three keys and the machine's CPUs",
    "program_spawn.yaml": "a spawn event names a thread declared elsewhere in the process, and who spawns whom is a graph",
    "program_references.yaml": "resource names an event uses must be declared under resources: a reference across the file",
    "program_cross.yaml": "until: exit is refused beside the runner's own processes: a rule across the items of processes",
    "expectation_needs_a_period.yaml": "whether the thread an expectation names has a period depends on its events, elsewhere in the file",
    "expectation_a_program_thread_cannot_meet.yaml": "which figures a named thread has depends on its process, elsewhere in the file",
    "never_released.yaml": "an offset or delay compared with the scenario's duration, each written with its own unit",
    "queue_without_consumer.yaml": "whether any thread suspends on a queue another resumes is a reference across the file",
}


def _verdict(ok: bool) -> str:
    return "accept" if ok else "reject"


def runner_verdicts() -> dict[str, str]:
    out = {}
    for path in FILES:
        try:
            load_scenario(path, MACHINE, for_run=False)
            out[path] = "accept"
        except ScenarioError:
            out[path] = "reject"
    return out


def jsonschema_verdicts() -> dict[str, str]:
    validator = jsonschema.Draft202012Validator(scenario_schema())
    out = {}
    for path in FILES:
        try:
            data = load_file(path).data
        except ScenarioError:
            out[path] = "reject"  # not YAML the runner reads: the parser says so before any schema
            continue
        out[path] = _verdict(validator.is_valid(data))
    return out


def test_jsonschema_and_ajv_agree_with_runner_validate_on_every_file(tmp_path):
    expected = runner_verdicts()
    python = jsonschema_verdicts()
    javascript = {
        path: "accept" if v["verdict"] == "accept" else "reject" for path, v in ajv_verdicts(scenario_schema(), FILES, tmp_path).items()
    }
    wrong = []
    for path in FILES:
        name = os.path.basename(path)
        if name in CANNOT_EXPRESS and "/invalid/" in path:
            assert expected[path] == "reject", path
            want = "accept"  # the schema cannot see the problem: the list must stay true
        else:
            want = expected[path]
        for who, got in (("jsonschema", python[path]), ("ajv", javascript[path])):
            if got != want:
                wrong.append(f"{os.path.relpath(path, REPO)}: runner validate {expected[path]}s, {who} {got}s")
    assert not wrong, "\n".join(wrong)


def test_every_listed_exception_is_a_file_of_the_invalid_corpus():
    names = {os.path.basename(p) for p in FILES if "/invalid/" in p}
    assert set(CANNOT_EXPRESS) <= names


def test_the_corpora_cover_what_editors_got_wrong():
    """The forms of issue 15: shipped scenarios accepted, and these refused by both validators."""
    names = {os.path.basename(p) for p in FILES}
    for name in ("deadline.yaml", "priority_range.yaml", "name_too_long.yaml", "rtla_forms.yaml", "sched_forms.yaml", "cpus_forms.yaml"):
        assert name in names


SCHED_CASES = [
    ({"policy": "SCHED_FIFO", "priority": 80}, True),
    ({"policy": "FIFO", "priority": 80}, True),
    ("normal", True),
    ("fifo:${{ matrix.priority }}", True),
    ("deadline:2ms/8ms/10ms", True),
    ("f:80", True),
    ("o:-5", True),
    ("d:100us:1ms", True),
    ("fifo:0", False),
    ("fifo:100", False),
    ("deadline", False),
    ("other:-5", False),
    ("(?i:fifo):80", False),
    ({"policy": "fifo"}, False),
    ({"policy": "fifo", "priority": 80, "nice": 3}, False),
    ({"policy": "other", "priority": 80}, False),
    ({"policy": "deadline", "period": "10ms"}, False),
    ({"policy": "${{ matrix.policy }}", "priority": "${{ matrix.priority }}"}, True),
]
NAME_CASES = [("minimal_schedul", True), ("minimal_schedule", False), ("a b", False), ("a/b", False), ("", False), ("x\u200by", False)]
CPUS_CASES = [("all", True), ("0-7:2", True), ("0-7:2/4", True), ("0, 1", True), ("0 1", False), ("all,3", False), ("1-x", False)]


def test_single_values_in_both_validators(tmp_path):
    """One value per file, so a pattern that lets one form through cannot hide behind another error in the same file."""
    cases = (
        [({"name": "x", "processes": [{"name": "app", "main": {"sched": v}}]}, ok) for v, ok in SCHED_CASES]
        + [({"name": "x", "processes": [{"name": v}]}, ok) for v, ok in NAME_CASES]
        + [({"name": "x", "processes": [{"name": "app", "main": {"cpus": v}}]}, ok) for v, ok in CPUS_CASES]
    )
    validator = jsonschema.Draft202012Validator(scenario_schema())
    paths = []
    for i, (data, _) in enumerate(cases):
        path = tmp_path / f"case{i}.yaml"
        path.write_text(json.dumps(data), encoding="utf-8")  # JSON is YAML
        paths.append(str(path))
    javascript = ajv_verdicts(scenario_schema(), paths, tmp_path)
    for data, ok in cases:  # runner validate says the same (a reference needs a matrix: the corpus has those)
        if "${{" not in json.dumps(data):
            try:
                parse_scenario(load_text(json.dumps(data), "case.yaml"), MACHINE, for_run=False)
                assert ok, data
            except ScenarioError:
                assert not ok, data
    wrong = [
        f"{json.dumps(data)}: wanted {_verdict(ok)}, jsonschema {_verdict(validator.is_valid(data))}, ajv {javascript[path]['verdict']}"
        for (data, ok), path in zip(cases, paths)
        if validator.is_valid(data) is not ok or javascript[path]["verdict"] != _verdict(ok)
    ]
    assert not wrong, "\n".join(wrong)
