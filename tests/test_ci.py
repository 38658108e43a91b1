"""What CI systems read: `--junit FILE` on run, merge and compare, and GitHub workflow annotations.

The JUnit files are validated against tests/junit.xsd (the Ant / Jenkins junit.xsd shape, see
its header) with xmlschema, and read back to check that a failed expectation, a cell that could not
run, a cell never run and a regression each come out as the test reporters expect.  Runs use the fake
backend (tests/fakebackend.py); merge and compare run on the recorded matrix in tests/data.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import xml.etree.ElementTree as ET

import pytest
import xmlschema
from conftest import REPO, SCENARIOS, _in_ci, run_cli
from fakebackend import Act, FakeBackend
from reportdata import MATRIX, heavy_tail, latencies, main_thread, matrix, with_latencies
from test_merge import split

from runner.cli import _run_parser
from runner.errors import Problem
from runner.report import compare as cmp
from runner.report import github
from runner.report.junit import junit_xml, xml_text
from runner.report.outcomes import Kind, cell_checks
from runner.results.document import RunDocument, Status, Verdict
from runner.results.read import load
from runner.scenario.loader import load_scenario
from runner.session import RunOptions, run_scenario

SCHEMA = xmlschema.XMLSchema(os.path.join(os.path.dirname(os.path.abspath(__file__)), "junit.xsd"))
POLICY_MATRIX = os.path.join(SCENARIOS, "policy_matrix.yaml")
OTHER, FIFO10 = "policy=other,priority=0", "policy=fifo,priority=10"
ERROR_ACT = Act(failures=("process minimal_schedul[0] (pid 4242) was killed by SIGKILL",))


def run(tmp_path, acts: dict[str, Act], *args: str, env: dict[str, str] | None = None) -> tuple[int, RunDocument]:
    ns = _run_parser().parse_args([POLICY_MATRIX, "--out", str(tmp_path / "r"), "--quiet", "--settle", "0", "--no-plots", *args])
    code = run_scenario(load_scenario(POLICY_MATRIX), RunOptions.from_namespace(ns, env=env or {}), FakeBackend(acts))
    return code, load(str(tmp_path / "r"))


def parsed(data: bytes | str) -> ET.Element:
    """The JUnit document, after checking it against the schema and that its counts add up."""
    text = data.decode() if isinstance(data, bytes) else data
    SCHEMA.validate(text)
    root = ET.fromstring(text)
    cases = root.findall("testsuite/testcase")
    assert int(root.get("tests")) == len(cases)
    assert int(root.get("failures")) == len(root.findall("testsuite/testcase/failure"))
    assert int(root.get("errors")) == len(root.findall("testsuite/testcase/error"))
    for suite in root.findall("testsuite"):
        assert int(suite.get("tests")) == len(suite.findall("testcase"))
        for tag, count in (("failure", "failures"), ("error", "errors"), ("skipped", "skipped")):
            assert int(suite.get(count)) == len(suite.findall(f"testcase/{tag}")), (suite.get("name"), tag)
    return root


def suite(root: ET.Element, cell: str) -> ET.Element:
    return next(s for s in root.findall("testsuite") if s.get("name", "").endswith(f": {cell}"))


def line_of(text: str, path: str = POLICY_MATRIX) -> int:
    with open(path, encoding="utf-8") as handle:
        return next(n for n, line in enumerate(handle, 1) if text in line)


# ---------------------------------------------------------------- the schema is a real check


def test_the_schema_refuses_what_readers_would_misread():
    good = (
        '<testsuites><testsuite name="s" tests="1" failures="0" errors="0">'
        '<testcase classname="c" name="n" time="0.5"/></testsuite></testsuites>'
    )
    SCHEMA.validate(good)
    SCHEMA.validate(good.replace('name="n" ', 'name="n" file="s.yaml" line="12" '))  # where a reader annotates it
    for bad in (
        good.replace('name="n" ', 'name="n" line="0" '),  # lines count from 1
        good.replace('name="n" ', 'name="n" line="12:5" '),  # a line is a number, as readers parseInt it
        good.replace('tests="1"', 'tests="one"'),  # a count that is not a number
        good.replace('time="0.5"', 'time="1,5"'),  # a time that is not decimal seconds
        good.replace('name="n" ', ""),  # a test case without a name
        good.replace("/></testsuite>", "><failure/><error/></testcase></testsuite>"),  # two outcomes
        good.replace("<testcase", '<properties/><testcase classname="c" name="m" time="0"/><properties/><testcase'),  # properties last
    ):
        assert not SCHEMA.is_valid(bad), bad


# ---------------------------------------------------------------- runner run --junit


def test_run_junit_has_a_suite_per_cell_with_matrix_properties_failures_and_errors(tmp_path):
    junit = tmp_path / "junit.xml"
    code, doc = run(tmp_path, {OTHER: Act(nivcsw=0), FIFO10: ERROR_ACT}, "--junit", str(junit))
    assert code == 4
    root = parsed(junit.read_bytes())
    assert len(root.findall("testsuite")) == 5 and root.get("failures") == "1" and root.get("errors") == "1"

    other = suite(root, OTHER)
    props = {p.get("name"): p.get("value") for p in other.findall("properties/property")}
    assert props == {"matrix.policy": "other", "matrix.priority": "0", "status": "failed"}
    assert other.get("file") == POLICY_MATRIX and other.get("hostname") == "fake"
    assert float(other.get("time")) == pytest.approx(doc.cells[-1].duration_ns / 1e9, abs=1e-3)
    (failure,) = other.findall("testcase/failure")
    case = other.find("testcase[failure]")
    assert case.get("name") == "minimal_schedul/minimal_schedul (main): involuntary.per_callback_mean >= 1"
    assert failure.get("type") == "expectation"
    # the report's words: the figure as the report names it, the limit, what was measured
    assert failure.get("message") == "minimal_schedul/minimal_schedul (main): involuntary switches per callback >= 1, measured 0.00"
    assert failure.text.startswith(f"{POLICY_MATRIX}:{line_of('min: 1')}:5: ")
    assert (case.get("file"), case.get("line")) == (POLICY_MATRIX, str(line_of("min: 1")))  # where readers annotate it

    fifo = suite(root, FIFO10)
    (error,) = fifo.findall("testcase/error")
    assert fifo.find("testcase[error]").get("name") == "run" and "killed by SIGKILL" in error.get("message")
    assert [c.get("name") for c in suite(root, "policy=rr,priority=80").findall("testcase")] == [
        "run",
        "minimal_schedul/minimal_schedul (main): involuntary.per_callback_mean <= 0.5",
        "minimal_schedul/minimal_schedul (main): latency.p99 <= 2ms",
    ]


def _readers(junit: str) -> dict[str, list[dict[str, object]]]:
    """Each test case as three report actions' own XML parsers read it: junitparser as EnricoMi's reads `file` and `line`
    (publish/junit.py), xml-js as mikepenz's reads `_attributes`, xml2js as dorny's phpunit-junit reader reads `$`."""
    import junitparser

    enrico = [
        {"name": c.name, "classname": c.classname, "file": c._elem.get("file"), "line": c._elem.get("line"), "failed": False}
        for s in junitparser.JUnitXml.fromfile(junit)
        for c in s
    ]
    for got, case in zip(enrico, ET.parse(junit).getroot().iter("testcase")):
        got["failed"] = case.find("failure") is not None
    modules = os.path.join(REPO, ".ci", "node_modules")
    if shutil.which("node") is None or not all(os.path.isdir(os.path.join(modules, m)) for m in ("xml-js", "xml2js")):
        if _in_ci():
            pytest.fail("node, xml-js or xml2js is not installed; .ci/run installs them with npm")
        pytest.skip("xml-js and xml2js are not installed (.ci/run's npm install line puts them in .ci/node_modules)")
    done = subprocess.run(["node", os.path.join(REPO, ".ci", "junit-readers.cjs"), junit], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return {"junitparser": enrico, **json.loads(done.stdout)}


def test_each_test_case_names_the_scenario_and_a_line_of_it_as_the_report_actions_read_them(tmp_path, monkeypatch):
    """A failed expectation at its own line; the run, and a thread that could not keep up (an implicit verdict, no line of the
    scenario declares it), at the file's first line.  The file as the run was given it, relative to where it ran."""
    monkeypatch.chdir(REPO)
    given = os.path.relpath(POLICY_MATRIX, REPO)
    ns = _run_parser().parse_args(
        [given, "--out", str(tmp_path / "r"), "--quiet", "--settle", "0", "--no-plots", "--junit", str(tmp_path / "j.xml")]
    )
    acts = {OTHER: Act(nivcsw=0), "policy=rr,priority=80": Act(served=0.5)}
    assert run_scenario(load_scenario(given), RunOptions.from_namespace(ns, env={}), FakeBackend(acts)) == 1
    junit = str(tmp_path / "j.xml")
    parsed(open(junit, encoding="utf-8").read())
    readers = _readers(junit)
    assert readers["junitparser"] == readers["xml-js"] == readers["xml2js"], readers
    cases = readers["junitparser"]
    assert cases and all(c["file"] == given == "scenarios/policy_matrix.yaml" for c in cases)
    by_name = {(c["classname"], c["name"]): (c["line"], c["failed"]) for c in cases}
    other = f"policy_matrix.{OTHER}"
    assert by_name[(other, "minimal_schedul/minimal_schedul (main): involuntary.per_callback_mean >= 1")] == (str(line_of("min: 1")), True)
    assert by_name[(other, "run")] == ("1", False)
    rr = "policy_matrix.policy=rr,priority=80"
    implicit = [(name, line) for (suite, name), (line, failed) in by_name.items() if suite == rr and failed]
    assert implicit and all(line == "1" and "missed_releases" in name for name, line in implicit), implicit


