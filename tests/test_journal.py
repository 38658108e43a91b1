"""results.json and its journal: every finished cell on disk at once, at a cost that stays linear in the run.

The policy is pure and tested by arithmetic; the store and the reader with real files; the
session with the fake backend, including a runner that dies between two rewrites.
"""

from __future__ import annotations

import errno
import json
import os

import pytest
from fakebackend import Act, Died, FakeBackend
from test_session import FIFO_CELLS, MATRIX, OTHER, preempted_other, run

from runner import outdir
from runner.cli import _run_parser
from runner.errors import ScenarioError, UsageError
from runner.results import document, journal, read, samplesfile
from runner.results.document import CellResult, RunDocument
from runner.results.journal import JOURNAL, REWRITE_BELOW, ResultsStore, rewrite_due
from runner.results.read import load
from runner.scenario.loader import load_scenario
from runner.session import RunOptions, run_scenario

CELL_BYTES = 34_000  # a policy_matrix cell as results.json holds it


def _simulate(cells: int, header: int = 8_000) -> tuple[int, int, int]:
    """Bytes a run of `cells` writes under the policy: results.json rewrites, the journal, and the final file's size."""
    saved, pending, rewritten, journaled = header, 0, header, 0
    for n in range(1, cells + 1):
        if rewrite_due(saved, pending):
            saved, pending = header + n * CELL_BYTES, 0
            rewritten += saved
        else:
            pending += CELL_BYTES
            journaled += CELL_BYTES
    final = header + cells * CELL_BYTES
    return rewritten + final, journaled, final


def test_small_results_are_rewritten_after_every_cell():
    assert rewrite_due(REWRITE_BELOW - 1, 1)
    assert not rewrite_due(REWRITE_BELOW, REWRITE_BELOW - 1)
    assert rewrite_due(REWRITE_BELOW, REWRITE_BELOW)


@pytest.mark.parametrize("cells", [1_000, 10_000])
def test_what_a_large_matrix_writes_grows_linearly_with_its_cells(cells):
    rewritten, journaled, final = _simulate(cells)
    # every cell rewritten whole would write about cells / 2 times the final file (17 GB for 1,000 cells)
    assert rewritten + journaled < 5 * final + 30 * REWRITE_BELOW


def _cell(n: int) -> CellResult:
    return CellResult(id=f"c{n}", spec_hash="h", status="passed")


def _doc_with(store: ResultsStore, cells: int) -> RunDocument:
    doc = RunDocument()
    store.begin(doc)
    for n in range(cells):
        doc.cells.append(_cell(n))
        store.add(doc, doc.cells[-1])
    return doc


