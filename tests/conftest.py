"""Shared helpers: the repository layout and an in-process CLI call; CI's rule for the kernel tests."""

from __future__ import annotations

import contextlib
import io
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from typing import Any

import pytest
from hypothesis import settings

# No property test is timed: hypothesis's default deadline (200 ms an example) failed one on a
# machine busy with real-time load.  Speed targets live in bench/.
settings.register_profile("runner", deadline=None)
settings.load_profile("runner")

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The tests import the installed package, never the source tree: `python -m pytest` puts the working
# directory first on sys.path, and a source tree lacks the native core a non-editable install built.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != REPO]
# The same for every Python child a test starts (`python -c` and `-m` put the working directory first
# as well; Python 3.11 and later leave it out under PYTHONSAFEPATH): a test that forgets `cwd=` must
# not run the source tree's runner, which CI's hermetic install leaves without its native core.
os.environ["PYTHONSAFEPATH"] = "1"
# A shell starts a background job with SIGINT ignored, and the runner rightly keeps a signal its caller
# ignores ignored: the tests that stop a run with SIGINT start from Python's own handler, wherever pytest runs.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
SCENARIOS = os.path.join(REPO, "scenarios")


def pyproject() -> dict[str, Any]:
    """The repository's pyproject.toml (tomllib; on Python 3.10 tomli, which pytest itself requires there)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    with open(os.path.join(REPO, "pyproject.toml"), "rb") as handle:
        return tomllib.load(handle)


def _in_ci() -> bool:
    return os.environ.get("CI", "") not in ("", "0", "false")


def pytest_sessionstart(session: pytest.Session) -> None:
    """In CI the kernel tests must run: a machine without RT rights fails the run instead of skipping 50 tests.

    A CI machine that really has no RT rights says so with RUNNER_TESTS_NO_RT=1; the kernel tests
    are then skipped, and the summary says why.
    """
    from kernelrun import can_use_rt

    if _in_ci() and not can_use_rt() and os.environ.get("RUNNER_TESTS_NO_RT", "") in ("", "0"):
        raise pytest.UsageError(
            "CI is set but this machine cannot use SCHED_FIFO (no CAP_SYS_NICE, RLIMIT_RTPRIO 0), so the "
            "kernel tests would be skipped; run CI as root or with CAP_SYS_NICE, or set "
            "RUNNER_TESTS_NO_RT=1 to run without them on purpose"
        )


@dataclass
class Outcome:
    code: int
    out: str
    err: str


def run_cli(*argv: str) -> Outcome:
    """Call runner's main() in-process and capture what it prints."""
    from runner.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return Outcome(int(code), out.getvalue(), err.getvalue())


@pytest.fixture
def write_scenario(tmp_path):
    """Write YAML text to a file and return its path."""

    def write(text: str, name: str = "s.yaml") -> str:
        path = tmp_path / name
        path.write_text(text)
        return str(path)

    return write


def _ajv_or_skip() -> None:
    modules = os.path.join(REPO, ".ci", "node_modules")
    if shutil.which("node") is None or not all(os.path.isdir(os.path.join(modules, m)) for m in ("ajv", "yaml")):
        if _in_ci():
            pytest.fail("node, ajv or yaml is not installed; .ci/run installs them with npm")
        pytest.skip("ajv not installed (npm install --prefix .ci ajv yaml, as .ci/run does)")


def ajv_verdicts(schema: dict[str, object], paths: list[str], tmp_path: pathlib.Path) -> dict[str, dict[str, object]]:
    """ajv's verdict per file ({"verdict": accept|reject|unparsed, "errors": [...]}), as .ci/schema.cjs prints
    them: strict mode, the schema's draft, YAML read as yaml-language-server reads it.  A schema ajv cannot
    compile fails the test."""
    _ajv_or_skip()
    schema_file = tmp_path / "schema.json"
    schema_file.write_text(json.dumps(schema), encoding="utf-8")
    done = subprocess.run(
        ["node", os.path.join(REPO, ".ci", "schema.cjs"), str(schema_file), *paths], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    verdicts: dict[str, dict[str, object]] = json.loads(done.stdout)
    return verdicts


def editor_answers(requests: list[dict[str, object]], tmp_path: pathlib.Path) -> list[dict[str, Any]]:
    """What an editor shows, as yaml-language-server's language service answers (.ci/yamlls.cjs): per request
    ({"file": PATH, "text": TEXT, "complete": [[LINE, CHARACTER], ...]}) its diagnostics and, per position, the
    completions.  A buffer is known by its file's path, so its modeline's schema is read from disk."""
    modules = os.path.join(REPO, ".ci", "node_modules")
    if shutil.which("node") is None or not os.path.isdir(os.path.join(modules, "yaml-language-server")):
        if _in_ci():
            pytest.fail("node or yaml-language-server is not installed; .ci/run installs it with npm")
        pytest.skip("yaml-language-server not installed (.ci/run's npm install line puts it in .ci/node_modules)")
    request_file = tmp_path / "requests.json"
    request_file.write_text(json.dumps(requests), encoding="utf-8")
    done = subprocess.run(["node", os.path.join(REPO, ".ci", "yamlls.cjs"), str(request_file)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    answers: list[dict[str, Any]] = json.loads(done.stdout)
    return answers