def test_a_test_case_without_a_scenario_path_names_no_file_or_line():
    doc = matrix()
    doc.scenario.path = None
    root = parsed(junit_xml(doc))
    assert all(case.get("file") is None and case.get("line") is None for case in root.iter("testcase"))


def test_cells_a_run_did_not_reach_are_skipped(tmp_path):
    junit = tmp_path / "junit.xml"
    code, _ = run(tmp_path, {FIFO10: Act(signals=1)}, "--junit", str(junit))
    assert code == 130
    root = parsed(junit.read_bytes())
    assert suite(root, FIFO10).find("testcase/error") is not None  # cut short: an error
    skipped = root.findall("testsuite/testcase/skipped")
    assert len(skipped) == 4 and {s.get("message") for s in skipped} == {"not run"}


def test_a_passing_run_has_no_failure_and_a_baseline_regression_fails(tmp_path):
    junit = tmp_path / "junit.xml"
    long = ("--duration", "40s")  # 400 callbacks a cell: enough for a p99 to be judged
    code, _ = run(tmp_path, {OTHER: Act(nivcsw=5)}, "--junit", str(junit), *long)
    assert code == 0
    root = parsed(junit.read_bytes())
    assert root.get("failures") == "0" and root.get("errors") == "0" and not root.findall(".//skipped")

    worse = tmp_path / "worse"
    code, _ = run(
        worse,
        {OTHER: Act(nivcsw=5), "policy=rr,priority=80": Act(latency_ns=900_000)},
        "--baseline",
        str(tmp_path / "r"),
        "--junit",
        str(junit),
        *long,
    )
    assert code == 1
    root = parsed(junit.read_bytes())
    (failure,) = root.findall(".//failure")
    assert failure.get("type") == "regression"
    assert (
        suite(root, "policy=rr,priority=80").find("testcase[failure]").get("name")
        == "minimal_schedul/minimal_schedul (main): latency.p99 against the baseline"
    )
    assert failure.get("message").startswith(
        "minimal_schedul/minimal_schedul (main): wake-up latency p99 50 µs [50, 50] → 900 µs [900, 900] (+850 µs (+1,700%)), "
        "threshold +20% and +10.0 µs: regression: beyond its sampling error: p = "
    ), failure.get("message")


