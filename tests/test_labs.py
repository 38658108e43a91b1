"""The lab formats: LAVA's test cases (read back with LAVA's own line grammar), KCIDB documents (valid under kcidb-io's
schema), and the shipped LAVA test definition (valid under LAVA's own schema, where Debian's lava-common is installed).

LAVA's grammar, as its sources have it (Linaro/lava): `lava-test-case` takes `TEST_CASE_ID --result RESULT
[--units UNITS] [--measurement MEASUREMENT]` and prints `<LAVA_SIGNAL_TESTCASE TEST_CASE_ID=ID RESULT=R UNITS=U
MEASUREMENT=M>`; `lava-test-set start NAME` and `stop` print `<LAVA_SIGNAL_TESTSET START NAME>` and `<... STOP>`.
The dispatcher finds signals with `<LAVA_SIGNAL_(\\S+) ([^>]+)>`, splits their parameters on whitespace, reads
`KEY=VALUE` pairs (lava_dispatcher/actions/test/shell.py), and takes a result of pass, fail, skip or unknown and
a measurement float() reads (lava_dispatcher/connection.py, SignalMatch).  Names: no spaces, none of
``$& "'`()<>/\\|;`` (doc/v2/writing-tests.rst), at most 100 characters (lava_results_app's TestCase.name).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap

import kcidb_io
import pytest
import yaml
from conftest import REPO, SCENARIOS, _in_ci, run_cli
from fakebackend import Act
from kernelrun import needs_rt
from reportdata import MATRIX, matrix, memory
from test_ci import ERROR_ACT, FIFO10, OTHER, run

from runner.report.kcidb import kcidb_document
from runner.report.labs import KEY_FIGURES, LabStatus, lab_cells
from runner.report.lava import LavaCall, lava_calls, lava_name, measurement, send
from runner.results.document import RunDocument, Status

SIGNAL = re.compile(r"<LAVA_SIGNAL_(\S+) ([^>]+)>")  # the dispatcher's pattern for every signal
NOT_IN_NAMES = re.compile(r"[\s$&\"'`()<>/\\|;]")  # writing-tests.rst's forbidden characters, and white space
RESULTS = ("pass", "fail", "skip", "unknown")
DEFINITION = os.path.join(REPO, "lava", "runner.yaml")


def signal_of(argv: list[str]) -> str:
    """The signal LAVA's own helper prints for `argv` (lava-test-case, lava-test-set), by its option grammar."""
    tool, args = argv[0], argv[1:]
    if tool == "lava-test-set":
        assert args[0] in ("start", "stop") and len(args) == (2 if args[0] == "start" else 1), args
        return f"<LAVA_SIGNAL_TESTSET START {args[1]}>" if args[0] == "start" else "<LAVA_SIGNAL_TESTSET STOP>"
    assert tool == "lava-test-case" and args and not args[0].startswith("--"), argv
    case, options = args[0], dict(zip(args[1::2], args[2::2]))
    assert len(args[1:]) % 2 == 0 and set(options) <= {"--result", "--units", "--measurement"} and "--result" in options, argv
    data = f" RESULT={options['--result']}"
    data += f" UNITS={options['--units']}" if "--units" in options else ""
    data += f" MEASUREMENT={options['--measurement']}" if "--measurement" in options else ""
    return f"<LAVA_SIGNAL_TESTCASE TEST_CASE_ID={case}{data}>"


def dispatcher_reads(signal: str) -> tuple[str, dict[str, str]]:
    """What LAVA's dispatcher takes from a signal line: its name and parameters, checked as the dispatcher checks them."""
    match = SIGNAL.fullmatch(signal)
    assert match, signal
    name, params = match.group(1), match.group(2).split()
    if name != "TESTCASE":
        return name, {"params": " ".join(params)}
    data = {}
    for param in params:
        key, sep, value = param.partition("=")
        assert sep, f"malformed parameter {param!r}"
        data[key.lower()] = value
    assert data["result"] in RESULTS, data
    if "measurement" in data:
        float(data["measurement"])
    return name, data


