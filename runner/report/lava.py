"""A run as LAVA test results: `lava-test-set` and `lava-test-case` calls, made when LAVA's helpers are there, printed otherwise.

LAVA (Linaro's lab software, which KernelCI's real-time labs run) records results through
two helper scripts it puts on a test shell's PATH, whose grammar is LAVA's
(Linaro/lava: doc/v2/writing-tests.rst, lava_dispatcher/lava_test_shell/lava-test-case):

    lava-test-set start NAME
    lava-test-case NAME --result pass|fail|skip|unknown [--measurement NUMBER --units UNITS]
    lava-test-set stop

Each cell run is a test set named after the cell (`policy=fifo,priority=80`; `-repeat-N`
added when cells ran several times).  In it, the case `outcome` says how the cell went
(pass when it passed or ran degraded, as its exit code says; fail when an expectation
failed, it could not run or was cut short; skip when it was not run), then each subject's
measures (runner/report/labs.py) follow as `process.thread.FIGURE` (`minimal_schedul.minimal_schedul.latency.p99`)
with the figure's value: durations in microseconds (`--units us`, to the nanosecond),
counts as counts.  A measure's result is its expectations' (fail if one failed); one no
expectation judges carries its thread's outcome (fail when any expectation on the thread
failed, and so on every figure of a thread that could not keep up; pass otherwise), as
Linaro's rt-tests parser passes its `t0-max-latency`; in a cell cut short it is `unknown`.

Names obey LAVA's rules: no spaces (its signal lines are split on them), none of
``$& "'`()<>/\\|;``, at most 100 characters (its database's limit): characters other
than `A-Za-z0-9_.=,+-` are written `_`, and a name that had to be cut ends its cut part
in `~` and a hash of the whole (a case keeps its figure's name at its end).  Measurements are
decimal numbers LAVA keeps exactly (10 decimals).

As LAVA asks of test scripts, `send` calls `lava-test-case` and `lava-test-set` when they
are on PATH and prints the same lines otherwise, so the same command runs inside and
outside a lab (Linaro's send-to-lava.sh does the same).  The lines are built here, pure;
`send` is the only part that runs anything.
"""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Optional

from runner.errors import RunnerError
from runner.figures import Number
from runner.report.labs import LAB_UNITS, LabCell, LabStatus, Measure, Subject, lab_cells, short_hash
from runner.results.document import RunDocument
from runner.terminal import say

NAME_LIMIT = 100  # characters LAVA's results database shows of a name (lava_results_app: TestCase.name)
_NOT_IN_LAVA_NAMES = re.compile(r"[^A-Za-z0-9_.=,+-]")

_RESULT = {
    LabStatus.PASS: "pass",
    LabStatus.FAIL: "fail",
    LabStatus.ERROR: "unknown",
    LabStatus.MISS: "unknown",
    LabStatus.SKIP: "skip",
}
_OUTCOME = {LabStatus.PASS: "pass", LabStatus.FAIL: "fail", LabStatus.ERROR: "fail", LabStatus.MISS: "fail", LabStatus.SKIP: "skip"}


@dataclass(frozen=True)
class LavaCall:
    """One call of a LAVA helper: its arguments, and the line that says it when the helper is not there."""

    argv: tuple[str, ...]

    @property
    def line(self) -> str:
        return " ".join(self.argv)  # every word is a LAVA name, a result, a number or a unit: no quoting needed


def lava_name(text: str) -> str:
    """`text` as LAVA takes a test case or test set name: `A-Za-z0-9_.=,+-` only, at most 100 characters."""
    name = _NOT_IN_LAVA_NAMES.sub("_", text) or "_"
    if len(name) <= NAME_LIMIT:
        return name
    return f"{name[: NAME_LIMIT - 9]}~{short_hash(text)}"