def test_an_unwritable_junit_path_is_refused_before_anything_runs(tmp_path):
    backend = FakeBackend()
    (tmp_path / "plain").write_text("")
    for target, words in (
        (tmp_path / "plain" / "j.xml", "is a file, not a folder"),
        (tmp_path, "a folder stands where a file is expected"),
    ):
        ns = _run_parser().parse_args([POLICY_MATRIX, "--out", str(tmp_path / "r"), "--junit", str(target)])
        with pytest.raises(Exception, match=words) as caught:
            run_scenario(load_scenario(POLICY_MATRIX), RunOptions.from_namespace(ns, env={}), backend)
        assert getattr(caught.value, "exit_code", None) == 2
    assert backend.ran == []
    done = run_cli("compare", MATRIX, MATRIX, "--junit", str(tmp_path / "plain" / "j.xml"))
    assert done.code == 2 and "is a file, not a folder" in done.err


def test_junit_folders_are_made_as_out_folders_are(tmp_path):
    code, _ = run(tmp_path, {OTHER: Act(nivcsw=5)}, "--junit", str(tmp_path / "r" / "ci" / "junit.xml"))
    assert code == 0 and parsed((tmp_path / "r" / "ci" / "junit.xml").read_bytes()).get("failures") == "0"


def test_text_xml_cannot_carry_is_shown_as_ps_shows_it_not_written_raw():
    doc = matrix()
    doc.cells[0].status, doc.cells[0].reason = Status.ERROR, "worker said \x1b[31mno\x07 \ud800"
    root = parsed(junit_xml(doc))
    assert "worker said ?[31mno? ?" in root.find(".//error").get("message")
    assert xml_text("tab\tok\nline") == "tab?ok?line"