def check_lava(calls: list[LavaCall]) -> list[dict[str, object]]:
    """Every call as LAVA reads it, after checking LAVA's rules: names, sets opened and closed, one case of a name per set."""
    out: list[dict[str, object]] = []
    current = None
    names: set[str] = set()
    sets: set[str] = set()
    for call in calls:
        assert shlex.split(call.line) == list(call.argv)  # the printed line says the same call, word for word
        name, data = dispatcher_reads(signal_of(list(call.argv)))
        if name == "TESTSET":
            if data["params"].startswith("START "):
                assert current is None
                current = data["params"].removeprefix("START ")
                assert current not in sets and not NOT_IN_NAMES.search(current) and len(current) <= 100 and current.isascii()
                sets.add(current)
                names = set()
            else:
                assert current is not None
                current = None
            continue
        case = str(data["test_case_id"])
        assert current is not None and case not in names, case
        assert not NOT_IN_NAMES.search(case) and len(case) <= 100 and case.isascii(), case
        names.add(case)
        out.append({"set": current, **data})
    assert current is None
    return out


def test_the_lava_cases_read_as_lavas_grammar_reads_them():
    cases = check_lava(lava_calls(matrix()))
    first = [c for c in cases if c["set"] == "policy=fifo,priority=10"]
    by_name = {str(c["test_case_id"]): c for c in first}
    assert first[0] == {"set": "policy=fifo,priority=10", "test_case_id": "outcome", "result": "pass"}
    p99 = by_name["minimal_schedul.minimal_schedul.latency.p99"]
    assert (p99["result"], p99["measurement"], p99["units"]) == ("pass", "58.366", "us")  # its expectation: <= 2ms, met
    assert by_name["minimal_schedul.minimal_schedul.callbacks"]["units"] == "count"
    assert {"latency.min", "latency.max", "latency.p99"} <= {str(c["test_case_id"]).split(".", 2)[2] for c in first[1:]}
    assert {c["set"] for c in cases} == {c.id for c in matrix().cells}
    assert all(str(c["test_case_id"]).startswith("minimal_schedul.minimal_schedul.") for c in first[1:])  # its helper threads: no callbacks


def test_a_failed_cell_never_passes_its_thread_and_a_cut_short_one_is_unknown(tmp_path):
    """A thread that missed releases fails its implicit expectation, and every figure of it fails too (never a pass on a
    thread that could not keep up) but those an expectation met, as the report says them; a cell that could not run
    fails its outcome, its figures unknown."""
    code, doc = run(tmp_path, {FIFO10: Act(served=0.5), OTHER: ERROR_ACT})
    assert code == 4
    cases = check_lava(lava_calls(doc))
    behind = {str(c["test_case_id"]): c for c in cases if c["set"] == FIFO10}
    judged = {f"minimal_schedul.minimal_schedul.{m}" for m in ("latency.p99", "involuntary.per_callback_mean")}  # both met
    assert behind.pop("outcome")["result"] == "fail" and len(behind) > 5
    assert {n: c["result"] for n, c in behind.items() if n in judged} == dict.fromkeys(judged, "pass")
    assert {c["result"] for n, c in behind.items() if n not in judged} == {"fail"}, behind  # its figures, not a pass among them
    assert float(str(behind["minimal_schedul.minimal_schedul.missed_releases"]["measurement"])) > 0
    broken = [c for c in cases if c["set"] == OTHER]
    assert broken[0]["result"] == "fail" and {c["result"] for c in broken[1:]} <= {"unknown", "fail"}
    fine = [c for c in cases if c["set"] == "policy=fifo,priority=80"]
    assert {c["result"] for c in fine} == {"pass"}


def _hostile(doc: RunDocument) -> RunDocument:
    """`doc` with thread and process names a program could give itself, a cell id with spaces, and duplicates once cleaned."""
    cell = doc.cells[0]
    names = ["$(reboot) `x` a>b", "a b", "a_b", "é/\\|;'\"&", "x" * 300]
    threads = [t.model_copy(update={"name": n, "process": "p q"}) for t, n in zip(cell.threads, names)]
    threads = [t.model_copy(update={"periodic": True}) for t in threads]
    cell = cell.model_copy(update={"threads": threads, "id": "a b=1,c/d=" + "z" * 200})
    return doc.model_copy(update={"cells": [cell], "cell_ids": [cell.id]})


