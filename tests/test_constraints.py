"""The nightly workflow installs pinned versions only: .github/nightly-constraints.txt, every package it pulls, in pyproject's ranges.

A night must not change because a dependency released: each `pip install` of the workflow takes
`-c "$CONSTRAINTS"`, and builds runner with the setuptools and wheel it pinned
(`--no-build-isolation`, after installing them).  The file is uv's universal resolution
(`bash .ci/nightly-constraints`): lines with markers hold for some Pythons only.  Here each
Python's slice of it is checked against pyproject.toml (every requirement pinned once, within its
range), and pip resolves each install of the workflow on this interpreter (`--dry-run --report`):
everything it would install is pinned, at the pinned version, and nothing pinned is left unused.
"""

from __future__ import annotations

import concurrent.futures
import json
import os
import re
import subprocess
import sys

import pytest
import yaml
from conftest import REPO, _in_ci, pyproject
from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

WORKFLOW = os.path.join(REPO, ".github", "workflows", "nightly-matrix.yml")
CONSTRAINTS = os.path.join(REPO, ".github", "nightly-constraints.txt")
# the Pythons a night may run on: the hosts' own python3 (Debian 12: 3.11, Ubuntu 22.04: 3.10, 24.04: 3.12) and the merge job's
PYTHONS = ("3.10", "3.11", "3.12", "3.13")


def pins() -> list[Requirement]:
    """The file's lines as requirements, each `name==version` with its marker (comments and `# via` lines dropped)."""
    out = []
    with open(CONSTRAINTS, encoding="utf-8") as handle:
        for line in handle:
            text = line.split("#", 1)[0].strip()
            if text:
                req = Requirement(text)
                assert len(req.specifier) == 1 and next(iter(req.specifier)).operator == "==", f"not pinned: {text}"
                out.append(req)
    return out


def environment(python: str) -> dict[str, str]:
    """This machine's marker environment, on another Python."""
    return {**default_environment(), "python_version": python, "python_full_version": f"{python}.0"}


def pinned(python: str) -> dict[str, str]:
    """Name -> version of the pins that hold on `python`: one per name, or the file is ambiguous."""
    out: dict[str, str] = {}
    for req in pins():
        if req.marker is None or req.marker.evaluate(environment(python)):
            name = canonicalize_name(req.name)
            assert name not in out, f"{name} is pinned twice for Python {python}"
            out[name] = next(iter(req.specifier)).version
    return out


def _steps(job: str) -> list[dict]:
    return yaml.safe_load(open(WORKFLOW))["jobs"][job]["steps"]


def installs() -> dict[str, list[str]]:
    """Per job of the workflow, the requirements its `pip install` lines name (`.[plots,history]` as written)."""
    out: dict[str, list[str]] = {}
    for job in ("shard", "merge"):
        for step in _steps(job):
            for line in step.get("run", "").splitlines():
                if "pip install" in line:
                    words = line.split("#", 1)[0].split("pip install", 1)[1].split()
                    out.setdefault(job, []).extend(w.strip("'\"") for w in words if not w.startswith("-") and w != '"$CONSTRAINTS"')
    return out


def requirements(named: list[str]) -> list[Requirement]:
    """What installing `named` asks for: runner (`.` or `.[EXTRA,...]`) is its dependencies and those of its extras."""
    project = pyproject()["project"]
    out = []
    for item in named:
        if item == "." or item.startswith(".["):
            extras = re.findall(r"[\w-]+", item[1:])
            out += [Requirement(r) for r in project["dependencies"]]
            out += [Requirement(r) for extra in extras for r in project["optional-dependencies"][extra]]
        else:
            out.append(Requirement(item))
    return out


