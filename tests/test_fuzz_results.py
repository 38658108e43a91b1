"""Fuzzing the readers: mutated recorded results must give exit 0, 1 or 2, never a traceback.

`runner report`, `runner compare` and `runner merge` read files that may come from another
machine, another version, or an attacker: every mutation of the recorded runs in tests/data
(values, types, keys, NaN, huge numbers, unicode and control characters, samples paths,
truncated text and samples files, values and keys of up to 100,000 characters, a plan asking for
up to two million cell runs) must end in a result or one-line errors, none longer than
`LINE_BOUND`.  Each run is
mutated in both forms a reader meets: as recorded (runner.results/1, upgraded on load) and
as this runner writes it (runner.results/2, read strictly).

A short run by default; `RUNNER_FUZZ_EXAMPLES=5000` for a long one (CI runs 1,000).  Reproducible:
derandomized, no example database.
"""

from __future__ import annotations

import gzip
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from conftest import run_cli
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from reportdata import DATA, MATRIX

EXAMPLES = int(os.environ.get("RUNNER_FUZZ_EXAMPLES", "120"))
LINE_BOUND = 5_000  # characters of a line a reader prints: a problem quotes a long value cut (errors.bounded)
RUNS = sorted(name for name in os.listdir(DATA) if os.path.isfile(os.path.join(DATA, name, "results.json")))  # recorded runs, not rtapp/


def _as_written(name: str) -> Any:
    """The recorded run as this runner writes it (runner.results/2)."""
    from runner.results.read import load

    return json.loads(load(os.path.join(DATA, name)).model_dump_json(by_alias=True))


ORIGINAL = {name: json.loads(Path(DATA, name, "results.json").read_text(encoding="utf-8")) for name in RUNS}
ORIGINAL.update({f"{name}@2": _as_written(name) for name in RUNS})
FORMS = sorted(ORIGINAL)  # `name` as recorded (/1), `name@2` as written now

TEXT = st.lists(
    st.characters(codec="utf-8", exclude_categories=("Cs",))
    | st.sampled_from(list("\x00\n\r\t\u2028$|`#*_[]<>&\\/") + ["..", "$\\foo$", "<script>", "线程"]),
    max_size=8,
).map("".join)
LEAF = st.one_of(
    st.none(),
    st.booleans(),
    TEXT,
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 2**63, -(2**63) - 1, 1e300, -0.0, "", "all", "fifo", "passed", "0-1", "p99"]),
)
VALUE = st.recursive(LEAF, lambda inner: st.lists(inner, max_size=3) | st.dictionaries(TEXT, inner, max_size=3), max_leaves=6)
LONG = st.builds(lambda unit, n: unit * n, st.sampled_from(["y", "线", "a b ", "'", '"', "\\", "\n"]), st.integers(500, 100_000))
SAMPLES_PATHS = st.sampled_from(
    ["/etc/passwd", "../../x", "cells/../../x", "cells/../cells", "", ".", "cells", "cells/x/samples.csv.gz", "\x00", "results.json"]
)


