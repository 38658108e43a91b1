"""A run (or a comparison) as JUnit XML, the file colcon/ament, GitLab, Jenkins and GitHub's test reporters read.  Pure.

The shape is the one Ant's JUnit task wrote and Jenkins' junit.xsd describes, kept to
what every reader takes (tests/junit.xsd checks it):

    <testsuites name="runner: SCENARIO" tests= failures= errors= time=>
      <testsuite name="SCENARIO: CELL" tests= failures= errors= skipped= time= timestamp= hostname= file=>
        <properties>   matrix.KEY = value for each matrix value, and the cell's status
        <testcase classname="SCENARIO.CELL" name="run" file= line= time=>   the cell's run: <error> if it could not run
        <testcase ... name="THREAD: FIGURE LIMIT">                          each expectation: <failure> if not met
        <testcase ... name="THREAD: FIGURE against the baseline">           each compared figure: <failure> on a regression
        <system-out>   the cell's warnings and degradations, in words

Each test case names the scenario file as the run was given it (`file`, relative to where it ran)
and a line of it (`line`): an expectation's own line, and the file's first line for what no line of
it declares (the run, an implicit verdict such as a thread that could not keep up, a figure against
the baseline or the history).  GitLab shows `file`; the JUnit-report actions (mikepenz's, EnricoMi's,
dorny's phpunit-junit reader) put a failure's annotation at `file`:`line`.

One test suite per cell run, so a reader groups by cell and shows the matrix values.
Test case names stay the same from run to run (they name the check, not its result), so
Jenkins and GitLab can follow a check across nights.  Times are seconds.  Messages are the
report's words (`outcomes.py`).  Names come from the scenario, the kernel and results files:
every name, attribute and message is shown as a terminal may get it (`printable.for_terminal`:
an escape sequence or a newline in a thread's name is `?`, as ps shows it), since readers print
them on terminals and list them one per line; what XML 1.0 cannot hold at all never reaches it.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING, Optional

from runner.printable import for_terminal
from runner.report.compare import Comparison
from runner.report.outcomes import CellChecks, Check, Kind, Outcome, cell_checks
from runner.results.document import RunDocument

if TYPE_CHECKING:
    from runner.history.judge import NightVerdict

# characters XML 1.0 cannot carry at all, even escaped
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def xml_text(text: str) -> str:
    """One line of text as a terminal may show it, with nothing XML 1.0 cannot carry (`for_terminal` leaves none)."""
    return _NOT_XML.sub("?", for_terminal(text))


def seconds(ns: int) -> str:
    """A duration in ns as JUnit's `time`: seconds with three decimals, `2.413`."""
    return f"{max(ns, 0) / 1e9:.3f}"


def junit_xml(doc: RunDocument, comparison: Optional[Comparison] = None, run: bool = True, history: Optional[NightVerdict] = None) -> bytes:
    """The JUnit XML of `doc`'s cells, with `comparison`'s and `history`'s checks when given (`run` False: the comparison alone)."""
    suites = cell_checks(doc, comparison, run, history)
    name = doc.scenario.name
    root = ET.Element("testsuites", {"name": xml_text(f"runner: {name}")})
    for suite in suites:
        root.append(_suite(name, doc.scenario.path, suite))
    root.set("tests", str(sum(len(s.checks) for s in suites)))
    root.set("failures", str(sum(s.count(Outcome.FAILED) for s in suites)))
    root.set("errors", str(sum(s.count(Outcome.ERROR) for s in suites)))
    root.set("time", seconds(sum(s.duration_ns for s in suites)))
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def _suite(scenario: str, path: Optional[str], suite: CellChecks) -> ET.Element:
    attrs = {
        "name": f"{scenario}: {suite.title}",
        "tests": str(len(suite.checks)),
        "failures": str(suite.count(Outcome.FAILED)),
        "errors": str(suite.count(Outcome.ERROR)),
        "skipped": str(suite.count(Outcome.SKIPPED)),
        "time": seconds(suite.duration_ns),
    }
    if suite.started_at:
        attrs["timestamp"] = suite.started_at
    if suite.hostname:
        attrs["hostname"] = suite.hostname
    if path:
        attrs["file"] = path
    element = ET.Element("testsuite", {k: xml_text(v) for k, v in attrs.items()})
    properties = ET.SubElement(element, "properties")
    for key, value in suite.matrix.items():
        ET.SubElement(properties, "property", {"name": xml_text(f"matrix.{key}"), "value": xml_text(value)})
    ET.SubElement(properties, "property", {"name": "status", "value": suite.status.value if suite.status else "not run"})
    for check in suite.checks:
        element.append(_case(f"{scenario}.{suite.title}", path, check))
    if suite.notes:
        ET.SubElement(element, "system-out").text = "\n".join(xml_text(note) for note in suite.notes)  # a line each
    return element


_TAG = {Outcome.FAILED: "failure", Outcome.ERROR: "error", Outcome.SKIPPED: "skipped"}
_TYPE = {
    Kind.RUN: "run error",
    Kind.EXPECTATION: "expectation",
    Kind.BASELINE: "regression",
    Kind.HISTORY: "regression against the history",
}


def _case(classname: str, path: Optional[str], check: Check) -> ET.Element:
    attrs = {"classname": xml_text(classname), "name": xml_text(check.name)}
    if path:
        attrs.update(file=xml_text(path), line=str(check.line or 1))  # no line of its own: the scenario's first
    case = ET.Element("testcase", {**attrs, "time": seconds(check.time_ns)})
    tag = _TAG.get(check.outcome)
    if tag is None:
        return case
    detail = ET.SubElement(case, tag, {"message": xml_text(check.message)})
    if check.outcome is not Outcome.SKIPPED:
        detail.set("type", _TYPE[check.kind])
        where = f"{path}:{check.line}:{check.col}: " if path and check.line and check.col else ""
        detail.text = xml_text(where + check.message)
    return case
