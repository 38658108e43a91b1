"""The README's test command passes for anyone: a handful of representative tests run without the runner's rights.

Most people who clone a repository are not root.  An ordinary user (no CAP_SYS_NICE, RLIMIT_RTPRIO 0, RLIMIT_MEMLOCK
at the usual 8 MiB, and no PYTHONUNBUFFERED, which CI sets and a login shell does not) once had ten tests fail and one
hang the whole run.  Here one test of each kind that failed runs in a pytest of its own with those rights dropped the
way the kernel tests drop them (`kernelrun.unprivileged_prefix`): each passes, or skips with a reason that names the
right it needs.  A shipped scenario's `--list` and an rt-app import are among them: no user's rlimit makes a file
invalid.  And CI's rule holds for that user (conftest.py): missing rights fail the run unless RUNNER_TESTS_NO_RT=1.
"""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from conftest import REPO
from kernelrun import RT_REASON, TRACING_REASON, unprivileged_prefix

pytestmark = pytest.mark.kernel  # the tests it runs start runners and cyclictest; one pytest at a time on the machine

ORDINARY_MEMLOCK = 8 << 20  # RLIMIT_MEMLOCK of a login on Debian and Ubuntu (systemd's default)

# Each passes, or skips naming a right: the kinds of test that failed or hung for an ordinary user.
REPRESENTATIVE = {
    "tests/test_boundary.py::test_an_output_folder_that_cannot_be_made_is_invalid_input": "passes",  # run by anyone
    "tests/test_cell_processes.py::test_a_process_named_in_bytes_that_are_not_utf8_is_read_listed_and_shown": "passes",  # no -u
    "tests/test_scenarios.py::test_shipped_scenario_validates_and_lists": "passes",  # locked memory past 8 MiB is a warning
    "tests/test_rtapp.py::test_cli_writes_yaml_to_stdout_and_notes_to_stderr": "passes",  # so for an import
    "tests/test_percpu.py::test_the_shipped_cyclictest_scenario_is_one_pinned_thread_per_cpu": "passes",  # and for a load
    "tests/test_export.py::test_the_formats_match_a_real_cyclictests": "skips",  # cyclictest needs RT, whatever its policy
    "tests/test_labs.py::test_the_lava_script_runs_a_scenario_and_reports_each_cell": "skips",  # its scenario is fifo:50
    "tests/test_kernel.py::test_unprivileged_fifo_fails_before_starting_with_exit_3": "skips",  # the kernel tests
    "tests/test_kernel_trace.py::test_a_fifo_sleeper_beside_a_hog_is_woken_and_never_preempted": "skips",  # tracing and RT
}
REASONS = {RT_REASON, TRACING_REASON, "cyclictest (rt-tests) not installed"}


def _as_anyone(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """pytest ARGS as an ordinary user: RT rights dropped, RLIMIT_MEMLOCK 8 MiB, a login's environment (plus `env`)."""
    prefix, _ = unprivileged_prefix()
    os.chmod(tmp_path, 0o777)
    dropped = ("CI", "RUNNER_TESTS_NO_RT", "PYTHONUNBUFFERED", "PYTEST_ADDOPTS", "GITHUB_STEP_SUMMARY")
    clean = {k: v for k, v in os.environ.items() if k not in dropped}
    argv = [
        "prlimit",
        f"--memlock={ORDINARY_MEMLOCK}:{ORDINARY_MEMLOCK}",
        *prefix,
        sys.executable,
        "-m",
        "pytest",
        "-p",
        "no:cacheprovider",
        f"--basetemp={tmp_path / 'tmp'}",
        *args,
    ]
    return subprocess.run(argv, cwd=REPO, env={**clean, **env}, capture_output=True, text=True, timeout=300)


def test_the_representative_tests_pass_or_skip_naming_a_right_for_an_ordinary_user(tmp_path):
    report = tmp_path / "junit.xml"
    done = _as_anyone(tmp_path, "-q", f"--junitxml={report}", *REPRESENTATIVE)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr
    outcomes: dict[str, list[tuple[str, str]]] = {node: [] for node in REPRESENTATIVE}
    for case in ET.parse(report).getroot().iter("testcase"):
        node = f"{case.get('classname', '').replace('.', '/')}.py::{case.get('name', '').split('[')[0]}"  # one per parameter
        skipped = case.find("skipped")
        assert node in outcomes, node
        outcomes[node].append(("skips", skipped.get("message", "")) if skipped is not None else ("passes", ""))
    for node, expected in REPRESENTATIVE.items():
        assert outcomes[node], f"{node} did not run"
        for outcome, reason in outcomes[node]:
            if outcome == "skips":
                assert reason in REASONS, (node, reason)
            assert outcome == expected or reason == "cyclictest (rt-tests) not installed", (node, outcome, reason)


def test_ci_refuses_to_skip_the_kernel_tests_for_missing_rights_unless_told(tmp_path):
    one = "tests/test_kernel.py::test_unprivileged_fifo_fails_before_starting_with_exit_3"
    refused = _as_anyone(tmp_path, "-q", one, CI="true")
    assert refused.returncode == 4, refused.stdout + refused.stderr  # pytest's usage error: nothing ran
    assert "CI is set but this machine cannot use SCHED_FIFO" in refused.stderr and "RUNNER_TESTS_NO_RT=1" in refused.stderr
    told = _as_anyone(tmp_path, "-q", one, CI="true", RUNNER_TESTS_NO_RT="1")
    assert told.returncode == 0 and f"SKIPPED [1] {one.split('::')[0]}" in told.stdout and RT_REASON in told.stdout, told.stdout
