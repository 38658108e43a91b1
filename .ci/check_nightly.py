"""Check the short nightly run made by .ci/nightly: exit codes agree with the results, reports say what they should.

usage: check_nightly.py OUT FULL_EXIT SHARD1_EXIT SHARD2_EXIT MERGE_EXIT
"""

from __future__ import annotations

import json
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

# README's exit-code table, written out so the check holds the tool to its documentation, not to its own code
README_EXIT = {"interrupted": 130, "error": 4, "failed": 1, "degraded": 0, "passed": 0}
SEVERITY = ["error", "interrupted", "failed", "degraded", "passed"]


def documented_exit(statuses: list[str]) -> int:
    return README_EXIT[min(statuses or ["passed"], key=SEVERITY.index)]


def cells(folder: str) -> list[dict]:
    with open(os.path.join(folder, "results.json")) as handle:
        return json.load(handle)["cells"]


def main(out: str, full: str, s1: str, s2: str, merged: str) -> int:
    failures = []

    def check(ok: bool, what: str) -> None:
        print(("ok   " if ok else "FAIL ") + what)
        if not ok:
            failures.append(what)

    for name, code in (("full", full), ("s1", s1), ("s2", s2)):
        statuses = [c["status"] for c in cells(os.path.join(out, name))]
        check(int(code) == documented_exit(statuses), f"{name}: exit {code} is the one README gives for its cells ({statuses})")
        check(int(code) in (0, 1), f"{name}: no run error, permission or input problem (exit {code})")
    full_cells = cells(os.path.join(out, "full"))
    merged_cells = cells(os.path.join(out, "merged"))
    check([c["id"] for c in merged_cells] == [c["id"] for c in full_cells], "shards 1/2 + 2/2 merged give the full run's cells, in order")
    check(int(merged) in (0, 1), f"merge with the full run as baseline: exit {merged} (0 or 1, never a refusal)")
    invol = {c["id"]: c["threads"][0]["figures"]["involuntary"]["per_callback_mean"] for c in full_cells}
    check(invol["policy=other,priority=0"] > 1.0, f"OTHER is preempted under contention ({invol['policy=other,priority=0']} per callback)")
    for cell_id in ("policy=fifo,priority=80", "policy=rr,priority=80", "policy=fifo,priority=10", "policy=rr,priority=10"):
        check(invol[cell_id] < 0.5, f"{cell_id} is not preempted ({invol[cell_id]} per callback)")
    report = Path(out, "full", "report.md").read_text(encoding="utf-8")
    for needle in (
        "## Matrix summary",
        "## minimal_schedul/minimal_schedul (main) across cells",
        "```text\n  TID COMMAND",
        "plots/minimal_schedul-minimal_schedul-main.latency.svg",
    ):
        check(needle in report, f"full report has {needle.splitlines()[0]!r}")
    check(
        "## Comparison with the baseline" in Path(out, "merged", "report.md").read_text(encoding="utf-8"),
        "merged report carries the comparison with the baseline",
    )
    junit = ET.parse(os.path.join(out, "merged", "junit.xml")).getroot()
    suites = junit.findall("testsuite")
    failed = sum(not v["passed"] for c in merged_cells for v in c["expectations"])
    junit_failures, junit_errors = int(junit.get("failures", "-1")), int(junit.get("errors", "-1"))
    check(len(suites) == len(merged_cells), f"junit.xml has a test suite per merged cell ({len(suites)})")
    check(
        junit_failures >= failed and (junit_failures > 0) == (int(merged) == 1),
        f"junit.xml's {junit_failures} failure(s) agree with exit {merged} and {failed} failed expectation(s)",
    )
    unrun = sum(c["status"] in ("error", "interrupted") for c in merged_cells)
    check(junit_errors == unrun, f"junit.xml's {junit_errors} error(s) are the {unrun} cell(s) that could not run")
    print(f"nightly check: {len(failures)} failure(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main(*sys.argv[1:6]))