def _hostile(doc: RunDocument, name: str) -> RunDocument:
    """`doc` whose first cell failed an expectation of a thread called `name`, its id, matrix and warnings quoting it."""
    cell = doc.cells[0]
    t = main_thread(cell)
    cell.threads[cell.threads.index(t)] = t.model_copy(update={"name": name, "process": name})
    cell.id = f"v={name}"
    cell.matrix = {**cell.matrix, "v": name}
    cell.warnings = [f"thread {name} did something"]
    cell.expectations = [Verdict(thread=name, metric="latency.p99", limit="<= 1us", measured=5_000, passed=False, note=name)]
    doc.matrix_cells = doc.cell_ids = [c.id for c in doc.cells]
    return doc


def test_junit_and_annotations_show_a_thread_name_with_an_escape_sequence_and_a_newline_as_ps_does():
    """A program's thread may call itself anything: its name reaches no reader of the JUnit file or the job's log raw."""
    name = "ctl\x1b[2J\nFAIL::error::x\u2028y"
    doc = _hostile(matrix(), name)
    data = junit_xml(doc)
    SCHEMA.validate(data.decode())
    text = data.decode()
    assert "\x1b" not in text and "\u2028" not in text
    root = parsed(data)
    shown = "ctl?[2J?FAIL::error::x?y"
    for element in root.iter():
        for value in element.attrib.values():
            assert "\n" not in value and "\x1b" not in value, (element.tag, value)
    assert any(shown in (c.get("name") or "") for c in root.iter("testcase"))
    assert any(shown in (c.get("value") or "") for c in root.iter("property"))
    commands = [a.command() for a in github.for_run(doc, None, "s.yaml")]
    assert commands and all("\x1b" not in line and "\n" not in line and "\u2028" not in line for line in commands)
    assert any(f"thread {shown} did something" in line for line in commands), commands


# ---------------------------------------------------------------- runner merge / compare --junit


def test_merge_writes_junit(tmp_path):
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    done = run_cli("merge", *shards, "--out", str(tmp_path / "merged"), "--no-plots", "--junit", str(tmp_path / "j.xml"))
    assert done.code == 0, done.err
    root = parsed((tmp_path / "j.xml").read_bytes())
    assert len(root.findall("testsuite")) == 5 and root.get("failures") == "0"
    assert f"junit: {tmp_path / 'j.xml'}" in done.out