def test_names_any_thread_can_give_itself_obey_lavas_rules_and_stay_apart():
    cases = check_lava(lava_calls(_hostile(matrix())))
    threads = {str(c["test_case_id"]).rsplit(".", 1)[0].split(".latency")[0] for c in cases[1:]}
    assert len({str(c["test_case_id"]) for c in cases}) == len(cases)
    assert len([c for c in cases if str(c["test_case_id"]).endswith(".faults.major")]) == 5  # five threads, five names
    assert all(n.isascii() for n in threads)
    assert lava_name("x" * 300) != lava_name("x" * 301) and len(lava_name("x" * 300)) == 100


def test_measurements_are_exact_decimals():
    assert [measurement(v, 1000) for v in (58_366, 58_300, 58_000, -1_200, 0, 7)] == ["58.366", "58.3", "58", "-1.2", "0", "0.007"]
    assert [measurement(v, 1) for v in (12, 9.8889, 0.0, 1e-12)] == ["12", "9.8889", "0", "0"]


@pytest.fixture
def fake_lava(tmp_path, monkeypatch):
    """lava-test-case and lava-test-set on PATH, recording their arguments as LAVA's would receive them."""
    folder = tmp_path / "lava-bin"
    folder.mkdir()
    log = tmp_path / "calls.jsonl"
    for tool in ("lava-test-case", "lava-test-set"):
        script = folder / tool
        script.write_text(
            f"#!{sys.executable}\nimport json, os, sys\n"
            f"open({str(log)!r}, 'a').write(json.dumps([os.path.basename(sys.argv[0])] + sys.argv[1:]) + '\\n')\n"
            "sys.exit(int(os.environ.get('FAKE_LAVA_EXIT', '0')))\n"
        )
        script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{folder}{os.pathsep}{os.environ['PATH']}")

    def calls() -> list[list[str]]:
        return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []

    return calls


def test_report_lava_calls_lavas_helpers_when_they_are_on_path(fake_lava):
    done = run_cli("report", MATRIX, "--lava")
    assert done.code == 0 and "lava-test-case" not in done.out, done.err
    assert fake_lava() == [list(c.argv) for c in lava_calls(matrix())]


