"""results.json's JSON Schema (`runner schema --results`), generated from the typed document, holds in
Python's jsonschema and in ajv (JavaScript, strict mode) for what the runner writes: the recorded runs of
tests/data as this version saves them, and runs made now through the fake backend (a matrix, and
programs with events and a deadline thread)."""

from __future__ import annotations

import json
import os

import jsonschema
import pytest
from conftest import REPO, SCENARIOS, ajv_verdicts, run_cli
from fakebackend import Act, FakeBackend

from runner.cli import _run_parser
from runner.results.document import results_schema
from runner.results.read import load
from runner.scenario.loader import load_scenario
from runner.session import RunOptions, run_scenario

DATA = os.path.join(REPO, "tests", "data")


def fresh_run(scenario: str, out: str, acts: dict[str, Act]) -> str:
    ns = _run_parser().parse_args([scenario, "--out", out, "--quiet", "--settle", "0", "--no-plots", "--duration", "1s"])
    run_scenario(load_scenario(scenario), RunOptions.from_namespace(ns, env={}), FakeBackend(acts))
    return os.path.join(out, "results.json")


@pytest.fixture(scope="module")
def documents(tmp_path_factory) -> list[str]:
    """results.json files as this version writes them."""
    root = tmp_path_factory.mktemp("results")
    paths = []
    for name in sorted(os.listdir(DATA)):
        path = root / name / "results.json"
        path.parent.mkdir()
        load(os.path.join(DATA, name)).save(str(path))
        paths.append(str(path))
    paths.append(fresh_run(os.path.join(SCENARIOS, "policy_matrix.yaml"), str(root / "matrix"), {"policy=other,priority=0": Act(nivcsw=9)}))
    paths.append(fresh_run(os.path.join(SCENARIOS, "phases.yaml"), str(root / "phases"), {}))
    return paths


def test_what_the_runner_writes_satisfies_the_results_schema_in_jsonschema_and_ajv(documents, tmp_path):
    schema = results_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    for path in documents:
        with open(path, encoding="utf-8") as handle:
            jsonschema.Draft202012Validator(schema).validate(json.load(handle))
    verdicts = ajv_verdicts(schema, documents, tmp_path)
    assert {p: v["verdict"] for p, v in verdicts.items()} == dict.fromkeys(documents, "accept"), verdicts


def test_ajv_refuses_a_document_the_reader_refuses(documents, tmp_path):
    with open(documents[0], encoding="utf-8") as handle:
        data = json.load(handle)
    data["cells"][0]["threads"][0]["figures"]["latency_ns"]["p99"] = 58.366  # durations are integer ns
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data), encoding="utf-8")
    assert ajv_verdicts(results_schema(), [str(bad)], tmp_path)[str(bad)]["verdict"] == "reject"


def test_the_results_schema_command_prints_it():
    outcome = run_cli("schema", "--results")
    assert outcome.code == 0 and json.loads(outcome.out) == results_schema()
