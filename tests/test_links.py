"""Nothing the runner writes follows a link it did not make (issue 40, item 4).

A results folder may be a downloaded artifact: every link planted in it (a report.md, a plots
folder, a dangling results.json or lock) is refused with exit 2, and what it names is untouched,
the run, `report`, `merge` and every option's file alike (docs/permissions.md, "Files the runner writes").
Links above the folder a user names are theirs, and followed.
"""

from __future__ import annotations

import ast
import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import run_cli
from reportdata import MATRIX, matrix

from runner import outdir
from runner.errors import UsageError
from runner.results.samplesfile import SamplesWriter
from runner.run.output import CappedOutput

RUNNER = Path(__file__).resolve().parent.parent / "runner"


@pytest.fixture
def artifact(tmp_path: Path) -> Path:
    """A downloaded results folder (the recorded policy matrix run, samples and all)."""
    folder = tmp_path / "artifact"
    shutil.copytree(MATRIX, folder)
    for leftover in ("report.md", "plots"):  # as a run leaves it, before `runner report`
        path = folder / leftover
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    return folder


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A file elsewhere that a planted link names: it must stay as it is."""
    path = tmp_path / "elsewhere" / "precious"
    path.parent.mkdir()
    path.write_text("keep me\n")
    return path


def _untouched(victim: Path) -> None:
    assert victim.read_text() == "keep me\n" and sorted(os.listdir(victim.parent)) == [victim.name], os.listdir(victim.parent)


def test_report_refuses_a_report_md_link_and_leaves_its_target(artifact, victim):
    (artifact / "report.md").symlink_to(victim)
    done = run_cli("report", str(artifact), "--no-plots")
    assert done.code == 2 and "Traceback" not in done.err, done.err
    assert f"{artifact / 'report.md'}: a symbolic link, which the runner never writes through" in done.err
    _untouched(victim)
    assert (artifact / "report.md").is_symlink()


def test_report_writes_no_plot_into_the_folder_a_plots_link_names(artifact, victim):
    (artifact / "plots").symlink_to(victim.parent)
    done = run_cli("report", str(artifact))
    assert done.code == 2 and "Traceback" not in done.err, done.err
    assert f"{artifact / 'plots'}: a symbolic link" in done.err
    _untouched(victim)
    assert "a symbolic link, which the runner never writes through" in (artifact / "report.md").read_text()  # written, saying why


def test_report_of_a_folder_is_written_there_not_where_its_results_json_link_leads(artifact, tmp_path):
    """doc.folder is where results.json really is: a link to another folder's once put report.md and plots there."""
    other = tmp_path / "other"
    other.mkdir()
    (artifact / "results.json").rename(other / "results.json")
    (artifact / "results.json").symlink_to(other / "results.json")
    shutil.copytree(artifact / "cells", other / "cells")
    done = run_cli("report", str(artifact))
    assert done.code == 0, done.err
    assert (artifact / "report.md").is_file() and (artifact / "plots").is_dir()
    assert sorted(os.listdir(other)) == ["cells", "results.json"]


@pytest.mark.parametrize("name", ["results.json", "cells.jsonl", ".runner.lock", "report.md", "comparison.md", "plots", "cells"])
def test_a_run_or_merge_refuses_a_folder_holding_a_link_where_it_writes(tmp_path, victim, name):
    """A dangling results.json or .runner.lock link once had its target made by the run's first write."""
    out = tmp_path / "out"
    out.mkdir()
    target = victim.parent / "made-by-the-run"
    (out / name).symlink_to(target)
    for resume in (False, True):
        with pytest.raises(UsageError, match=f"holds {name}, a symbolic link, which the runner never writes through"):
            outdir.claim(str(out), resume=resume)
    assert not os.path.lexists(target) and sorted(os.listdir(out)) == [name]
    _untouched(victim)


def test_merge_refuses_a_link_inside_the_merged_folder_and_writes_nothing_through_it(tmp_path, victim):
    shard = tmp_path / "shard"
    shutil.copytree(MATRIX, shard)
    out = tmp_path / "merged"
    (out / "cells").mkdir(parents=True)
    first = matrix().cells[0]
    (out / os.path.dirname(first.samples_file)).symlink_to(victim.parent)  # cells/<id> -> elsewhere
    done = run_cli("merge", str(shard), "--out", str(out), "--no-plots")
    assert done.code == 2 and "a symbolic link, which the runner never writes through" in done.err, done.err
    _untouched(victim)


def test_a_link_to_the_run_folder_itself_is_the_users_and_followed(tmp_path):
    """--out through a symlinked home, or a link the user named as --out, is the user's choice."""
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "home").symlink_to(real)
    held = outdir.claim(str(tmp_path / "home" / "out"))
    try:
        assert (real / "out" / outdir.LOCK_NAME).is_file()
    finally:
        held.release()


def test_cell_folders_below_the_run_folder_are_never_links(tmp_path, victim):
    from runner import safefs

    root = tmp_path / "run"
    (root / "cells").mkdir(parents=True)
    (root / "cells" / "c1").symlink_to(victim.parent)
    with pytest.raises(OSError) as err:
        safefs.make_folders(str(root), "cells/c1/repeat-1")
    assert err.value.errno == errno.ELOOP and err.value.filename == str(root / "cells" / "c1")
    (root / "cells" / "c2").write_text("")
    with pytest.raises(OSError) as err:
        safefs.make_folders(str(root), "cells/c2")
    assert err.value.errno == errno.ENOTDIR
    assert safefs.make_folders(str(root), "cells/c3/repeat-2") == str(root / "cells" / "c3" / "repeat-2")
    _untouched(victim)