def test_every_install_of_the_workflow_takes_the_constraints_and_builds_with_the_pinned_setuptools():
    flow = yaml.safe_load(open(WORKFLOW))
    assert flow["env"]["CONSTRAINTS"] == ".github/nightly-constraints.txt"
    for job in ("shard", "merge"):
        lines = [line.strip() for step in _steps(job) for line in step.get("run", "").splitlines() if "pip install" in line]
        assert lines and all('-c "$CONSTRAINTS"' in line for line in lines), (job, lines)
        build, runner = lines  # the build's tools first, then runner built with them
        assert build.split("#")[0].split()[-2:] == ["setuptools", "wheel"], build
        assert "--no-build-isolation" in runner and re.search(r" '?\.(\[[\w,-]+\])?'?( |$)", runner), runner
    assert installs()["merge"][-1] == ".[plots,history]"  # the report's plots, the history's change points and PostgreSQL


@pytest.mark.parametrize("python", PYTHONS)
def test_every_requirement_of_pyproject_is_pinned_within_its_range(python):
    """A range raised in pyproject without a refresh (or a new dependency, a new extra the workflow installs) fails here."""
    env = environment(python)
    versions = pinned(python)
    build = [Requirement(r) for r in pyproject()["build-system"]["requires"]]
    named = sorted({item for items in installs().values() for item in items})
    for req in build + requirements(named):
        if req.marker is not None and not req.marker.evaluate(env):
            continue
        name = canonicalize_name(req.name)
        assert name in versions, f"{req} (pyproject.toml) has no pin for Python {python}: bash .ci/nightly-constraints"
        assert req.specifier.contains(versions[name], prereleases=True), f"{name}=={versions[name]} is outside {req}: refresh the file"


def _dry_run(named: list[str]) -> dict[str, str]:
    """Name -> version of what pip would install for `named` with the constraints, on this interpreter, from scratch."""
    args = [str(r) for r in requirements(named)]
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--dry-run", "--quiet", "--ignore-installed", "--report", "-", "-c", CONSTRAINTS, *args],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"},
    )
    if (
        done.returncode != 0
        and not _in_ci()
        and re.search(r"NewConnectionError|Temporary failure in name resolution|Network is unreachable", done.stderr)
    ):
        pytest.skip("the package index is out of reach: " + done.stderr.strip().splitlines()[-1])
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    return {canonicalize_name(item["metadata"]["name"]): item["metadata"]["version"] for item in report["install"]}


def test_pip_installs_exactly_the_pinned_versions_and_every_pin_is_used():
    python = f"{sys.version_info.major}.{sys.version_info.minor}"
    versions = pinned(python)
    jobs = installs()
    with concurrent.futures.ThreadPoolExecutor() as pool:  # each waits on the index; together they take half as long
        resolved = dict(zip(jobs, pool.map(_dry_run, jobs.values())))
    for job, got in resolved.items():
        unpinned = sorted(name for name in got if name not in versions)
        assert not unpinned, f"the {job} job would install {unpinned}, which the constraints do not pin: bash .ci/nightly-constraints"
        assert {n: v for n, v in got.items() if versions[n] != v} == {}, job
    used = set().union(*resolved.values())
    assert sorted(set(versions) - used) == [], "pins no install of the workflow uses: bash .ci/nightly-constraints"


def test_ci_runs_the_short_nightly_installed_as_the_merge_job_installs():
    """.ci/run's own environment takes today's releases (what users get); its short nightly runs on the pins, installed by
    the merge job's own commands (the shard job's install is the same, without the extras)."""
    with open(os.path.join(REPO, ".ci", "run"), encoding="utf-8") as handle:
        ci = handle.read()
    lines = [line.split("#")[0].strip() for step in _steps("merge") for line in step.get("run", "").splitlines() if "pip install" in line]
    for line in lines:
        assert (
            line.replace(".venv/bin/pip", '"$work/nightly/bin/pip"').replace('"$CONSTRAINTS"', ".github/nightly-constraints.txt") in ci
        ), line
    assert 'PATH="$work/nightly/bin:$PATH" bash .ci/nightly' in ci
    assert "-c .github/nightly-constraints.txt" not in ci.split('step "short nightly matrix', 1)[0]  # not for the tests' environment
