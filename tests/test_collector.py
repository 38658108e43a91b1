"""The cyclic collector is paused only while the runner builds or walks its records, and always on again after."""

from __future__ import annotations

import gc
import os
import shutil

from conftest import REPO, run_cli

from runner.collector import collector_paused

MATRIX = os.path.join(REPO, "tests", "data", "policy_matrix")


def test_the_pause_ends_with_its_block_and_keeps_a_pause_it_is_inside_of():
    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled()
        with collector_paused():
            assert not gc.isenabled()
        assert not gc.isenabled(), "an inner pause leaves the outer one paused"
    assert gc.isenabled()


def test_the_commands_that_read_documents_leave_the_collector_on_whatever_they_end_with(tmp_path):
    results = shutil.copytree(MATRIX, tmp_path / "m")
    for argv, code in (
        (("report", str(results), "-o", str(tmp_path / "r.md"), "--no-plots"), 0),
        (("compare", str(results), str(results)), 0),
        (("compare", str(results), str(tmp_path / "none")), 2),
        (("merge", str(results), "--out", str(tmp_path / "merged")), 0),
    ):
        outcome = run_cli(*argv)
        assert outcome.code == code, (argv, outcome.err)
        assert gc.isenabled(), argv