def case_name(subject: str, figure: str) -> str:
    """A measure's case name, `SUBJECT.FIGURE`: a subject too long for LAVA is cut (and hashed), never the figure's name."""
    whole = lava_name(f"{subject}.{figure}")
    if whole.endswith(f".{figure}"):
        return whole
    return f"{lava_name(subject)[: NAME_LIMIT - len(figure) - 10]}~{short_hash(subject)}.{figure}"


def measurement(value: Number, per: int) -> str:
    """`value` divided by `per` as a plain decimal number LAVA records exactly: `58.366`, `-1.2`, `0`, `9.8889`."""
    if isinstance(value, int):
        whole, part = divmod(abs(value), per)
        digits = f"{part:0{len(str(per)) - 1}d}".rstrip("0") if per > 1 else ""
        return ("-" if value < 0 else "") + str(whole) + (f".{digits}" if digits else "")
    return f"{value / per:.10f}".rstrip("0").rstrip(".") or "0"


def _case(name: str, result: str, measure: Optional[Measure] = None) -> LavaCall:
    argv = ["lava-test-case", name, "--result", result]
    if measure is not None and measure.value is not None and math.isfinite(measure.value):
        unit = LAB_UNITS[measure.figure.unit]
        argv += ["--measurement", measurement(measure.value, unit.lava_per), "--units", unit.lava]
    return LavaCall(tuple(argv))


def _result(measure: Measure, subject: Subject) -> str:
    """A measure's result: its expectations' when any judged it, else its thread's outcome (never pass on a failed thread)."""
    if measure.status is LabStatus.DONE:
        return "fail" if subject.status is LabStatus.FAIL else "pass"
    return _RESULT[measure.status]


def _set_names(cells: Sequence[LabCell]) -> list[str]:
    repeated = any(c.repeat for c in cells)
    names = [c.cell_id + (f"-repeat-{c.repeat + 1}" if repeated and c.result is not None else "") for c in cells]
    shown = [lava_name(n) for n in names]
    return [f"{lava_name(n)[: NAME_LIMIT - 9]}~{short_hash(n)}" if shown.count(s) > 1 else s for n, s in zip(names, shown)]


def lava_calls(doc: RunDocument) -> list[LavaCall]:
    """Every call the run comes to: a test set per cell run, with its `outcome` and each subject's measures."""
    cells = lab_cells(doc)
    out: list[LavaCall] = []
    for cell, name in zip(cells, _set_names(cells)):
        out.append(LavaCall(("lava-test-set", "start", name)))
        out.append(_case("outcome", _OUTCOME[cell.status]))
        for subject in cell.subjects:
            for measure in subject.measures:
                out.append(_case(case_name(subject.token, measure.figure.name), _result(measure, subject), measure))
        out.append(LavaCall(("lava-test-set", "stop")))
    return out


def send(
    calls: Sequence[LavaCall],
    which: Callable[[str], Optional[str]] = shutil.which,
    run: Callable[..., Any] = subprocess.run,
) -> None:
    """Make each call with LAVA's helper when it is on PATH, or print its line when it is not.

    A helper that cannot be run or exits non-zero stops the rest, as a RunnerError (exit 4):
    results that did not reach LAVA are never reported as sent.
    """
    found: dict[str, Optional[str]] = {}
    for call in calls:
        if call.argv[0] not in found:
            found[call.argv[0]] = which(call.argv[0])
        tool = found[call.argv[0]]
        if tool is None:
            say(call.line)
            continue
        sys.stdout.flush()  # what was printed before comes before what the helper prints
        try:
            done = run([tool, *call.argv[1:]], stdin=subprocess.DEVNULL, check=False)
        except OSError as exc:
            raise RunnerError(
                f"runner: cannot run {tool}: {exc.strerror or exc}; the results from `{call.line}` on did not reach LAVA"
            ) from None
        if done.returncode:
            raise RunnerError(f"runner: `{call.line}` exited {done.returncode}; the results from it on did not reach LAVA")
