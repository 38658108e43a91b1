"""The markdown report and its plots, rendered from recorded results: golden files, table structure, units."""

from __future__ import annotations

import copy
import itertools
import os
import re
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from conftest import run_cli
from hypothesis import given, settings
from hypothesis import strategies as st
from markdown_it import MarkdownIt
from reportdata import DATA, MATRIX, matrix, memory, program, renamed, traced

from runner.report import fmt
from runner.report import markdown as report
from runner.report.publish import append_step_summary, write_report

GOLDEN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "golden")


def golden(name: str, text: str) -> None:
    """Compare with tests/golden/NAME; UPDATE_GOLDEN=1 rewrites it (review the diff before committing).

    Tables are compared as parsed cells (text, alignment), not as source: how a table is spaced
    out (cells are no longer padded to their column's width) does not matter, its content does.
    Everything outside the tables is compared byte for byte.
    """
    path = os.path.join(GOLDEN, name)
    if os.environ.get("UPDATE_GOLDEN") == "1":
        with open(path, "w", encoding="utf-8") as handle:
            handle.write(text)
    with open(path, encoding="utf-8") as handle:
        expected = handle.read()
    got, want = layout(text), layout(expected)
    for n, (a, b) in enumerate(zip(got, want)):
        assert a == b, f"{name} changed at block {n}; rerun with UPDATE_GOLDEN=1 if intended"
    assert len(got) == len(want), f"{name} changed: {len(got)} blocks, golden has {len(want)}"


Block = tuple[str, object]


def layout(markdown: str) -> list[Block]:
    """`markdown` as blocks: ("text", the source lines between tables) and ("table", rows of (alignment, cell text)).

    A table's cells are the parser's (pipes unescaped, stripped), so two renderings that differ only
    in column padding have the same layout, and any other difference (a cell, a row, an alignment,
    a character outside a table) shows.
    """
    tokens = MarkdownIt("commonmark").enable("table").parse(markdown)
    lines = markdown.splitlines(keepends=True)
    out: list[Block] = []
    done = 0
    rows: list[list[tuple[str, str]]] = []
    align = ""
    for tok in tokens:
        if tok.type == "table_open":
            assert tok.map is not None
            start, end = tok.map
            out.append(("text", "".join(lines[done:start])))
            done, rows = end, []
        elif tok.type == "tr_open":
            rows.append([])
        elif tok.type in ("th_open", "td_open"):
            align = str(tok.attrs.get("style", ""))
        elif tok.type == "inline" and rows and tok.level > 3:  # a cell's text (table > thead/tbody > tr > cell)
            rows[-1].append((align, tok.content.strip()))
        elif tok.type == "table_close":
            out.append(("table", rows))
            rows = []
    out.append(("text", "".join(lines[done:])))
    return out


def test_golden_layout_ignores_padding_and_nothing_else():
    a = "# t\n\n| a   | b |\n|:----|--:|\n| ✅ x |  1 |\n\nend\n"
    assert layout(a) == layout(a.replace("| a   |", "| a |").replace("|  1 |", "| 1 |").replace(":----", ":--"))
    for changed in (
        a.replace("✅ x", "✅ y"),
        a.replace("--:", "---"),
        a.replace("end", "end."),
        a.replace("| ✅ x |  1 |\n", "| ✅ x |  1 |\n| z | 2 |\n"),
        a.replace("# t", "## t"),
    ):
        assert layout(changed) != layout(a), changed


def tables(markdown: str) -> list[list[list[str]]]:
    """Every table in `markdown` as rows of cell texts, parsed by a CommonMark+GFM parser."""
    tokens = MarkdownIt("commonmark").enable("table").parse(markdown)
    out: list[list[list[str]]] = []
    row: list[str] | None = None
    for tok in tokens:
        if tok.type == "table_open":
            out.append([])
        elif tok.type == "tr_open":
            row = []
        elif tok.type == "inline" and row is not None:
            row.append(tok.content)
        elif tok.type == "tr_close":
            out[-1].append(row or [])
            row = None
    return out


def test_matrix_report_matches_golden_file():
    golden("policy_matrix.md", report.render_run(matrix()))


def test_memory_lock_report_matches_golden_file():
    golden("memory_lock.md", report.render_run(memory()))


def test_traced_report_matches_golden_file():
    """A run the scheduler trace followed, with expectations that failed: the headline's `file:line`, the trace's table."""
    golden("traced.md", report.render_run(traced()))


def test_program_report_matches_golden_file():
    """A `command:` program measured from outside: its command line, its rule, /proc's rates and the trace's."""
    golden("own_program.md", report.render_run(program()))


def test_every_table_parses_as_a_table_with_even_rows():
    text = report.render_run(matrix())
    found = tables(text)
    # facts, the summary's two, the thread across cells in five groups, then per cell: scheduling, switches,
    # latency, releases and slack, faults, expectations
    assert len(found) == 1 + 2 + 5 + 5 * 6
    for t in found:
        assert len(t) >= 2 and len({len(r) for r in t}) == 1, t[0]


def test_report_shows_the_headline_effect_in_words_and_units():
    text = report.render_run(matrix())
    found = tables(text)
    switches = next(t for t in found if t[0][:2] == ["Cell", "Involuntary / callback (mean)"])
    latency = next(t for t in found if t[0][0] == "Cell" and "p99 (µs)" in t[0])
    scheduling = next(t for t in found if t[0][:2] == ["Cell", "Scheduling"])
    row = {r[0]: r for r in switches}
    assert float(row["policy=other,priority=0"][1]) > 1.0
    assert row["policy=fifo,priority=80"][1] == "0.00"
    assert {r[0]: r[1] for r in scheduling}["policy=fifo,priority=80"] == "FIFO 80"
    p99 = latency[0].index("p99 (µs)")
    assert [r[p99] for r in latency[1:]] == ["58", "84", "90", "69", "3,156"]  # one unit, one precision: the largest's
    for raw in ("per_callback_mean", "latency_us", "minor_after_first", "nivcsw"):
        assert raw not in text  # readable by someone who only read the seed
    assert "0 involuntary switches in 10 callbacks" in text


NUMBER = r"[−+]?[0-9][0-9,]*(\.[0-9]+)?"