def test_results_json_is_indented_while_small_and_one_line_beyond(tmp_path, monkeypatch):
    doc = RunDocument(cells=[_cell(n) for n in range(40)])
    path = str(tmp_path / "results.json")
    small = doc.save(path)
    with open(path) as handle:
        assert handle.read().count("\n") > 40  # indented: one line per key at least
    assert load(path).cells == doc.cells
    monkeypatch.setattr(document, "INDENT_BELOW", small // 2)
    large = doc.save(path)
    with open(path) as handle:
        text = handle.read()
    assert text.count("\n") == 1 and text.endswith("}\n")
    assert large < small
    assert load(path).cells == doc.cells


def test_a_reader_sees_journaled_cells_that_results_json_does_not_hold_yet(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)  # rewrite only at doubling, as a large run does
    store = ResultsStore(str(tmp_path / "results.json"))
    _doc_with(store, 6)
    on_disk = json.loads((tmp_path / "results.json").read_text())
    assert len(on_disk["cells"]) < 6, "the policy never skipped a rewrite: this test proves nothing"
    assert [c.id for c in load(str(tmp_path)).cells] == [f"c{n}" for n in range(6)]


def test_finishing_writes_every_cell_and_removes_the_journal(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    store = ResultsStore(str(tmp_path / "results.json"))
    doc = _doc_with(store, 2)
    assert (tmp_path / JOURNAL).exists()
    store.finish(doc)
    assert not (tmp_path / JOURNAL).exists()
    assert [c["id"] for c in json.loads((tmp_path / "results.json").read_text())["cells"]] == ["c0", "c1"]


def test_keys_a_newer_runner_adds_to_a_journal_line_are_tolerated_and_dropped(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    _doc_with(ResultsStore(str(tmp_path / "results.json")), 1)
    line = json.loads(_cell(1).model_dump_json())
    line["energy_uj"] = 7
    line["overhead_ns"]["gc_ns"] = 3
    with open(tmp_path / JOURNAL, "a") as handle:
        handle.write(json.dumps(line) + "\n")
    cells = load(str(tmp_path)).cells
    assert [c.id for c in cells] == ["c0", "c1"] and cells[1] == _cell(1)


def test_a_last_line_cut_short_is_the_cell_in_flight_and_left_out(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    _doc_with(ResultsStore(str(tmp_path / "results.json")), 3)
    with open(tmp_path / JOURNAL, "ab") as handle:
        handle.write(_cell(3).model_dump_json().encode()[:40])
    assert [c.id for c in load(str(tmp_path)).cells] == ["c0", "c1", "c2"]


@pytest.mark.parametrize("line", [2, 3], ids=["in the middle", "the last, whole JSON: no crash writes that"])
def test_a_damaged_journal_line_is_refused_with_its_place(tmp_path, monkeypatch, line):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    _doc_with(ResultsStore(str(tmp_path / "results.json")), 3)
    lines = (tmp_path / JOURNAL).read_text().splitlines(keepends=True)
    lines[line - 1] = lines[line - 1].replace('"status":"passed"', '"status":"splendid"')
    (tmp_path / JOURNAL).write_text("".join(lines))
    with pytest.raises(ScenarioError) as caught:
        load(str(tmp_path))
    text = str(caught.value)
    assert f"{tmp_path / JOURNAL}:{line}:1: status:" in text and "splendid" in text


@pytest.mark.parametrize(
    ("tail", "said"),
    [
        (lambda cell: cell[: len(cell) // 2] + b"\n", "cell 'c3'"),  # the line's start reached the disk, and a newline after it
        (lambda cell: b"\0" * len(cell) + b"\n", "a cell whose id cannot be read"),  # its blocks allocated, never written
        (lambda cell: b"\n", "a cell whose id cannot be read"),
    ],
    ids=["half a line", "zeros", "an empty line"],
)
def test_a_damaged_last_line_ending_in_a_newline_is_left_out_with_a_warning(tmp_path, monkeypatch, capsys, tail, said):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    _doc_with(ResultsStore(str(tmp_path / "results.json")), 3)
    with open(tmp_path / JOURNAL, "ab") as handle:
        handle.write(tail(_cell(3).model_dump_json(by_alias=True).encode()))
    assert [c.id for c in load(str(tmp_path)).cells] == ["c0", "c1", "c2"]
    warning = capsys.readouterr().err
    assert warning.startswith(f"runner: warning: {tmp_path / JOURNAL}:4: the last line is damaged (not valid JSON"), warning
    assert f"left out: {said}, which runs again when the run is resumed (--resume)" in warning and warning.count("\n") == 1


def test_a_damaged_line_before_the_last_is_refused_saying_what_to_do(tmp_path, monkeypatch):
    """A torn line then a whole one: the torn one was not the last written, so no crash explains it."""
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    _doc_with(ResultsStore(str(tmp_path / "results.json")), 2)
    cell = _cell(2).model_dump_json(by_alias=True).encode()
    with open(tmp_path / JOURNAL, "ab") as handle:
        handle.write(cell[:30] + b"\n" + cell[:30])
    with pytest.raises(ScenarioError) as caught:
        load(str(tmp_path))
    text = str(caught.value)
    assert text.startswith(f"{tmp_path / JOURNAL}:3:") and "not valid JSON" in text and "\n" not in text
    assert "delete the line and resume the run (--resume)" in text


def test_a_cell_whose_journal_line_was_damaged_runs_again_on_resume(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    out = tmp_path / "r"
    acts = preempted_other()
    with pytest.raises(Died):
        run(MATRIX, out, FakeBackend({**acts, FIFO_CELLS[3]: Act(dies=True)}))
    lines = (out / JOURNAL).read_bytes().splitlines(keepends=True)
    assert lines[-1].startswith(b'{"id":' + json.dumps(FIFO_CELLS[2]).encode()), "the third cell not journaled: this test proves nothing"
    (out / JOURNAL).write_bytes(b"".join(lines[:-1]) + lines[-1][:50] + b"\n")  # the third cell's line, damaged
    backend = FakeBackend(acts)
    ns = _run_parser().parse_args([MATRIX, "--resume", str(out), "--quiet", "--no-plots"])
    code = run_scenario(load_scenario(MATRIX), RunOptions.from_namespace(ns, env={}), backend)
    assert code == 0 and backend.ran == FIFO_CELLS[2:] + [OTHER]
    assert f"left out: cell {FIFO_CELLS[2]!r}" in capsys.readouterr().err
    results = json.loads((out / "results.json").read_text())
    assert [c["id"] for c in results["cells"]] == FIFO_CELLS + [OTHER] and results["status"] == "passed"
    assert not (out / JOURNAL).exists()


def test_a_line_is_never_appended_to_a_torn_one(tmp_path, monkeypatch):
    """A write that failed and whose truncation failed too leaves a torn tail; the next line must start a line of its own."""
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    store = ResultsStore(str(tmp_path / "results.json"))
    doc = _doc_with(store, 2)
    real_write = os.write

    def half_then_full(fd: int, data: bytes) -> int:
        if len(data) > 20:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, "No space left on device")

    def cannot_truncate(fd: int, length: int) -> None:
        raise OSError(errno.EIO, "Input/output error")

    with monkeypatch.context() as failing:
        failing.setattr(journal.os, "write", half_then_full)
        failing.setattr(journal.os, "ftruncate", cannot_truncate)
        big = CellResult(id="c9", spec_hash="h", status="error", reason="x" * 300_000)  # torn past a chunk of the backward scan
        with pytest.raises(OSError):
            store.add(doc, big)
    assert not (tmp_path / JOURNAL).read_bytes().endswith(b"\n"), "no torn tail left: this test proves nothing"
    doc.cells.append(_cell(2))
    store.add(doc, doc.cells[-1])
    assert (tmp_path / JOURNAL).read_bytes().endswith(b"}\n" + _cell(2).model_dump_json(by_alias=True).encode() + b"\n")
    assert [c.id for c in load(str(tmp_path)).cells] == ["c0", "c1", "c2"]


def test_a_journal_of_cells_another_run_was_asked_for_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    store = ResultsStore(str(tmp_path / "results.json"))
    doc = RunDocument(cell_ids=["c0", "c1"])
    store.begin(doc)
    doc.cells.append(_cell(0))
    store.add(doc, doc.cells[-1])
    with open(tmp_path / JOURNAL, "ab") as handle:  # a journal copied from another scenario's folder
        handle.write((_cell(7).model_dump_json() + "\n").encode())
    with pytest.raises(ScenarioError) as caught:
        load(str(tmp_path))
    assert f"{tmp_path / JOURNAL}:2:1: cell 'c7' is not one" in str(caught.value)


def test_a_journal_that_is_a_fifo_or_a_device_is_refused_without_reading_it(tmp_path):
    RunDocument(cell_ids=["c0"]).save(str(tmp_path / "results.json"))
    os.mkfifo(tmp_path / JOURNAL)  # reading it would wait for a writer forever
    with pytest.raises(ScenarioError, match="is a FIFO, not a file"):
        load(str(tmp_path))
    os.unlink(tmp_path / JOURNAL)
    os.symlink("/dev/zero", tmp_path / JOURNAL)  # reading it would never end
    with pytest.raises(ScenarioError, match="is a character device, not a file"):
        load(str(tmp_path))


def test_a_write_that_fails_halfway_leaves_no_torn_line(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    store = ResultsStore(str(tmp_path / "results.json"))
    doc = _doc_with(store, 2)
    size = (tmp_path / JOURNAL).stat().st_size
    assert not rewrite_due(store.saved_bytes, store.pending_bytes), "the next cell would not be journaled"

    real_write = os.write

    def half_then_full(fd: int, data: bytes) -> int:
        if len(data) > 20:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(journal.os, "write", half_then_full)
    doc.cells.append(_cell(2))
    with pytest.raises(OSError) as caught:
        store.add(doc, doc.cells[-1])
    assert caught.value.filename == store.journal
    assert (tmp_path / JOURNAL).stat().st_size == size


def test_a_rewrite_empties_the_journal_and_a_small_run_never_keeps_one(tmp_path, monkeypatch):
    store = ResultsStore(str(tmp_path / "results.json"))
    _doc_with(store, 3)
    assert not (tmp_path / JOURNAL).exists(), "results.json under 64 KiB is rewritten after every cell"
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    doc = _doc_with(store, 30)
    assert len(json.loads((tmp_path / "results.json").read_text())["cells"]) + len((tmp_path / JOURNAL).read_text().splitlines()) == len(
        doc.cells
    ), "a cell is in results.json or the journal, never both, once results.json was rewritten"


def test_a_runner_that_dies_between_rewrites_loses_no_finished_cell_and_resumes_after_them(tmp_path, monkeypatch):
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    out = tmp_path / "r"
    acts = preempted_other()
    with pytest.raises(Died):
        run(MATRIX, out, FakeBackend({**acts, FIFO_CELLS[3]: Act(dies=True)}))
    on_disk = json.loads((out / "results.json").read_text())
    assert len(on_disk["cells"]) < 3, "results.json was rewritten after every cell: this test proves nothing"
    assert [c.id for c in load(str(out)).cells] == FIFO_CELLS[:3]
    backend = FakeBackend(acts)
    ns = _run_parser().parse_args([MATRIX, "--resume", str(out), "--quiet", "--no-plots"])
    code = run_scenario(load_scenario(MATRIX), RunOptions.from_namespace(ns, env={}), backend)
    assert code == 0 and backend.ran == [FIFO_CELLS[3], OTHER]
    results = json.loads((out / "results.json").read_text())
    assert [c["id"] for c in results["cells"]] == FIFO_CELLS + [OTHER] and results["status"] == "passed"
    assert not (out / JOURNAL).exists()


def test_a_reader_of_a_run_still_going_never_misses_cells_a_rewrite_moved(tmp_path, monkeypatch):
    """The run rewrites results.json (the journal's cells in it) and drops the journal between the reader's two reads."""
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    store = ResultsStore(str(tmp_path / "results.json"))
    doc = _doc_with(store, 6)
    assert (tmp_path / JOURNAL).exists(), "nothing journaled: this test proves nothing"
    opened: list[str] = []
    real_open = open

    def open_and_rewrite_between(path, *args, **kwargs):  # the reader's second file is opened after the runner's rewrite
        opened.append(os.path.basename(path))
        if len(opened) == 2:
            store.rewrite(doc)
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(read, "open", open_and_rewrite_between, raising=False)
    assert [c.id for c in load(str(tmp_path)).cells] == [f"c{n}" for n in range(6)]
    assert sorted(opened) == sorted([JOURNAL, "results.json"])


def test_a_results_json_or_journal_that_is_a_link_is_refused_and_what_it_names_untouched(tmp_path, monkeypatch):
    """The store once wrote the file a results.json link named, and its journal beside that file."""
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    (tmp_path / "kept").mkdir()
    (tmp_path / "run").mkdir()
    (tmp_path / "kept" / "results.json").write_text("{}")
    os.symlink(tmp_path / "kept" / "results.json", tmp_path / "run" / "results.json")
    with pytest.raises(OSError, match="symbolic link"):
        _doc_with(ResultsStore(str(tmp_path / "run" / "results.json")), 4)
    assert (tmp_path / "kept" / "results.json").read_text() == "{}" and os.listdir(tmp_path / "kept") == ["results.json"]
    (tmp_path / "run" / "results.json").unlink()
    os.symlink(tmp_path / "kept" / "journal", tmp_path / "run" / JOURNAL)  # dangling: an append would make its target
    store = ResultsStore(str(tmp_path / "run" / "results.json"))
    doc = RunDocument(cells=[_cell(0)])
    doc.save(store.results_path)
    store.saved_bytes = 1 << 20  # large: the next cell is a journal line
    with pytest.raises(OSError, match="symbolic link"):
        store.add(doc, doc.cells[0])
    assert os.listdir(tmp_path / "kept") == ["results.json"]


def test_a_folder_holding_a_journal_without_its_results_is_refused_unless_resumed(tmp_path):
    (tmp_path / JOURNAL).write_text(_cell(0).model_dump_json() + "\n")  # a run's results.json was deleted; its cells were not
    with pytest.raises(UsageError, match="holds the cells journal"):
        outdir.claim(str(tmp_path))
    outdir.claim(str(tmp_path), resume=True).release()


class _DefectAfterTheCell(FakeBackend):
    """Writes the cell's samples, then fails as a defect would (no OSError): nothing the run began may be left behind."""

    def run_cell(self, cell, folder, start, options):
        super().run_cell(cell, folder, start, options)
        raise RuntimeError("a defect after the cell ran")


def test_a_defect_during_a_cell_leaves_no_half_written_samples_file(tmp_path):
    out = tmp_path / "r"
    with pytest.raises(RuntimeError, match="a defect"):
        run(MATRIX, out, _DefectAfterTheCell(preempted_other()))
    cells = [p for p in out.rglob("*") if p.is_file() and "cells" in p.parts]
    assert not [p for p in cells if p.name.endswith(".tmp")], cells


def test_new_names_are_synced_with_their_folders_as_results_json_is(tmp_path, monkeypatch):
    """A power cut must not leave results.json naming a samples file or a journal whose folder entry never reached the disk."""
    synced: list[str] = []
    monkeypatch.setattr(samplesfile, "sync_folder", synced.append)
    monkeypatch.setattr(journal, "sync_folder", synced.append)
    cell = tmp_path / "cells" / "c0"
    cell.mkdir(parents=True)
    writer = samplesfile.SamplesWriter(str(cell / "samples.csv.gz"))
    writer.close()
    assert synced == [str(cell), str(tmp_path / "cells")]
    synced.clear()
    monkeypatch.setattr(journal, "REWRITE_BELOW", 0)
    _doc_with(ResultsStore(str(tmp_path / "results.json")), 3)
    assert synced == [str(tmp_path)], "the journal's folder once, when the journal was made"