def test_compare_junit_has_a_case_per_compared_figure_and_regressions_fail(tmp_path):
    fifo = matrix().cells[1].id
    base = with_latencies(matrix(), fifo, latencies(2_000, seed=1))
    new_doc = with_latencies(base, fifo, heavy_tail(latencies(2_000, seed=2)))
    new_doc.cells = [c for c in new_doc.cells if c.id != OTHER]  # the baseline's other cell is not in this run
    new_doc.cell_ids = [c.id for c in new_doc.cells]  # (run with --cell)
    for name, doc in (("base", base), ("new", new_doc)):
        (tmp_path / name).mkdir()
        doc.save(str(tmp_path / name / "results.json"))
    done = run_cli("compare", str(tmp_path / "base"), str(tmp_path / "new"), "--junit", str(tmp_path / "j.xml"))
    assert done.code == 1
    root = parsed((tmp_path / "j.xml").read_bytes())
    comparison = cmp.compare(base, load(str(tmp_path / "new")))
    compared = [f for f in comparison.figures if f.cell != OTHER]
    assert len(root.findall("testsuite/testcase")) == len(compared) + 4 + 1  # figures, a status per cell, the missing cell
    (failure,) = root.findall(".//failure")
    assert failure.get("type") == "regression" and "wake-up latency p99" in failure.get("message")
    assert suite(root, base.cells[1].id).find("testcase[failure]") is not None
    assert suite(root, OTHER).find("testcase/skipped").get("message") == "in the baseline, not in this run"
    assert not root.findall(".//testcase[@name='run']/..//error")  # compare judges figures, not the runs


def test_a_shuffled_repeated_run_puts_its_baseline_checks_under_the_first_repeat_every_night(tmp_path):
    """JUnit test names are a history: the checks against the baseline stay under `(repeat 1)` whatever order repeats ran in."""
    acts = {OTHER: Act(nivcsw=5)}
    _, base = run(tmp_path / "base", acts, "--duration", "1s")
    placed = set()
    for seed in ("3", "7"):
        _, doc = run(tmp_path / seed, acts, "--duration", "1s", "--repeat", "2", "--shuffle", seed)
        assert [c.repeat for c in doc.cells] != sorted(c.repeat for c in doc.cells), "the shuffle must put a second repeat first"
        checks = cell_checks(doc, cmp.compare(base, doc))
        placed.add(frozenset(item.title for item in checks if any(c.kind is Kind.BASELINE for c in item.checks)))
    (titles,) = placed
    assert len(titles) == 5 and all(t.endswith("(repeat 1)") for t in titles), titles


def test_a_cell_missing_from_a_merge_and_in_the_baseline_is_one_test_suite(tmp_path):
    shards = split(tmp_path, [[0, 2, 4], [1, 3]])
    done = run_cli("merge", shards[0], "--out", str(tmp_path / "m"), "--no-plots", "--baseline", MATRIX, "--junit", str(tmp_path / "j.xml"))
    assert done.code == 0, done.err
    names = [s.get("name") for s in parsed((tmp_path / "j.xml").read_bytes()).findall("testsuite")]
    assert len(names) == len(set(names)) == 5, names


# ---------------------------------------------------------------- GitHub annotations


@pytest.mark.parametrize(
    "text, data, prop",
    [
        ("50% done", "50%25 done", "50%25 done"),
        ("a\r\nb", "a%0D%0Ab", "a%0D%0Ab"),
        ("cell a=1,b=2: x", "cell a=1,b=2: x", "cell a=1%2Cb=2%3A x"),
        ("%0A", "%250A", "%250A"),  # an escape in the text stays text
    ],
)
def test_escaping_follows_github(text, data, prop):
    assert github.escape_data(text) == data
    assert github.escape_property(text) == prop


def test_command_lines():
    assert github.Annotation("error", "m\nn", "s.yaml", 3, 5, "t: x").command() == "::error file=s.yaml,line=3,col=5,title=t%3A x::m%0An"
    assert github.Annotation("warning", "w").command() == "::warning::w"


def test_annotations_only_inside_github_actions():
    assert github.enabled({"GITHUB_ACTIONS": "true"})
    assert not github.enabled({})
    assert not github.enabled({"GITHUB_ACTIONS": "true", "RUNNER_ANNOTATIONS": "off"})