def test_a_samples_file_that_is_a_link_is_refused_and_no_temporary_file_is_left(tmp_path, victim):
    (tmp_path / "samples.csv.gz").symlink_to(victim)
    writer = SamplesWriter(str(tmp_path / "samples.csv.gz"))
    writer.writerows([["t", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, "", 0, ""]])
    with pytest.raises(OSError) as err:
        writer.close()
    assert err.value.errno == errno.ELOOP
    assert sorted(os.listdir(tmp_path)) == ["elsewhere", "samples.csv.gz"]
    _untouched(victim)


def test_a_program_output_or_log_that_is_a_link_is_refused(tmp_path, victim):
    (tmp_path / "prog.stdout").symlink_to(victim)
    with pytest.raises(OSError) as err:
        CappedOutput(str(tmp_path / "prog.stdout"), 1 << 20)
    assert err.value.errno == errno.ELOOP
    _untouched(victim)


def test_a_file_of_several_names_is_not_truncated_nor_written_into(tmp_path, victim):
    """A hard link in an unpacked archive is as bad as a symbolic one, as root: the same file under another name."""
    os.link(victim, tmp_path / "prog.stdout")
    with pytest.raises(OSError, match="a file of 2 names"):
        CappedOutput(str(tmp_path / "prog.stdout"), 1 << 20)
    _untouched(victim)


@pytest.mark.parametrize(
    "argv",
    [
        ["report", "{run}", "-o", "{link}"],
        ["report", "{run}", "--histogram", "{link}", "--cell", "{cell}"],
        ["report", "{run}", "--json", "{link}", "--cell", "{cell}"],
        ["report", "{run}", "--hdr", "{link}", "--cell", "{cell}"],
        ["report", "{run}", "--kcidb", "{link}"],
        ["compare", "{run}", "{run}", "-o", "{link}"],
        ["compare", "{run}", "{run}", "--junit", "{link}"],
        ["merge", "{run}", "--out", "{out}", "--junit", "{link}", "--no-plots"],
        ["import-rtapp", "{rtapp}", "-o", "{link}"],
    ],
    ids=lambda argv: " ".join(a for a in argv if not a.startswith("{")),
)
def test_a_file_named_on_the_command_line_is_never_written_through_a_link(tmp_path, artifact, victim, argv):
    """cp follows a link named as its destination; the runner does not: as root it would overwrite any file a planted link names."""
    words = {
        "run": str(artifact),
        "link": str(tmp_path / "out.file"),
        "out": str(tmp_path / "merged"),
        "cell": matrix().cells[0].id,
        "rtapp": os.path.join(os.path.dirname(__file__), "rtapp", "example2.json"),
    }
    for target in (victim, tmp_path / "dangling"):
        (tmp_path / "out.file").unlink(missing_ok=True)
        (tmp_path / "out.file").symlink_to(target)
        done = run_cli(*[a.format(**words) for a in argv])
        assert done.code == 2 and "Traceback" not in done.err, done.err
        assert f"{tmp_path / 'out.file'}: a symbolic link, which the runner never writes through" in done.err, done.err
        assert not (tmp_path / "dangling").exists()
        _untouched(victim)


def test_standard_output_named_as_a_file_is_still_written_into(tmp_path, artifact):
    """/dev/stdout is a link (to /proc/self/fd/1): the runner's own descriptor, the one link it writes through."""
    argv = ["compare", str(artifact), str(artifact), "--junit", "/dev/stdout"]
    code = f"from runner.cli import main; raise SystemExit(main({argv!r}))"
    with open(tmp_path / "log", "w") as log:
        done = subprocess.run([sys.executable, "-c", code], stdout=log, stderr=subprocess.PIPE, text=True, timeout=120, cwd="/")
    assert done.returncode == 0, done.stderr
    assert "<testsuites" in (tmp_path / "log").read_text()


def test_a_step_summary_that_is_a_link_is_warned_of_and_not_written(artifact, victim, monkeypatch):
    link = victim.parent.parent / "summary.md"
    link.symlink_to(victim)
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(link))
    done = run_cli("compare", str(artifact), str(artifact))
    assert done.code == 0 and f"cannot append to GITHUB_STEP_SUMMARY {link}: a symbolic link" in done.err, done.err
    _untouched(victim)


def _write_opens(tree: ast.AST) -> list[int]:
    """Lines of open() calls for writing, and of os.open() calls for writing that do not say O_NOFOLLOW."""
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name, text = ast.unparse(node.func), ast.unparse(node)
        mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
        writes = mode is not None and not (isinstance(mode, ast.Constant) and not any(c in str(mode.value) for c in "wax+"))
        raw = name == "os.open" and any(f in text for f in ("O_WRONLY", "O_RDWR", "O_CREAT")) and "O_NOFOLLOW" not in text
        if (name == "open" and writes) or raw:
            lines.append(node.lineno)
    return lines


def test_no_module_opens_a_file_for_writing_without_refusing_links():
    """The rule of runner/safefs.py, kept: every write goes through it, or opens with O_NOFOLLOW itself."""
    found = []
    for path in sorted(RUNNER.rglob("*.py")):
        if path.name == "safefs.py":
            continue
        found += [f"{path.relative_to(RUNNER.parent)}:{line}" for line in _write_opens(ast.parse(path.read_text(), str(path)))]
    assert not found, found