def test_numbers_are_right_aligned_with_their_unit_in_the_header_only():
    """GitHub aligns by the `---:` markers; a number column never mixes units or precisions, nor carries a unit itself."""
    doc = matrix()
    again = copy.deepcopy(doc.cells)
    for cell in again:
        cell.repeat = 1
    doc.cells += again  # the spread table too
    for text in (report.render_run(doc), report.render_run(memory())):
        numeric = 0
        for block in layout(text):
            if block[0] != "table":
                continue
            rows = block[1]
            assert isinstance(rows, list)
            for col, (style, header) in enumerate(rows[0]):
                values = [r[col][1] for r in rows[1:] if r[col][1] not in ("–", "")]
                is_number = [re.fullmatch(NUMBER + r"( ⚠️)?", v) for v in values]
                if values and all(is_number) and header != "CPUs":  # a CPU list (`0-1`) is a set, not a quantity
                    numeric += 1
                    assert style == "text-align:right", (header, values)
                    if header not in ("Limit", "Measured"):  # expectations: each row its own figure, unit and precision
                        assert len({len(v.split(" ")[0].partition(".")[2]) for v in values}) == 1, (header, values)
                if style == "text-align:right":  # a number, `2 of 2`, `≤ 0.50`, or a spread `51.6 (43.3 – 62.4)`
                    for v in values:
                        assert re.fullmatch(rf"(≤ |≥ )?{NUMBER}( ⚠️| of [0-9]+| \({NUMBER} – {NUMBER}\))?", v), (header, v)
        assert numeric > 20


def test_limits_are_in_the_unit_and_precision_of_what_they_limit():
    text = report.render_run(matrix())
    verdicts = next(t for t in tables(text) if t[0][0] == "Verdict")
    assert verdicts[2][2:] == ["wake-up latency p99 (µs)", "≤ 2,000", "58"]
    assert verdicts[1][2:] == ["involuntary switches per callback", "≤ 0.50", "0.00"]


def test_ps_table_in_the_report_is_the_procps_layout():
    text = report.render_run(matrix())
    block = text.split("```text\n", 1)[1].split("```", 1)[0]
    lines = block.splitlines()
    assert lines[0] == "  TID COMMAND         RTPRIO CLS PSR"
    assert lines[1].split()[2:4] == ["10", "FF"]
    assert all(line.split()[2:4] == ["-", "TS"] for line in lines[2:])


def test_single_cell_report_has_no_matrix_sections():
    doc = matrix()
    doc.cells = doc.cells[:1]
    text = report.render_run(doc)
    assert "## Matrix summary" not in text and "across cells" not in text
    assert "**minimal_schedul/minimal_schedul (main)** at FIFO 10" in text


def test_repeats_get_a_spread_table_and_their_own_sections():
    doc = matrix()
    again = copy.deepcopy(doc.cells)
    for cell in again:
        cell.repeat = 1
    doc.cells += again
    text = report.render_run(doc)
    assert "## Spread across repeats" in text
    assert "## Cell policy=other,priority=0 (repeat 2)" in text
    assert "(#cell-policyotherpriority0-repeat-2)" in text


def test_plots_are_valid_svg_with_every_cell_overlaid(tmp_path):
    doc = matrix()
    path = write_report(doc, str(tmp_path))
    text = Path(path).read_text(encoding="utf-8")
    svgs = sorted(os.listdir(tmp_path / "plots"))
    assert svgs == ["minimal_schedul-minimal_schedul-main.involuntary.svg", "minimal_schedul-minimal_schedul-main.latency.svg"]
    for name in svgs:
        root = ET.parse(tmp_path / "plots" / name).getroot()
        assert root.tag.endswith("svg")
        assert f"(plots/{name})" in text
        body = (tmp_path / "plots" / name).read_text()
        for cell in doc.cells:
            assert cell.id in body  # legend entry per cell (svg.fonttype none keeps text as text)