def test_paths_are_given_relative_to_the_workspace():
    assert github.workspace_path("scenarios/x.yaml", "/w/repo", "/w/repo") == "scenarios/x.yaml"
    assert github.workspace_path("../scenarios/x.yaml", "/w/repo/build", "/w/repo") == "scenarios/x.yaml"
    assert github.workspace_path("/srv/x.yaml", "/w/repo", "/w/repo") == "/srv/x.yaml"
    assert github.workspace_path(None, "/w", "/w") is None


def annotation_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith("::")]


def test_a_failed_expectation_is_an_error_at_its_scenario_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("GITHUB_ACTIONS", "true")
    monkeypatch.setenv("GITHUB_WORKSPACE", os.path.dirname(SCENARIOS))
    code, doc = run(tmp_path, {OTHER: Act(nivcsw=0), FIFO10: ERROR_ACT})
    assert code == 4
    lines = annotation_lines(capsys.readouterr().out)
    line = line_of("min: 1")
    assert lines[0].startswith(f"::error file=scenarios/policy_matrix.yaml,line={line},col=5,title=expectation failed in cell ")
    assert lines[0].endswith(
        "::cell policy=other,priority=0: minimal_schedul/minimal_schedul (main): involuntary switches per callback >= 1, measured 0.00"
    )
    assert lines[1].startswith("::error file=scenarios/policy_matrix.yaml,title=cell policy=fifo%2Cpriority=10%3A error::")
    assert "killed by SIGKILL" in lines[1] and len(lines) == 2
    stored = next(c for c in doc.cells if c.id == OTHER).expectations[0]
    assert (stored.line, stored.col) == (line, 5)