def _nodes(node: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [path]
    if isinstance(node, dict):
        for key, value in node.items():
            out += _nodes(value, path + (key,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _nodes(value, path + (i,))
    return out


NODES = {name: _nodes(doc) for name, doc in ORIGINAL.items()}


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for part in path[:-1]:
        doc = doc[part]
    return doc


@st.composite
def mutated(draw: st.DrawFn) -> tuple[str, str, list[tuple[str, Any]]]:
    """A recorded run's results.json text after a few mutations, and what to do to its samples files."""
    name = draw(st.sampled_from(FORMS))
    doc = json.loads(json.dumps(ORIGINAL[name]))
    for _ in range(draw(st.integers(1, 4))):
        path = draw(st.sampled_from(NODES[name][1:]))
        try:
            parent = _parent(doc, path)
            parent[path[-1]]  # the path may be gone after an earlier mutation
        except (KeyError, IndexError, TypeError):
            continue
        op = draw(st.sampled_from(["replace", "replace", "delete", "add", "samples_file", "copy", "long", "amplify"]))
        if op == "long":  # a long value where one was, or a long key beside it
            if isinstance(parent, dict) and draw(st.booleans()):
                parent[draw(LONG)] = parent[path[-1]]
            else:
                parent[path[-1]] = draw(LONG)
        elif op == "amplify" and isinstance(doc.get("plan"), dict):  # cells times repeats: up to twice what a run may ask for
            cells = draw(st.integers(1, 2_000))
            doc["cell_ids"] = [f"c{i}" for i in range(cells)]
            doc["plan"]["repeat"] = draw(st.integers(1, 2_000_000 // cells))
        elif op == "replace":
            parent[path[-1]] = draw(VALUE)
        elif op == "delete":
            del parent[path[-1]]
        elif op == "add" and isinstance(parent, dict):
            parent[draw(TEXT)] = draw(VALUE)
        elif op == "copy" and isinstance(parent, list):
            parent.append(json.loads(json.dumps(parent[path[-1]])))
        elif op == "samples_file" and doc.get("cells"):
            cells = doc["cells"] if isinstance(doc["cells"], list) else []
            if cells and isinstance(cells[0], dict):
                cells[draw(st.integers(0, len(cells) - 1))]["samples_file"] = draw(SAMPLES_PATHS)
    text = json.dumps(doc, ensure_ascii=draw(st.booleans()))
    edit = draw(st.sampled_from(["none", "none", "none", "truncate", "huge", "inf", "garbage"]))
    if edit == "truncate":
        text = text[: draw(st.integers(0, len(text)))]
    elif edit in ("huge", "inf") and '": 0' in text:
        text = text.replace('": 0', '": ' + ("9" * 5000 if edit == "huge" else "1e999"), 1)
    elif edit == "garbage":
        at = draw(st.integers(0, len(text)))
        text = text[:at] + draw(TEXT) + text[at:]
    samples = draw(st.lists(st.tuples(st.sampled_from(["truncate", "rows", "empty", "missing", "symlink"]), st.integers(0, 4)), max_size=2))
    return name, text, samples


BAD_ROWS = [
    b"thread,seq,latency_ns,nivcsw,minflt,cpu_end\nk,1,x,0,0,0\n",
    b"thread\n\n\n",
    b"\x00\x01\x02",
    b"thread,seq,latency_ns,nivcsw,minflt,cpu_end\n" + b"a,1," + b"9" * 40 + b",0,0,0\n",
]


def _spoil_samples(folder: str, how: str, index: int, outside: str = "/etc/hostname") -> None:
    """Spoil one of the folder's sample files as `how` says; "symlink" makes it a link to `outside`, a file out of the folder."""
    files = sorted(os.path.join(d, f) for d, _, fs in os.walk(os.path.join(folder, "cells")) for f in fs)
    if not files:
        return
    path = Path(files[index % len(files)])
    if path.is_symlink():  # spoilt into a link already: a write would go into `outside` (as root, /etc/hostname)
        return
    if how == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif how == "rows":
        path.write_bytes(gzip.compress(BAD_ROWS[index % len(BAD_ROWS)]))
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "missing":
        os.unlink(path)
    elif how == "symlink":
        os.unlink(path)
        os.symlink(outside, path)


def _lay_out(tmp: str, case: tuple[str, str, list[tuple[str, Any]]]) -> str:
    """The mutated run as a results folder under `tmp` (its samples spoilt as drawn); its path."""
    name, text, samples = case
    run = os.path.join(tmp, "run")
    shutil.copytree(os.path.join(DATA, name.split("@")[0]), run)
    with open(os.path.join(run, "results.json"), "w", encoding="utf-8", errors="surrogatepass") as handle:
        handle.write(text)
    for how, index in samples:
        _spoil_samples(run, how, index)
    return run


def _check(argv: tuple[str, ...]) -> None:
    done = run_cli(*argv)
    # README's exit codes a reader of results can give: a regression 1, a refused input 2, a cell in error or a run that
    # never finished 4, a run asked to stop 130; never 70 (an internal error) or a traceback
    assert done.code in (0, 1, 2, 4, 130), (argv, done.code, done.err[-2000:])
    for bad in ("Traceback", "internal error"):
        assert bad not in done.err and bad not in done.out, (argv, done.err[-2000:])
    longest = max((len(line) - len(max(argv, key=len)) for line in done.err.splitlines()), default=0)
    assert longest < LINE_BOUND, (argv, f"a line of {longest:,} characters", done.err[:500])


@settings(
    max_examples=EXAMPLES,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(mutated())
def test_mutated_results_never_crash_report_compare_or_merge(case):
    with tempfile.TemporaryDirectory() as tmp:
        run = _lay_out(tmp, case)
        _check(("report", run, "-o", os.path.join(tmp, "report.md"), "--no-plots"))
        _check(("compare", MATRIX, run))
        _check(("compare", run, run, "-o", os.path.join(tmp, "comparison.md")))
        _check(("merge", run, "--out", os.path.join(tmp, "merged"), "--no-plots"))


@settings(
    max_examples=max(3, EXAMPLES // 20),
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(mutated())
def test_mutated_results_never_crash_the_plots(case):
    with tempfile.TemporaryDirectory() as tmp:
        _check(("report", _lay_out(tmp, case)))


def test_a_sample_spoilt_into_a_link_is_never_written_through(tmp_path):
    """A link, then rows: as root the fuzz once wrote gzip bytes into /etc/hostname; as anyone else it failed on EACCES."""
    folder = tmp_path / "run"
    (folder / "cells" / "c").mkdir(parents=True)
    (folder / "cells" / "c" / "samples.csv.gz").write_bytes(gzip.compress(b"thread\n"))
    outside = tmp_path / "outside"
    outside.write_bytes(b"kept\n")
    for how in ("truncate", "rows", "empty"):
        _spoil_samples(str(folder), "symlink", 0, outside=str(outside))
        _spoil_samples(str(folder), how, 0, outside=str(outside))
        assert outside.read_bytes() == b"kept\n", how


def test_the_fuzzer_reaches_every_outcome():
    """A harness that only ever produced refusals (or only successes) would prove little."""
    with tempfile.TemporaryDirectory() as tmp:
        run = os.path.join(tmp, "run")
        shutil.copytree(MATRIX, run)
        assert run_cli("report", run, "--no-plots").code == 0
        doc = json.loads(json.dumps(ORIGINAL["policy_matrix"]))
        doc["cells"][0]["threads"][0]["latency_us"]["p99"] = "fast"
        with open(os.path.join(run, "results.json"), "w", encoding="utf-8") as handle:
            json.dump(doc, handle)
        done = run_cli("report", run, "--no-plots")
        assert done.code == 2 and "cells[0].threads[0].latency_us.p99" in done.err
        doc = json.loads(json.dumps(ORIGINAL["policy_matrix@2"]))
        assert run_cli("report", _written(run, doc), "--no-plots").code == 0
        doc["cells"][0]["threads"][0]["figures"]["latency_ns"]["p99"] = "fast"
        done = run_cli("report", _written(run, doc), "--no-plots")
        assert done.code == 2 and "cells[0].threads[0].figures.latency_ns.p99" in done.err


def _written(folder: str, doc: Any) -> str:
    with open(os.path.join(folder, "results.json"), "w", encoding="utf-8") as handle:
        json.dump(doc, handle)
    return folder


def _limited(argv: tuple[str, ...], memory: int = 1 << 30) -> subprocess.CompletedProcess[str]:
    """`runner ARGV` in a child process that may use at most `memory` bytes: a blow-up fails the child, not the machine."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    code = "import sys; from runner.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, preexec_fn=limit, timeout=300)


@settings(
    max_examples=max(1, EXAMPLES // 60),  # and the explicit examples: a child process each
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    name=st.sampled_from(FORMS),
    cells=st.sampled_from([1, 5, 1_000, 4_000]) | st.integers(1, 4_000),
    repeat=st.sampled_from([1, 1_000, 1_000_000]) | st.integers(1, 1_000_000),
    status=st.sampled_from(["passed", "running", "interrupted", "error"]),
    command=st.sampled_from(["report", "compare", "merge"]),
)
@example(name="policy_matrix@2", cells=2_000, repeat=1_000_000, status="passed", command="report")  # the file the issue reported
@example(name="policy_matrix", cells=4_000, repeat=500_000, status="running", command="compare")
@example(name="memory_lock@2", cells=1_001, repeat=1_000, status="interrupted", command="merge")
def test_a_plan_asking_for_billions_of_cell_runs_costs_no_memory(name, cells, repeat, status, command):
    """A 44 KB file asking for 10^6 repeats of 2,000 cells took 7 to 9 GB to count them: in 1 GiB, it is refused or read."""
    doc = json.loads(json.dumps(ORIGINAL[name]))
    doc["cell_ids"] = [f"c{i}" for i in range(cells)]
    doc.setdefault("plan", {})["repeat"] = repeat
    doc["status"] = status
    with tempfile.TemporaryDirectory() as tmp:
        run = _lay_out(tmp, (name, json.dumps(doc), []))
        argv = {"report": (run, "-o", "-", "--no-plots"), "compare": (MATRIX, run), "merge": (run, "--out", os.path.join(tmp, "m"))}
        done = _limited((command, *argv[command]))
        assert done.returncode in (0, 1, 2, 4, 130), (command, cells, repeat, done.stderr[-2000:])
        assert "Traceback" not in done.stderr and "internal error" not in done.stderr, done.stderr[-2000:]
        if cells * repeat > 1_000_000:
            assert "no run asks for more than 1,000,000" in done.stderr, done.stderr[-2000:]