def test_plots_are_deterministic(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for folder in (a, b):
        folder.mkdir()
        write_report(matrix(), str(folder))
    for name in os.listdir(a / "plots"):
        assert (a / "plots" / name).read_bytes() == (b / "plots" / name).read_bytes()


def test_report_command_re_renders_without_running(tmp_path):
    import shutil

    shutil.copytree(MATRIX, tmp_path / "run")
    done = run_cli("report", str(tmp_path / "run"))
    assert done.code == 0, done.err
    assert (tmp_path / "run" / "report.md").read_text() == report.render_run(matrix(), _plots(tmp_path / "run"))
    out = run_cli("report", os.path.join(MATRIX, "results.json"), "-o", "-")
    assert out.code == 0 and out.out == report.render_run(matrix())


def _plots(folder):  # the plot links write_report made, rebuilt from the files
    from runner.report.markdown import Plot

    names = sorted(os.listdir(folder / "plots"))
    label = "minimal_schedul/minimal_schedul (main)"
    return [
        Plot(f"{label}: wake-up latency histogram", f"plots/{names[1]}"),
        Plot(f"{label}: involuntary context switches per callback", f"plots/{names[0]}"),
    ]


def test_report_of_a_file_that_is_not_results_is_a_user_error(tmp_path):
    bad = tmp_path / "results.json"
    bad.write_text('{"schema": "something/else"}')
    done = run_cli("report", str(bad))
    assert done.code == 2 and "expected a runner.results/2 (or runner.results/1) results file" in done.err
    assert "Traceback" not in done.err
    bad.write_text("{not json")
    done = run_cli("report", str(bad))
    assert done.code == 2 and f"{bad}:1:2: not valid JSON" in done.err


def test_step_summary_is_appended_without_plot_links(tmp_path):
    summary = tmp_path / "summary.md"
    summary.write_text("earlier step\n")
    text = "# r\n\n![plot](plots/x.svg)\n\n| a |\n|---|\n| 1 |\n"
    assert append_step_summary(text, {"GITHUB_STEP_SUMMARY": str(summary)}) == str(summary)
    assert summary.read_text() == "earlier step\n# r\n\n\n| a |\n|---|\n| 1 |\n\n"
    assert append_step_summary(text, {}) is None


@pytest.mark.parametrize(
    "value, text",
    [
        (None, "–"),
        (6040, "6.0 µs"),
        (56580, "56.6 µs"),
        (99_940, "99.9 µs"),
        (142_000, "142 µs"),
        (999_400, "999 µs"),
        (6_122_100, "6.12 ms"),
        (2_500_000_000, "2.50 s"),
        (0, "0.0 µs"),
    ],
)
def test_durations_are_stored_in_ns_and_shown_in_the_unit_that_reads_best(value, text):
    assert fmt.fmt_ns(value) == text


def test_fixture_data_is_where_the_tests_expect_it():
    assert os.path.isdir(os.path.join(DATA, "policy_matrix", "cells"))


def test_written_files_get_the_mode_of_any_new_file(tmp_path):
    from runner.safefs import write_atomic

    mask = os.umask(0o022)
    os.umask(mask)
    for name, data in (("results.json", "{}"), ("samples.csv.gz", b"\x1f\x8b")):
        path = tmp_path / name
        write_atomic(str(path), data)
        assert path.stat().st_mode & 0o777 == 0o666 & ~mask, name
    path = write_report(matrix(), str(tmp_path))
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~mask
    for name in os.listdir(tmp_path / "plots"):
        assert (tmp_path / "plots" / name).stat().st_mode & 0o777 == 0o666 & ~mask


@pytest.mark.parametrize("fail", ["write", "fsync", "replace"])
def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary_file(tmp_path, monkeypatch, fail):
    import errno

    from runner import safefs as results

    path = tmp_path / "results.json"
    path.write_text("old")

    def broken(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    if fail == "write":
        monkeypatch.setattr(results.os, "fchmod", broken)
    else:
        monkeypatch.setattr(results.os, fail, broken)
    with pytest.raises(OSError) as err:
        results.write_atomic(str(path), "new")
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(path)  # the caller can say which file
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["results.json"]


def test_a_device_or_fifo_named_as_an_output_is_written_into_never_replaced(tmp_path):
    import stat
    import threading

    from runner.safefs import write_named

    null = tmp_path / "null"
    try:
        os.mknod(null, 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # a /dev/null of our own: the real one is not ours to risk
    except PermissionError:  # without CAP_MKNOD: the real one, which only root could have replaced
        null = Path("/dev/null")
    write_named(str(null), "{}")
    assert stat.S_ISCHR(os.stat(null).st_mode), "the device was replaced by a regular file"
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    write_named(str(fifo), "through the pipe")
    reader.join(5)
    assert got == [b"through the pipe"] and stat.S_ISFIFO(fifo.stat().st_mode)


@pytest.mark.parametrize("named", [False, True], ids=["in a results folder", "named on the command line"])
def test_a_link_where_a_file_is_written_is_refused_and_what_it_names_untouched(tmp_path, named):
    """A link planted in a downloaded results folder once carried the runner's writes to the file it named, as root too."""
    import errno

    from runner.safefs import write_atomic, write_named

    write = write_named if named else write_atomic
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "made-by-the-write")
    for path in (link, dangling):
        with pytest.raises(OSError) as err:
            write(str(path), "new")
        assert err.value.errno == errno.ELOOP and err.value.filename == str(path) and "symbolic link" in str(err.value)
        assert path.is_symlink()
    assert real.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["dangling.json", "link.json", "real.json"]


def test_a_device_or_fifo_in_a_results_folder_is_refused_never_written_into(tmp_path):
    """`tar x` as root makes the device files an archive holds: a report.md that is the disk must not be written."""
    import stat

    from runner.safefs import open_write, write_atomic

    fifo = tmp_path / "report.md"
    os.mkfifo(fifo)
    began = time.monotonic()
    for write in (lambda: write_atomic(str(fifo), "x"), lambda: open_write(str(fifo))):
        with pytest.raises(OSError, match="a FIFO, not a regular file"):
            write()
    assert time.monotonic() - began < 2 and stat.S_ISFIFO(fifo.stat().st_mode)


def test_a_folder_that_cannot_take_the_file_is_an_os_error_naming_the_file(tmp_path):
    from runner.safefs import write_atomic

    target = tmp_path / "missing" / "results.json"
    with pytest.raises(OSError) as err:
        write_atomic(str(target), "x")
    assert err.value.filename == str(target)


@settings(max_examples=200, derandomize=True, database=None)
@given(
    st.lists(
        st.tuples(st.text(max_size=30), st.integers(-2, 12), st.integers(-2, 12), st.text(max_size=30)),
        min_size=2,
        max_size=6,
        unique_by=lambda t: t,
    )
)
def test_plot_names_are_injective_safe_and_bounded(threads):
    import re

    from runner.report.plots import plot_name
    from runner.results.document import ThreadResult, thread_key

    def thread(process, instance, index, name):  # identity only: plot names need nothing else
        return ThreadResult.model_construct(process=process, instance=instance, index=index, name=name)

    names = {thread_key(*t): plot_name(thread(*t)) for t in threads}
    keys = {thread_key(*t) for t in threads}
    assert len(set(names.values())) == len(keys), names
    for name in names.values():
        assert re.fullmatch(r"[A-Za-z0-9_.=,+~-]+", name) and not name.startswith(".") and len(name) <= 133


def test_plot_names_of_threads_in_other_scripts_do_not_collide(tmp_path):
    doc = renamed(str(tmp_path / "run"), [("进程", "线程甲"), ("进程", "线程乙")])
    text = Path(write_report(doc, str(tmp_path))).read_text(encoding="utf-8")
    keys = {t.key for c in doc.cells for t in c.threads if t.periodic}
    assert len(keys) == 3  # the two renamed threads and the recorded one in the other cells
    per_thread = [n for n in os.listdir(tmp_path / "plots") if n.endswith(".latency.svg") and n != "all-threads.latency.svg"]
    assert len(per_thread) == 3
    assert text.count(".latency.svg)") == 3 + 1  # and the aggregate of all periodic threads


# ---------------------------------------------------------------- results files that are not what they claim


def _edited(tmp_path, edit):
    import shutil

    folder = tmp_path / "run"
    shutil.copytree(MATRIX, folder)
    path = folder / "results.json"
    text = edit(path.read_text(encoding="utf-8"))
    path.write_text(text, encoding="utf-8")
    return str(path)


def _json_edit(change):
    import json

    def edit(text):
        data = json.loads(text)
        change(data)
        return json.dumps(data)

    return edit


def _thread(data):
    return data["cells"][0]["threads"][0]


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t.replace('"p99": 58.366', '"p99": NaN'), ":1:1: NaN is not a number"),
        (lambda t: t.replace('"p99": 58.366', '"p99": Infinity'), "Infinity is not a number"),
        (lambda t: t.replace('"p99": 58.366', '"p99": 1e400'), "1e400 is out of range"),
        (lambda t: t.replace('"callbacks": 10,', '"callbacks": ' + "9" * 5000 + ",", 1), "not a usable number"),
        (
            _json_edit(lambda d: _thread(d).update(callbacks="ten")),
            "cells[0].threads[0].callbacks: input should be a valid integer; got 'ten'",
        ),
        (
            _json_edit(lambda d: _thread(d).update(callbacks=True)),
            "cells[0].threads[0].callbacks: input should be a valid integer; got True",
        ),
        (
            _json_edit(lambda d: _thread(d)["latency_us"].update(p99=1e300)),
            "cells[0].threads[0].latency_us.p99: input should be less than or equal to",
        ),
        (_json_edit(lambda d: _thread(d).pop("faults")), "cells[0].threads[0].faults: field required"),
        (_json_edit(lambda d: d["cells"][0].update(status="splendid")), "cells[0].status: input should be"),
        (_json_edit(lambda d: d.update(cells={"a": 1})), "cells: input should be a valid list"),
        (_json_edit(lambda d: d.update(command="runner x")), "command: input should be a valid list"),
        (
            _json_edit(lambda d: d["cells"][0]["background"].append({"kind": "command", "argv": [1]})),
            "cells[0].background[2].argv[0]: input should be a valid string; got 1",
        ),
        (
            # 4,305 digits in ns: past Python's limit for an integer as text
            _json_edit(lambda d: d.update(plan={**d.get("plan", {}), "settle_s": 10**4295})),
            "plan.settle_ns: an integer of about 4,305 digits is out of range; expected a 64-bit integer",
        ),
        (
            _json_edit(lambda d: d["cells"][0].update(overhead_s={"start_to_first_callback": 10**400})),  # past a float's range
            "cells[0].overhead_s.start_to_first_callback: input should be a valid number; got an integer of about 401 digits",
        ),
        (lambda t: "[" * 100 + "]" * 100, "nested more than 64 levels"),
        (lambda t: "[]", "expected a runner.results/2 (or runner.results/1) results file, got None"),
        (lambda t: '{"schema": "runner.results/1", "x": ' + "[" * 100 + "]" * 100 + "}", "nested more than 64 levels"),
        (lambda t: "\xff", "not valid JSON"),
    ],
)
def test_bad_results_files_are_one_line_errors(tmp_path, edit, message):
    path = _edited(tmp_path, edit)
    for argv in (("report", path, "-o", "-"), ("compare", MATRIX, path), ("merge", path, "--out", str(tmp_path / "m"))):
        done = run_cli(*argv)
        assert done.code == 2, (argv, done.out[-300:], done.err)
        assert message in done.err, done.err
        assert done.err.startswith(path + ":") and "Traceback" not in done.err and "internal error" not in done.err