def test_without_github_actions_nothing_is_annotated(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("GITHUB_ACTIONS", raising=False)
    run(tmp_path, {OTHER: Act(nivcsw=0)})
    assert annotation_lines(capsys.readouterr().out) == []


def test_one_annotation_per_expectation_naming_every_cell_it_failed_in():
    doc = matrix()
    for cell in doc.cells[:4]:
        cell.expectations = [Verdict(thread="t", metric="latency.p99", limit="<= 2ms", measured=3_100_000, passed=False, line=37, col=5)]
    (only,) = github.for_run(doc, None, "s.yaml")
    assert (only.level, only.line, only.col) == ("error", 37, 5)
    assert only.title == "expectation failed in 4 cells: t: latency.p99 <= 2ms"
    assert only.message.splitlines()[0] == f"cell {doc.cells[0].id}: t: wake-up latency p99 <= 2ms, measured 3.10 ms"
    assert len(only.message.splitlines()) == 4


def test_regressions_are_warnings_on_the_scenario_file():
    base, new = matrix(), matrix()
    for n, cell in enumerate(base.cells):
        base = with_latencies(base, cell.id, latencies(2_000, seed=n))
        new = with_latencies(new, cell.id, heavy_tail(latencies(2_000, seed=10 + n)))
    found = github.for_run(new, cmp.compare(base, new), "scenarios/policy_matrix.yaml", run=False)
    assert [a.level for a in found] == ["warning"] and found[0].line is None
    assert found[0].title == "regression in 5 cells: minimal_schedul/minimal_schedul (main): latency.p99 against the baseline"
    assert found[0].file == "scenarios/policy_matrix.yaml"


def test_past_ten_per_level_the_tenth_says_how_many_more():
    doc = matrix()
    doc.cells[0].expectations = [
        Verdict(thread=f"t{i}", metric="latency.p99", limit="<= 2ms", measured=3_000_000, passed=False, line=10 + i, col=5)
        for i in range(15)
    ]
    found = github.for_run(doc, None, "s.yaml")
    assert len(found) == 10 and found[-1].title == "6 more" and "6 more error annotation(s)" in found[-1].message
    assert [a.line for a in found[:9]] == list(range(10, 19))


def test_a_scenario_warning_is_annotated_at_its_place():
    got = github.for_problem(Problem("s.yaml", 4, 9, "processes[0].cpus", "CPU 7 is not online here", "warning")).command()
    assert got == "::warning file=s.yaml,line=4,col=9::processes[0].cpus: CPU 7 is not online here"


def test_verdict_position_round_trips_and_older_files_read_without_it(tmp_path):
    doc = matrix()
    assert all(v.line is None for c in doc.cells for v in c.expectations)  # recorded before positions were kept
    doc.cells[0].expectations[0].line, doc.cells[0].expectations[0].col = 36, 5
    doc.save(str(tmp_path / "results.json"))
    again = load(str(tmp_path / "results.json"))
    assert (again.cells[0].expectations[0].line, again.cells[0].expectations[0].col) == (36, 5)


# ---------------------------------------------------------------- permission advice (README, Permissions)


def test_sudo_advice_names_the_virtual_environment_script():
    from runner.run.preflight import runner_command

    assert runner_command("/srv/rt/.venv/bin/python", "/srv/rt/.venv", "/usr") == "sudo /srv/rt/.venv/bin/runner"
    assert runner_command("/usr/bin/python3", "/usr", "/usr") == "sudo runner"


def test_rights_advice_covers_login_services_and_containers_and_never_setcap():
    from runner.run.preflight import Permissions, _grant_rt, how_to_grant

    text = _grant_rt(Permissions("rt", 1000, False, False, 0, 65536), 80)
    for words in ("/etc/security/limits.d/", "'rt  -  rtprio  98'", "LimitRTPRIO=98", "--cap-add SYS_NICE --ulimit rtprio=98", "sudo "):
        assert words in text, words
    assert "setcap" not in text and "limits.conf" not in text
    memlock = how_to_grant("rt", "memlock", "unlimited", "LimitMEMLOCK=infinity", "--ulimit memlock=-1", "sudo runner")
    assert "'rt  -  memlock  unlimited'" in memlock and "LimitMEMLOCK=infinity" in memlock


@pytest.mark.parametrize("uid", [0, 1000])
def test_rights_advice_to_root_without_the_capability_says_it_is_missing_not_sudo(monkeypatch, uid):
    """Root in a container without CAP_SYS_NICE: sudo would change nothing; a user without it is told of sudo."""
    import errno

    from runner.run import preflight
    from runner.run.preflight import Needs, Permissions
    from runner.scenario.model import Policy

    monkeypatch.setattr(preflight, "_try_on_thread", lambda action: errno.EPERM)  # the kernel refuses, as it would
    wanted = Needs(rt={(Policy.FIFO, 80): "p/t"}, min_nice=(-5, "p/n"), lock=(80 << 20, "process p locks its memory"))
    missing = preflight.missing_rights(Permissions("root" if uid == 0 else "rt", uid, False, False, 0, 65536), wanted)
    assert len(missing) == 3
    for line, cap, container in zip(
        missing, ("CAP_SYS_NICE", "CAP_SYS_NICE", "CAP_IPC_LOCK"), ("--cap-add SYS_NICE", "--cap-add SYS_NICE", "--cap-add IPC_LOCK")
    ):
        if uid == 0:
            assert "run as root" not in line and "(sudo " not in line, line
            assert f"this user is root but lacks {cap}" in line and container in line, line
            # root without the capability is bound by its own limits like any user; pam_limits applies a limits.d line to
            # root's logins when it names root itself (a `*` line does not)
            assert "/etc/security/limits.d/" in line and "'root  -  " in line, line
        else:
            assert "run as root (sudo " in line and "limits.d" in line and "is root" not in line, line


def test_rights_advice_to_root_with_the_capability_names_what_else_refuses(monkeypatch):
    import errno

    from runner.run import preflight
    from runner.run.preflight import Needs, Permissions
    from runner.scenario.model import Policy

    monkeypatch.setattr(preflight, "_try_on_thread", lambda action: errno.EPERM)
    (line,) = preflight.missing_rights(Permissions("root", 0, True, True, 0, -1), Needs(rt={(Policy.FIFO, 80): "p/t"}))
    assert "this user is root and has CAP_SYS_NICE, so sudo would change nothing" in line and "cpu.rt_runtime_us" in line
    assert "run as root" not in line and "--cap-add" not in line


def test_no_message_of_the_runner_suggests_setcap():
    import runner

    root = os.path.dirname(runner.__file__)
    for folder, _, files in os.walk(root):
        for name in files:
            if name.endswith((".py", ".j2", ".c")):
                with open(os.path.join(folder, name), encoding="utf-8") as handle:
                    text = handle.read()
                assert "setcap cap_sys_nice" not in text, name


def test_readme_installs_into_a_virtual_environment_and_says_how_to_grant_rights():
    from conftest import REPO

    with open(os.path.join(REPO, "README.md"), encoding="utf-8") as handle:
        text = handle.read()
    first = text.split("```sh\n", 1)[1].split("```", 1)[0].splitlines()
    assert len(first) == 2 and all(line.startswith("python3 -m venv .venv && . .venv/bin/activate && pip install ") for line in first)
    assert "sudo .venv/bin/runner" in text and "pipx install ." in text
    # the README's "Permissions" (which the runner's messages name) is short and leads to the whole of it
    short = text.split("\n## Permissions\n", 1)[1].split("\n## ", 1)[0]
    assert "(docs/permissions.md#permissions)" in short and "exit 3" in short
    assert "setcap" not in text.replace(short, "")  # only where it leads to its warning
    with open(os.path.join(REPO, "docs", "permissions.md"), encoding="utf-8") as handle:
        text = handle.read()
    permissions = text.split("\n## Permissions\n", 1)[1].split("\n# ", 1)[0]
    for words in ("limits.d", "LimitRTPRIO=", "LimitMEMLOCK=", "CPUSchedulingPolicy=", "AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK",
                  "--cap-add SYS_NICE --ulimit rtprio=99 --ulimit memlock=-1", "cpu.rt_runtime_us", "cgroup v2"):  # fmt: skip
        assert words in permissions, words
    assert "setcap" not in text.replace(permissions, "")  # only where its warning is
    assert "grants `CAP_SYS_NICE` to every script that interpreter runs" in " ".join(permissions.split())


def test_problems_in_a_scenario_are_annotated_at_their_line(tmp_path, monkeypatch):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nprocesses:\n  - name: app\n    threads: [{name: t, sched: fifo:100}]\n")
    monkeypatch.setenv("GITHUB_WORKSPACE", str(tmp_path))
    monkeypatch.setenv("GITHUB_ACTIONS", "true")
    for argv in (("validate", str(bad)), (str(bad), "--list")):
        done = run_cli(*argv)
        assert done.code == 2
        (line,) = annotation_lines(done.out)
        assert line.startswith("::error file=bad.yaml,line=4,col=") and "sched" in line, line
    monkeypatch.delenv("GITHUB_ACTIONS")
    assert annotation_lines(run_cli("validate", str(bad)).out) == []


def test_the_pre_commit_hooks_are_ci_s_linters_from_the_lint_extra():
    """.pre-commit-config.yaml runs ruff check, ruff format and mypy from the environment (language: system),
    so a commit is checked by the versions the lint extra pins, as .ci/run checks it."""
    import re

    import yaml
    from conftest import pyproject

    with open(os.path.join(REPO, ".pre-commit-config.yaml"), encoding="utf-8") as handle:
        config = yaml.safe_load(handle)
    hooks = {h["id"]: h for repo in config["repos"] for h in repo["hooks"]}
    assert [r["repo"] for r in config["repos"]] == ["local"]
    assert set(hooks) == {"ruff", "ruff-format", "mypy"}
    assert hooks["ruff"]["entry"].split()[:2] == ["ruff", "check"] and hooks["ruff-format"]["entry"].split()[:2] == ["ruff", "format"]
    assert all(h["language"] == "system" for h in hooks.values())
    assert hooks["mypy"]["pass_filenames"] is False  # the package as [tool.mypy] configures it, not the files staged
    lint = pyproject()["project"]["optional-dependencies"]["lint"]
    pinned = {m.group(1) for d in lint if (m := re.match(r"([\w-]+)==", d))}
    assert {"ruff", "mypy"} <= pinned