def test_report_lava_prints_the_same_lines_without_them(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    done = run_cli("report", MATRIX, "--lava")
    assert done.code == 0 and done.out.splitlines() == [c.line for c in lava_calls(matrix())], done.err
    assert not os.path.exists(os.path.join(MATRIX, "report.md.new"))


def test_report_lava_exits_as_the_run_did(tmp_path, monkeypatch):
    """Its exit code is the run's (session.exit_code): 1 for a failed expectation, 4 for a cell that could not run or a
    run that never finished, 130 for one interrupted; the same results without --lava re-render and exit 0."""
    monkeypatch.setenv("PATH", str(tmp_path))
    code, doc = run(tmp_path, {FIFO10: Act(served=0.5)})
    assert code == 1 and run_cli("report", str(tmp_path / "r"), "--lava").code == 1
    for status, want in (("running", 4), ("interrupted", 130)):
        path = str(tmp_path / f"{status}.json")
        doc.model_copy(update={"status": status, "cells": doc.cells[:2]}).save(path)
        done = run_cli("report", path, "--lava")
        assert done.code == want and done.out.startswith("lava-test-set start"), (status, done.code, done.err)
    assert run_cli("report", str(tmp_path / "r"), "-o", str(tmp_path / "x.md")).code == 0


def test_a_lava_helper_that_fails_stops_the_report_with_exit_4(fake_lava, monkeypatch):
    monkeypatch.setenv("FAKE_LAVA_EXIT", "3")
    done = run_cli("report", MATRIX, "--lava")
    assert done.code == 4 and "`lava-test-set start policy=fifo,priority=10` exited 3" in done.err, done.err
    assert len(fake_lava()) == 1


def test_send_calls_a_helper_found_once_and_prints_for_one_missing():
    ran: list[list[str]] = []
    looked: list[str] = []

    def which(name: str) -> str | None:
        looked.append(name)
        return "/x/lava-test-case" if name == "lava-test-case" else None

    class Done:
        returncode = 0

    calls = [LavaCall(("lava-test-set", "start", "a")), LavaCall(("lava-test-case", "b", "--result", "pass"))] * 2
    send(calls, which=which, run=lambda argv, **_: ran.append(argv) or Done())
    assert ran == [["/x/lava-test-case", "b", "--result", "pass"]] * 2 and sorted(looked) == ["lava-test-case", "lava-test-set"]


def test_a_run_with_lava_reports_its_cells_after_its_verdict(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PATH", str(tmp_path))
    code, doc = run(tmp_path, {OTHER: Act(nivcsw=2)}, "--lava")
    out = capsys.readouterr().out.splitlines()
    lines = [c.line for c in lava_calls(doc)]
    assert code == 0 and out[-len(lines) :] == lines
    assert "passed; results:" in out[-len(lines) - 1]


# ------------------------------------------------------------------ KCIDB


def valid_kcidb(data: dict[str, object]) -> dict[str, object]:
    """`data` after kcidb-io's own validation of schema v5.3 (JSON Schema draft 7, formats checked), and id checks."""
    kcidb_io.schema.V5_3.validate_exactly(data)
    for kind in ("checkouts", "builds", "tests"):
        ids = [o["id"] for o in data.get(kind, [])]  # type: ignore[attr-defined]
        assert len(ids) == len(set(ids)), kind
    return data


def test_the_kcidb_document_is_valid_and_says_what_the_run_measured():
    data = valid_kcidb(kcidb_document(matrix()))
    assert data["version"] == {"major": 5, "minor": 3}
    (build,) = data["builds"]  # type: ignore[misc]
    tests = {t["path"]: t for t in data["tests"]}  # type: ignore[attr-defined]
    cell = tests["runner.policy_matrix.policy_fifo_priority_10"]
    assert cell["status"] == "PASS" and cell["misc"]["cell"] == "policy=fifo,priority=10" and cell["duration"] == 1.331
    assert cell["environment"]["misc"]["kernel"] == "6.18.44-fc-v669" and cell["environment"]["comment"] == "vm"
    assert [f["name"] for f in cell["output_files"]] == ["report.md", "results.json", "samples.csv.gz"]
    assert all(f["url"].startswith("file:///") for f in cell["output_files"])
    p99 = tests["runner.policy_matrix.policy_fifo_priority_10.minimal_schedul.minimal_schedul.latency.p99"]
    assert p99["status"] == "PASS" and p99["number"] == {"value": 58366e-9, "unit": "s", "prefix": "metric"}
    assert "latency p99 <= 2ms, measured" in p99["comment"]
    p50 = tests["runner.policy_matrix.policy_fifo_priority_10.minimal_schedul.minimal_schedul.latency.p50"]
    assert p50["status"] == "DONE" and p50["number"]["unit"] == "s"
    assert tests["runner.policy_matrix.policy_fifo_priority_10.minimal_schedul.minimal_schedul.callbacks"]["number"] == {
        "value": 10,
        "prefix": "metric",
    }
    assert all(t["build_id"] == build["id"] for t in data["tests"])  # type: ignore[attr-defined]
    assert kcidb_document(matrix()) == data  # the same ids every time: a second submission replaces the first


def test_the_kcidb_statuses_follow_the_verdicts(tmp_path):
    code, doc = run(tmp_path, {FIFO10: Act(served=0.5), OTHER: ERROR_ACT}, "--cell", "policy=fifo*", "--cell", "policy=other*")
    assert code == 4
    data = valid_kcidb(kcidb_document(doc))
    cells = {t["misc"]["cell"]: t for t in data["tests"] if t["path"].count(".") == 2}  # type: ignore[attr-defined]
    assert {c: t["status"] for c, t in cells.items()} == {FIFO10: "FAIL", "policy=fifo,priority=80": "PASS", OTHER: "ERROR"}
    behind = [t for t in data["tests"] if "policy_fifo_priority_10.minimal_schedul" in t["path"]]  # type: ignore[attr-defined]
    by_figure = {t["path"].rsplit("minimal_schedul.", 1)[1]: t["status"] for t in behind[1:]}
    assert behind[0]["status"] == "FAIL" and by_figure["missed_releases"] == "FAIL"  # the thread, and the verdict that failed it
    assert by_figure["latency.p99"] == "PASS" and by_figure["latency.p50"] == "DONE"  # a met expectation; a measurement
    broken = [t for t in data["tests"] if "policy_other_priority_0." in t["path"]]  # type: ignore[attr-defined]
    assert {t["status"] for t in broken} <= {"ERROR", "FAIL"}
    assert not [c for c in lab_cells(doc) if c.status is LabStatus.DONE]


def test_cells_the_run_never_reached_are_missed(tmp_path):
    doc = matrix().model_copy(update={"status": "running"})
    doc.cells = doc.cells[:2]
    data = valid_kcidb(kcidb_document(doc))
    statuses = {t["misc"]["cell"]: t["status"] for t in data["tests"] if t["path"].count(".") == 2}  # type: ignore[attr-defined]
    assert list(statuses.values()) == ["PASS", "PASS", "MISS", "MISS", "MISS"]
    doc.status = Status.INTERRUPTED.value
    assert [c.status for c in lab_cells(doc)][2:] == [LabStatus.SKIP] * 3


def test_kcidb_takes_hostile_names_a_given_build_and_a_publishing_url():
    data = valid_kcidb(kcidb_document(_hostile(matrix()), origin="lab_1", build_id="maestro:67a1b2", url="https://lab.example/r/42/"))
    assert "checkouts" not in data and all(t["build_id"] == "maestro:67a1b2" for t in data["tests"])  # type: ignore[attr-defined]
    assert all(t["id"].startswith("lab_1:") for t in data["tests"])  # type: ignore[attr-defined]
    names = {t["misc"]["name"] for t in data["tests"] if "name" in t.get("misc", {})}  # type: ignore[attr-defined]
    assert "p q[0]/$(reboot) `x` a>b (main)" in names  # the exact name kept where KCIDB allows it
    urls = [f["url"] for t in data["tests"] for f in t.get("output_files", [])]  # type: ignore[attr-defined]
    assert urls[:2] == ["https://lab.example/r/42/report.md", "https://lab.example/r/42/results.json"]
    valid_kcidb(kcidb_document(memory()))


def test_every_key_figure_of_the_registry_has_a_lab_unit():
    from runner.report.labs import LAB_UNITS

    assert {f.unit for f in KEY_FIGURES} <= set(LAB_UNITS)
    assert {"latency.min", "latency.mean", "latency.max", "latency.p99", "missed_releases"} <= {f.name for f in KEY_FIGURES}


def test_report_kcidb_writes_the_file_and_checks_its_options(tmp_path):
    target = tmp_path / "k.json"
    done = run_cli("report", MATRIX, "--kcidb", str(target), "--kcidb-origin", "my_lab", "--kcidb-url", "https://x.example/run/")
    assert done.code == 0 and done.err == "", done.err
    data = valid_kcidb(json.loads(target.read_text()))
    assert data["checkouts"][0]["id"].startswith("my_lab:")  # type: ignore[index]
    for given, words in (
        (["--kcidb-origin", "lab"], "--kcidb-origin lab shapes the KCIDB export; give --kcidb FILE too"),
        (["--kcidb", "-", "--kcidb-origin", "Lab-1"], "--kcidb-origin 'Lab-1': expected lowercase letters, digits and _"),
        (["--kcidb", "-", "--kcidb-build", "67a1"], "--kcidb-build '67a1': expected a KCIDB build id, ORIGIN:ID"),
        (["--kcidb", "-", "--kcidb-url", "lab/runs"], "--kcidb-url 'lab/runs': expected a URL"),
        (["--kcidb", "-", "--json", "-"], "only one export can go to standard output"),
    ):
        done = run_cli("report", MATRIX, *given)
        assert done.code == 2 and done.err.startswith(f"runner report: {words}"), (given, done.err)


# ------------------------------------------------------------------ the LAVA test definition


def test_the_lava_definition_is_what_lava_takes():
    """Its metadata as LAVA requires, a name by LAVA's rules, and run steps that are single lines of shell without
    pipes or redirects (writing-tests.rst), calling a script of this repository that parses as sh."""
    with open(DEFINITION, encoding="utf-8") as handle:
        definition = yaml.safe_load(handle)
    meta = definition["metadata"]
    assert meta["format"] == "Lava-Test Test Definition 1.0" and meta["description"]
    assert not NOT_IN_NAMES.search(meta["name"]) and meta["name"].isascii()
    assert "install" not in definition  # deprecated in Lava-Test Test Definition 1.0: run.sh installs
    assert all(isinstance(v, str) for v in definition["params"].values())
    steps = definition["run"]["steps"]
    assert steps and all(isinstance(s, str) and "\n" not in s for s in steps)
    for step in steps:
        words = shlex.split(step)
        assert not {"|", ">", ">>", "<", ";", "&&", "||", "&"} & set(words) and not re.search(r"[|<>;]", step), step
        script = os.path.join(REPO, words[0])
        assert os.access(script, os.X_OK), script
        subprocess.run(["sh", "-n", script], check=True)
        assert set(re.findall(r"\$\{(\w+)\}", step)) == set(definition["params"])  # every parameter reaches the script


def test_the_lava_definition_validates_under_lavas_own_schema():
    """lava_common's voluptuous schema (Debian's lava-common package; LAVA's REST API validates definitions with it)."""
    system = "/usr/bin/python3"
    found = os.path.exists(system) and not subprocess.run([system, "-c", "import lava_common.schemas.test.testdef"]).returncode
    if not found:
        if _in_ci():
            pytest.fail("Debian's lava-common is not installed; .ci/run installs it")
        pytest.skip("Debian's lava-common not installed (apt-get install lava-common)")
    with open(DEFINITION, encoding="utf-8") as handle:
        data = json.dumps(yaml.safe_load(handle))
    check = "import json, sys\nfrom lava_common.schemas.test.testdef import validate\nvalidate(json.load(sys.stdin))\n"
    done = subprocess.run([system, "-c", check], input=data, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    broken = json.dumps({"metadata": {"name": "x"}, "run": {"steps": ["a"]}})
    assert subprocess.run([system, "-c", check], input=broken, capture_output=True, text=True).returncode != 0  # it does refuse


@pytest.mark.kernel
@needs_rt  # its scenario's fifo:50, for a p99 that passes on a busy machine
def test_the_lava_script_runs_a_scenario_and_reports_each_cell(tmp_path, fake_lava):
    """lava/run.sh as LAVA runs it, with the runner already installed (its VENV is this one): the install and every
    cell reach lava-test-case, and KCIDB's file is written beside the results."""
    scenario = tmp_path / "s.yaml"
    scenario.write_text(
        textwrap.dedent(
            """\
            name: lava_smoke
            duration: 500ms
            processes:
              - name: tick
                main: {sched: fifo:50, work: {kind: periodic, period: 10ms, burn: 100us}}
            expect:
              - {thread: tick, metric: latency.p99, max: 50ms}
            """
        )
    )
    out = tmp_path / "out"
    done = subprocess.run(
        [os.path.join(REPO, "lava", "run.sh"), str(scenario), "", str(out), sys.prefix], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    calls = fake_lava()
    assert calls[0] == ["lava-test-case", "runner-install", "--result", "pass"]
    assert calls[1] == ["lava-test-set", "start", "default"] and calls[-1] == ["lava-test-set", "stop"]
    p99 = next(c for c in calls if c[1] == "tick.tick.latency.p99")
    assert p99[2:4] == ["--result", "pass"] and p99[-2:] == ["--units", "us"] and float(p99[5]) > 0
    (run_folder,) = out.iterdir()
    valid_kcidb(json.loads((run_folder / "kcidb.json").read_text()))
    assert (run_folder / "junit.xml").exists()


def test_the_shipped_scenario_the_definition_names_exists():
    with open(DEFINITION, encoding="utf-8") as handle:
        scenario = yaml.safe_load(handle)["params"]["SCENARIO"]
    assert os.path.exists(os.path.join(REPO, scenario)) and scenario.startswith("scenarios/")
    assert shutil.which("sh") and os.path.dirname(os.path.join(REPO, scenario)) == SCENARIOS