def test_a_file_that_is_not_utf8_is_a_one_line_error(tmp_path):
    path = tmp_path / "results.json"
    path.write_bytes(b'{"schema": "\xff"}')
    done = run_cli("report", str(path), "-o", "-")
    assert done.code == 2 and f"{path}:1:1: not UTF-8 text" in done.err


@pytest.mark.parametrize(
    "content, message",
    [
        (lambda raw: raw[: len(raw) // 2], "cannot read samples"),
        (lambda raw: b"not gzip at all", "cannot read samples"),
        (
            lambda raw: __import__("gzip").compress(b"thread,seq,latency_ns,nivcsw,minflt,cpu_end\nk,1,x,0,0,0\n"),
            ":2:1: not a samples row: latency_ns is 'x'",
        ),
        (lambda raw: __import__("gzip").compress(b"thread,seq\nk,1\n"), "column latency_ns is missing"),
        (
            lambda raw: __import__("gzip").compress(b"thread,seq,latency_ns,nivcsw,minflt,cpu_end\nk,1," + b"9" * 30 + b",0,0,0\n"),
            "out of range",
        ),
    ],
)
def test_bad_samples_files_are_one_line_errors(tmp_path, content, message):
    import shutil

    shutil.copytree(MATRIX, tmp_path / "run")
    cell = matrix().cells[0]
    samples = tmp_path / "run" / cell.samples_file
    samples.write_bytes(content(samples.read_bytes()))
    done = run_cli("report", str(tmp_path / "run"))
    assert done.code == 2, done.err
    assert done.err.startswith(f"{samples}:") and message in done.err and "Traceback" not in done.err
    written = (tmp_path / "run" / "report.md").read_text(encoding="utf-8")  # said once the report is written, not instead of it
    assert f"Plots skipped: drawing them failed ({samples}:" in written.replace("\\", "")


def test_a_figure_that_is_not_a_number_is_written_as_null(tmp_path):
    import json

    from runner.results.read import load

    doc = matrix()
    t = doc.cells[0].threads[0]
    doc.cells[0].threads[0] = t.model_copy(
        update={
            "figures": t.figures.model_copy(
                update={"involuntary": t.figures.involuntary.model_copy(update={"per_callback_mean": float("nan")})}
            )
        }
    )
    doc.cells[0].expectations[0] = doc.cells[0].expectations[0].model_copy(update={"measured": float("inf")})
    doc.save(str(tmp_path / "results.json"))
    text = (tmp_path / "results.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    stored = json.loads(text)["cells"][0]
    assert stored["threads"][0]["figures"]["involuntary"]["per_callback_mean"] is None
    assert stored["expectations"][0]["measured"] is None
    again = load(str(tmp_path)).cells[0]
    assert again.threads[0].figures.involuntary.per_callback_mean is None and again.expectations[0].measured is None


def test_every_recorded_run_loads_and_what_runner_writes_loads_again(tmp_path):
    for name in os.listdir(DATA):
        doc = report_load(os.path.join(DATA, name))
        doc.save(str(tmp_path / f"{name}.json"))
        again = report_load(str(tmp_path / f"{name}.json"))
        assert again.cells == doc.cells
        assert again.model_dump(exclude={"folder", "source"}) == doc.model_dump(exclude={"folder", "source"})


def report_load(path):
    from runner.results.read import load

    return load(path)


# ---------------------------------------------------------------- names from the scenario stay text

HOSTILE = st.lists(
    st.sampled_from(
        list("#|`*_[]()!<>&\\~-+=.:$@/ \n\r\t\x00\u2028\u202ea1")
        + ["<script>", "](http://x)", "$\\foo$", "```", "<!--", "&amp;", "1. ", "> ", "- ", "## "]
        + ["@bob", "#12", "GH-3", "o/r#4", "https://x.io/a", "www.x.io", "a@b.io", " #1"]
    ),
    min_size=1,
    max_size=12,
).map("".join)


def structure(markdown: str) -> list[str]:
    """The markdown's blocks (headings, lists, tables with their rows and cells) and inline structure, no text.

    Code spans count as text: `md_text` shows what GitHub would link (`@bob`, `#1`) in one, and escapes every
    backtick of the text itself, so a code span of a name is the escape's (`rendered_text` checks what it holds).
    """
    out = []
    for tok in MarkdownIt("commonmark").enable(["table", "strikethrough"]).parse(markdown):
        if tok.type != "inline":
            out.append(tok.type + tok.tag)
        for child in tok.children or []:
            if child.type not in ("text", "text_special", "softbreak", "code_inline"):
                out.append(child.type)
    return out


def rendered_text(markdown: str) -> str:
    tokens = MarkdownIt("commonmark").enable(["table", "strikethrough"]).parse(markdown)
    return "".join(c.content for t in tokens for c in t.children or [] if c.type in ("text", "text_special", "code_inline"))


# What GitHub links by itself in rendered text outside code and links (html-pipeline's mention and issue reference
# filters, cmark-gfm's autolink extension), written wider than GitHub's: any of these in text is a failure.
GITHUB_LINKS = re.compile(r"@[A-Za-z0-9]|#\d|\bGH-\d|://|\bwww\.", re.IGNORECASE)


def github_links(markdown: str) -> list[str]:
    """The text of `markdown`, rendered, that GitHub would turn into a mention, an issue reference or a link."""
    out = []
    for tok in MarkdownIt("commonmark").enable(["table", "strikethrough"]).parse(markdown):
        in_link = 0
        for child in tok.children or []:
            in_link += child.type == "link_open"
            in_link -= child.type == "link_close"
            if child.type in ("text", "text_special") and not in_link and GITHUB_LINKS.search(child.content):
                out.append(child.content)
    return out


@settings(max_examples=300, derandomize=True, database=None)
@given(HOSTILE)
def test_escaped_text_renders_as_the_text_itself(text):
    from runner.report.fmt import md_text

    expected = re.sub(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\u202e]", " ", text).strip()
    escaped = md_text(text)
    assert "\n" not in escaped
    assert " ".join(rendered_text(escaped).split()) == " ".join(expected.split()), (text, escaped)
    assert structure(escaped) in ([], ["paragraph_openp", "paragraph_closep"]), (text, escaped)
    assert github_links(escaped) == [], (text, escaped)
    cell = md_text(text, in_table=True)
    row = "| a | b |\n|---|---|\n| " + cell + " | x |\n"
    assert structure(row) == structure("| a | b |\n|---|---|\n| plain | x |\n"), (text, cell)
    assert " ".join(rendered_text(row).split()) == " ".join(("ab" + expected + "x").split()), (text, cell)
    assert github_links(row) == [], (text, cell)


def _hostile_doc(name: str, cells: int = 3):
    doc = matrix()
    doc.cells = doc.cells[:cells]
    doc.scenario = doc.scenario.model_copy(update={"description": name, "name": name})
    for i, cell in enumerate(doc.cells):
        cell.id = f"v={name}{i}"
        cell.reason = name
        t = next(t for t in cell.threads if t.periodic)
        cell.threads[cell.threads.index(t)] = t.model_copy(update={"process": name, "name": name, "degraded": [name]})
        cell.expectations = [v.model_copy(update={"thread": name, "limit": name, "note": name}) for v in cell.expectations]
    doc.matrix_cells = doc.cell_ids = [c.id for c in doc.cells]
    return doc


@settings(max_examples=40, derandomize=True, database=None, deadline=None)
@given(HOSTILE.filter(lambda s: re.sub(r"[\x00-\x20\x7f-\x9f\u2028\u2029]", "", s)))  # a blank description is none
def test_hostile_names_do_not_change_the_report_structure(name):
    from runner.report.compare import compare

    plain = _hostile_doc("plain")
    hostile = _hostile_doc(name)
    text = report.render_run(hostile)
    assert structure(text) == structure(report.render_run(plain))
    assert github_links(text) == [], name
    section = report.render_comparison(compare(hostile, hostile), name, name)
    assert structure(section) == structure(report.render_comparison(compare(plain, plain), "plain", "plain"))
    assert github_links(section) == [], name


def test_the_golden_reports_link_nothing_github_would_link_by_itself():
    """The runner's own labels (`minimal_memory_/gc #2`: its thread with index 2) once referenced issue 2."""
    for golden_file in os.listdir(GOLDEN):
        assert github_links(Path(GOLDEN, golden_file).read_text(encoding="utf-8")) == [], golden_file


def unescaped_pipes(line: str) -> int:
    """The `|` of a table row that split it into cells: those not escaped by a backslash (GFM escapes them so in code spans too)."""
    count, i = 0, 0
    while i < len(line):
        if line[i] == "\\":
            i += 2
            continue
        count += line[i] == "|"
        i += 1
    return count


def table_rows_off_their_header(markdown: str) -> list[tuple[str, str]]:
    """Each table row (with its header) whose count of cell-splitting `|` is not its header's: a name that split a cell."""
    out = []
    header = None
    for line in markdown.splitlines():
        if not line.startswith("|"):
            header = None
        elif header is None:
            header = line
        elif unescaped_pipes(line) != unescaped_pipes(header):
            out.append((header, line))
    return out


def test_every_table_row_has_as_many_cells_as_its_header_whatever_the_names():
    """A `|` in a phase's name, a lock holder's or a thread rule split their rows: those cells were escaped for text, not tables."""
    from runner.report.compare import compare
    from runner.results.document import EventResult, Holder, PhaseResult
    from runner.results.threadfigures import Spread

    name = "a|b"
    doc = _hostile_doc(name, cells=2)
    for cell in doc.cells:
        t = next(t for t in cell.threads if t.periodic)
        lock = EventResult(
            phase=f"phase {name}",
            index=0,
            event=f"lock m{name}",
            kind="lock",
            measures="wait",
            count=3,
            spread_ns=Spread(min=1, p50=2, p90=3, p99=4, p999=5, max=6),
            contended=1,
            holders=[Holder(thread=f"holder {name}", contentions=1, wait_ns=1_000)],
        )
        phase = PhaseResult(name=f"phase {name}", passes=2, time_ns=1_000_000, cpus_seen=[0])
        cell.threads[cell.threads.index(t)] = t.model_copy(
            update={"program": True, "rule": f"rule*{name}", "rule_after_ns": 1_000, "events": [lock], "phases": [phase]}
        )
    text = report.render_run(doc) + report.render_comparison(compare(doc, doc), name, name)
    assert table_rows_off_their_header(text) == []
    assert "phase a\\|b" in text and "holder a\\|b" in text and "`rule*a\\|b`" in text  # the tables are there, escaped
    for golden_file in os.listdir(GOLDEN):  # and the reports the golden files hold
        assert table_rows_off_their_header(Path(GOLDEN, golden_file).read_text(encoding="utf-8")) == [], golden_file


@pytest.mark.parametrize("name", ["$\\foo$", "_hidden", "a\nb", "线程", "<b>x</b>", "$x^2", "\\"])
def test_plots_draw_any_name(tmp_path, name):
    doc = renamed(str(tmp_path / "run"), [(name, name)] * 2, cell_ids=[f"v={name}", f"v={name}2", "c", "d", "e"])
    path = write_report(doc, str(tmp_path / "run"))
    assert os.path.exists(path)
    svgs = [n for n in os.listdir(tmp_path / "run" / "plots") if n.endswith(".svg")]
    assert len(svgs) == 5  # the renamed thread and the recorded one, two plots each, and the aggregate latency plot


def _errored_with_a_thread_of_its_own(folder: str):
    """The recorded matrix in `folder`, its first cell an error in which no callback ran, of a thread no other cell has."""
    import shutil

    from reportdata import main_thread

    from runner.results.document import Status

    shutil.copytree(MATRIX, folder)
    doc = report_load(folder)
    cell = doc.cells[0]
    i = cell.threads.index(main_thread(cell))
    t = cell.threads[i]
    cell.threads[i] = t.model_copy(update={"name": "only_here", "figures": t.figures.model_copy(update={"callbacks": 0})})
    cell.status, cell.reason, doc.status = Status.ERROR, "worker crashed", "error"
    doc.save(os.path.join(folder, "results.json"))
    return report_load(folder)


def test_a_thread_only_a_cell_without_callbacks_has_is_not_plotted(tmp_path, capsys):
    """Its key came from every cell, the plotted cells were those with callbacks: no entry, and entries[0] crashed the report."""
    from runner.report.plots import write_plots

    doc = _errored_with_a_thread_of_its_own(str(tmp_path / "run"))
    drawn = write_plots(doc, str(tmp_path / "run"), report.thread_labels(doc.cells))
    assert drawn and not any("only_here" in p.title for p in drawn)
    text = Path(write_report(doc, str(tmp_path / "run"))).read_text(encoding="utf-8")
    assert "Plots skipped" not in text and "warning" not in capsys.readouterr().err


def test_a_plot_that_fails_to_draw_costs_neither_the_report_nor_the_junit_file(tmp_path, monkeypatch, capsys):
    """A failure in the plots raised out of `finish` before JUnit was written: CI got exit 70 and no report, no JUnit."""
    from runner.report import plots
    from runner.report.publish import finish

    def broken(*args: object, **kwargs: object) -> list[report.Plot]:
        raise IndexError("list index out of range")

    monkeypatch.setattr(plots, "write_plots", broken)
    folder = tmp_path / "run"
    folder.mkdir()
    junit = tmp_path / "junit.xml"
    assert finish(matrix(), str(folder), None, [], True, True, {}, junit=str(junit)) == 0
    text = (folder / "report.md").read_text(encoding="utf-8")
    assert "Plots skipped: drawing them failed (a bug in the runner, please report it: IndexError: list index out of range)" in text
    assert junit.exists() and "<testsuites" in junit.read_text()
    assert "warning: Plots skipped: drawing them failed" in capsys.readouterr().err


# ---------------------------------------------------------------- plots that do not grow with threads


def test_a_cell_of_many_threads_draws_two_plots_and_names_the_threads_it_shows(tmp_path):
    from reportdata import many_threads

    doc = many_threads(str(tmp_path / "run"), threads=48, processes=4, callbacks=40)
    text = Path(write_report(doc, str(tmp_path / "run"))).read_text(encoding="utf-8")
    assert sorted(os.listdir(tmp_path / "run" / "plots")) == ["threads.involuntary.svg", "threads.latency.svg"]
    body = (tmp_path / "run" / "plots" / "threads.latency.svg").read_text()
    shown = report.threads_of_interest(doc.cells)
    assert len(shown) == report.MAX_THREAD_VIEWS
    labels = report.thread_labels(doc.cells)
    assert all(labels[key] in body for key in shown) and "all 48 periodic threads" in body
    assert "4 of 48 periodic threads" in text
    assert len(tables(text)[1]) == 48 + 1  # every thread is still in the cell's tables


def test_a_matrix_of_many_threads_draws_a_fixed_number_of_plots(tmp_path):
    from reportdata import many_threads

    doc = many_threads(str(tmp_path / "run"), threads=24, processes=3, callbacks=20, cells=2)
    text = Path(write_report(doc, str(tmp_path / "run"))).read_text(encoding="utf-8")
    names = sorted(os.listdir(tmp_path / "run" / "plots"))
    assert len(names) == 2 * report.MAX_THREAD_VIEWS + 1 and "all-threads.latency.svg" in names
    assert text.count(" across cells\n") == report.MAX_THREAD_VIEWS
    assert f"the {report.MAX_THREAD_VIEWS} periodic threads with the highest wake-up p99, of 24" in text


def test_threads_of_interest_are_the_worst_by_wake_up_p99():
    from reportdata import with_figures

    doc = matrix()
    assert report.threads_of_interest(doc.cells) == [main_key := doc.cells[0].threads[0].key]
    worse = with_figures(doc, "policy=rr,priority=10", latency_p99=9_000_000)
    assert report.threads_of_interest(worse.cells, most=1) == [main_key]


def test_latency_bins_are_osadls_fixed_width_from_zero_counted_at_the_upper_end():
    from runner.histogram import from_values
    from runner.report.plots import osadl_bins

    a, b = from_values([1_000, 1_400, 2_600, 150_000]), from_values([3_000_000])
    assert a is not None and b is not None
    edges, counts = osadl_bins([a, b])
    width = edges[1]
    assert edges[0] == 0 and width == 20 and all(abs(y - x - width) < 1e-9 for x, y in itertools.pairwise(edges))
    assert len(counts[0]) == len(edges) - 1 <= 200 and [sum(c) for c in counts] == [4, 1]
    assert counts[0][0] == 3 and counts[0][150 // 20] == 1  # 150 µs, a 1.2-µs-wide native bucket, at its upper end
    assert counts[1][-1] == 1  # the largest value lands in the last bin
    edges, counts = osadl_bins([a])
    assert edges[1] == 1 and counts[0][1] == 2 and counts[0][2] == 1  # up to 150 µs: bins of 1 µs, as cyclictest -h
    for odd in (from_values([2**62]), from_values([-3_000])):  # a hand-edited results file: no crash, at most 200 bins
        assert odd is not None
        edges, counts = osadl_bins([odd])
        assert len(counts[0]) == len(edges) - 1 <= 201 and sum(counts[0]) == 1


def test_plot_lines_never_share_a_colour_and_style():
    from runner.report.plots import MAX_SERIES, style

    looks = [tuple(sorted(style(i).items())) for i in range(40)]
    assert len(set(looks)) == 40 >= MAX_SERIES


def test_the_readme_names_the_plots_extra_in_the_words_of_the_skipped_note():
    from runner.report.plots import PLOTS_EXTRA_INSTALL, skipped_note

    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text(encoding="utf-8")
    assert f"`{PLOTS_EXTRA_INSTALL}`" in readme and f"`{PLOTS_EXTRA_INSTALL}`" in skipped_note()


def test_plots_skipped_without_matplotlib_say_so_and_no_plots_says_nothing(tmp_path, monkeypatch, capsys):
    from runner.report import plots

    monkeypatch.setattr(plots, "available", lambda: False)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    text = Path(write_report(matrix(), str(tmp_path / "a"))).read_text(encoding="utf-8")
    assert "Plots skipped: matplotlib is not installed (plotting is the plots extra, `pip install '.[plots]'` in runner's clone" in text
    assert "`pip install 'matplotlib>=3.7'` into its environment" in text  # installed otherwise (pipx, a wheel)
    assert not (tmp_path / "a" / "plots").exists() and "![" not in text
    assert "warning: Plots skipped" in capsys.readouterr().err
    text = Path(write_report(matrix(), str(tmp_path / "b"), plots=False)).read_text(encoding="utf-8")
    assert "## Plots" not in text and "skipped" not in text


def test_the_core_import_path_imports_no_plotting_and_no_numpy():
    """`runner --version` and `runner validate` load neither matplotlib nor numpy (nor the report's jinja2, nor tabulate)."""
    import subprocess
    import sys

    code = (
        "import sys, runner.cli; version = set(sys.modules); "
        "import runner.scenario.loader, runner.scenario.listing; "
        "heavy = ('matplotlib', 'numpy', 'jinja2', 'tabulate', 'pydantic'); "
        "print(sorted(m for m in version if m.split('.')[0] in heavy)); "
        "print(sorted({m.split('.')[0] for m in sys.modules} & set(heavy))); "
        "print('runner.scenario.rtapp' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd="/")
    # tabulate (with wcwidth and importlib.metadata, about 50 ms) only when a listing is printed, rt-app's converter for rt-app files
    assert done.stdout.splitlines() == ["[]", "[]", "False"], done.stdout


def test_validate_imports_no_pydantic_and_builds_no_results_record(tmp_path):
    """`runner validate` checks a scenario with the scenario's own models: pydantic (the results' records, about
    130 ms of a start to import and build) waits for a command that measures or reads results, and hashlib for one
    that needs a cell's spec hash."""
    import subprocess
    import sys

    from conftest import SCENARIOS

    files = [os.path.join(SCENARIOS, name) for name in ("policy_matrix.yaml", "phases.yaml")]
    code = (
        "import io, sys, contextlib, runner.cli\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    code = runner.cli.main(['validate', *{files!r}])\n"
        "late = ('pydantic', 'pydantic_core', 'hashlib')  # hashlib: OpenSSL's 5 ms, for spec hashes a run needs\n"
        "print(code, sorted(m for m in sys.modules if m.split('.')[0] in late or m.startswith('runner.results')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert done.stdout.splitlines() == ["0 []"], done.stdout


def test_preemption_lines_name_who_preempted_and_for_periodic_threads_which_callbacks():
    """A periodic thread runs only in its callbacks: its line says how many were preempted before who did it."""
    from runner.results.document import Preemptor

    cell = matrix().cells[-1]  # the OTHER cell: its callbacks were preempted
    t = next(t for t in cell.threads if t.periodic)
    f = t.figures.model_copy(update={"preemptions": 146})
    by = [Preemptor(comm="hog", tid=41, pid=41, cls="TS", count=100), Preemptor(comm="ksoftirqd/1", tid=9, cls="TS", count=40)]
    late = [Preemptor(comm="hog", tid=41, pid=41, cls="TS", count=1)]
    periodic = t.model_copy(update={"figures": f, "preempted_by": by, "late_wakeups": 1, "late_wakeups_by": late})
    hit, calls = f.involuntary.callbacks_with_any, f.callbacks
    assert hit and calls
    assert report.preemption_lines([("p/main", periodic)]) == [
        f"p/main: {hit:,} of {calls:,} callbacks preempted, preempted 146 times: 100 by hog[41] (TS), 40 by ksoftirqd/1[9] (TS), "
        "6 by others; its 1 worst wake-up beyond p99 waited: 1 behind hog[41] (TS)"
    ]
    sleeper = periodic.model_copy(update={"periodic": False, "late_wakeups": 0, "late_wakeups_by": []})
    assert report.preemption_lines([("p/idle", sleeper)]) == [
        "p/idle: preempted 146 times: 100 by hog[41] (TS), 40 by ksoftirqd/1[9] (TS), 6 by others"
    ]
    never = sleeper.model_copy(update={"figures": f.model_copy(update={"preemptions": 0}), "preempted_by": []})
    untraced = sleeper.model_copy(update={"figures": f.model_copy(update={"preemptions": None})})
    assert report.preemption_lines([("p/a", never), ("p/b", untraced)]) == ["p/a: never preempted"]


def test_preemption_lines_end_with_the_most_preempted_callbacks_and_who_held_the_cpu():
    from runner.results.document import PreemptedRun, Preemptor

    cell = matrix().cells[-1]
    t = next(t for t in cell.threads if t.periodic)
    hog = Preemptor(comm="hog", tid=41, pid=41, cls="TS", count=5)
    rt = Preemptor(comm="irq/24", tid=7, cls="FF", rtprio=50, count=1)
    runs = [
        PreemptedRun(at_ns=100_066_000, wall_ns=88_000_000, preempted_ns=48_000_000, preemptions=9, by=hog, by_ns=31_980_000),
        PreemptedRun(at_ns=800_000_000, wall_ns=2_500_000, preempted_ns=40_000, preemptions=1, by=rt, by_ns=40_000),
        PreemptedRun(at_ns=900_000_000, wall_ns=2_000_000, preempted_ns=30_000, preemptions=1, by=rt, by_ns=30_000),
        PreemptedRun(at_ns=950_000_000, wall_ns=2_000_000, preempted_ns=20_000, preemptions=1, by=rt, by_ns=20_000),
    ]
    f = t.figures.model_copy(update={"preemptions": 12})
    line = report.preemption_lines([("p/main", t.model_copy(update={"figures": f, "preempted_by": [hog], "preempted_runs": runs}))])[0]
    assert line.endswith(
        "; most preempted callbacks: at 0.100 s: 48.0 of 88.0 ms preempted, 9 times, 5 by hog[41] (TS) for 32.0 ms; "
        "at 0.800 s: 40 of 2,500 µs preempted, 1 time, 1 by irq/24[7] (FF 50) for 40 µs; "
        "at 0.900 s: 30 of 2,000 µs preempted, 1 time, 1 by irq/24[7] (FF 50) for 30 µs"
    ), line
    sleeper = t.model_copy(update={"periodic": False, "figures": f, "preempted_runs": runs[:1]})
    assert "; most preempted runs: at 0.100 s" in report.preemption_lines([("p/idle", sleeper)])[0]


def test_a_programs_command_line_is_written_as_a_shell_would_read_it_back():
    """`["sh", "-c", "a b", ""]` was written `sh -c a b `: neither the argument boundaries nor the empty one showed."""
    from runner.report.markdown import program_lines
    from runner.results.document import CellResult, ProgramResult, Status
    from runner.scenario.plan import Settings

    program = ProgramResult(name="p", argv=["sh", "-c", "echo 'hi' $HOME", ""], path="/bin/sh", started=True, requested=Settings())
    cell = CellResult(id="c", spec_hash="-", status=Status.PASSED, started_at="now", programs=[program])
    assert "`sh -c 'echo '\"'\"'hi'\"'\"' $HOME' ''`" in program_lines(cell)[0]


# ---------------------------------------------------------------- the trace's latency, with its wake-ups


def _traced(wakeups: int):
    """The recorded matrix's first cell, its periodic thread traced: waking to running of `wakeups` wake-ups, 15 µs."""
    from reportdata import main_thread

    from runner.histogram import from_rows, index
    from runner.run.measure import spread

    doc = matrix()
    cell = doc.cells[0]
    t = main_thread(cell)
    wakeup = spread(from_rows([(index(15_000), wakeups)], 15_000, 15_000), 15_000.0, None, wakeups)
    figures = t.figures.model_copy(update={"wakeup_ns": wakeup, "preemptions": 0})
    cell.threads[cell.threads.index(t)] = t.model_copy(update={"figures": figures})
    return doc, cell, t.model_copy(update={"figures": figures})


def test_a_trace_figure_says_how_many_wake_ups_it_stands_on_in_results_report_and_terminal():
    """A DEADLINE thread's "p50/p99/max 15.0 us" came from 1 of its 20 wake-ups, and nothing said so."""
    from runner.figures import figure
    from runner.report.cellview import render_cell
    from runner.run.measure import check
    from runner.scenario.model import Expectation

    doc, cell, t = _traced(1)
    assert t.figures.wakeup_ns is not None and t.figures.wakeup_ns.count == 1
    verdict = check(Expectation.parse({"thread": "x", "metric": "wakeup.p99", "max": "1ms"}), "x", t.figures)
    assert verdict.passed and verdict.samples == 1 and verdict.figure == figure("wakeup.p99")
    cell.expectations = [verdict]
    text = report.render_run(doc)
    outside = next(tb for tb in tables(text) if any("Wake-ups traced" in c for c in tb[0]))
    head = outside[0]
    row = next(r for r in outside[1:] if r[head.index("Wake-ups traced")] != "–")
    assert row[head.index("Wake-ups traced")] == "1" and row[head.index("Waking to running p50 (µs)")] == "15.0"
    assert "| 15 (1 wake-up) |" in text, "the verdict's measured value with its wake-ups"
    assert "(measured 15.0 µs, of 1 wake-up)" in render_cell(cell)
    assert "does not compare with the runner's own threads' wake-up latency" in text


def test_spreads_keep_their_count_and_older_files_without_it_read_as_unknown():
    from runner.results.threadfigures import Spread

    _, _, t = _traced(20)
    assert t.figures.wakeup_ns is not None and t.figures.wakeup_ns.count == 20
    assert t.figures.latency_ns is not None and t.figures.latency_ns.count is None  # recorded before the count was kept
    assert Spread.model_validate({"min": 1, "p50": 1, "p90": 1, "p99": 1, "p999": 1, "max": 1}).count is None


def test_a_deadline_thread_is_reported_with_its_runtime_deadline_and_period_as_the_terminal_says_them():
    """The report said only "DEADLINE" where the terminal says deadline 2ms/8ms/10ms (issue 40, 15)."""
    from runner.scenario.model import Policy
    from runner.scenario.plan import Settings

    dl = Settings(Policy.DEADLINE, runtime=2_000_000, deadline=8_000_000, period=10_000_000)
    assert report.policy_label(dl) == "DEADLINE 2ms/8ms/10ms"
    assert dl.label() == "deadline 2ms/8ms/10ms"
    assert report.policy_label(Settings(Policy.FIFO, 80)) == "FIFO 80"


def test_the_trace_line_says_how_many_wake_ups_it_could_not_measure():
    """On this VM's CPU 1 the kernel traces no switch out of idle: a 1 kHz loop there showed 14 wake-ups traced of 1,000
    and nothing said where the others went."""
    from types import SimpleNamespace

    from runner.results.document import TraceInfo

    cell = SimpleNamespace(trace=TraceInfo(enabled=True, events=5_000, unseen_switch_ins=986, reader_cpu_ns=2_000_000))
    line = report.trace_line(cell)  # type: ignore[arg-type]
    assert line is not None and "986 wake-ups unmeasured: the kernel traced no switch onto the CPU they ran on" in line
    cell = SimpleNamespace(trace=TraceInfo(enabled=True, events=5_000))
    assert "unmeasured" not in (report.trace_line(cell) or "")  # type: ignore[arg-type]
