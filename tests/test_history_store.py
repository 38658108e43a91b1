"""The history's store: nights in and series out, two writers at once, and every bad file refused with its exit code.

The same tests run on SQLite (a file) and on PostgreSQL when a server is given (RUNNER_TEST_POSTGRES_URL; .ci/run
starts one): skipped with their reason outside CI, a failure in CI.
"""

from __future__ import annotations

import copy
import multiprocessing
import os
import sqlite3
import uuid

import pytest
from reportdata import latencies, main_thread, matrix, with_latencies

from runner.errors import ExitCode
from runner.history import store as hs
from runner.history.environment import changes, facts
from runner.history.night import record

KEY = main_thread(matrix().cells[1]).key
PG_URL = os.environ.get("RUNNER_TEST_POSTGRES_URL", "")
IN_CI = os.environ.get("CI", "") not in ("", "0", "false")


def night(hour: int, seed: int = 1, host: str = "vm", kernel: str = "6.12.8"):
    """The recorded matrix as a night at `hour`, its FIFO 80 thread with 2,000 callbacks drawn from `seed`."""
    doc = with_latencies(matrix(), "policy=fifo,priority=80", latencies(2_000, seed=seed))
    doc = copy.deepcopy(doc)
    stamp = f"2026-11-{1 + hour // 24:02d}T{hour % 24:02d}:00:00+00:00"
    doc.started_at = stamp
    doc.machine.hostname = host
    doc.machine.kernel = kernel
    for cell in doc.cells:
        cell.started_at = stamp
    return doc


@pytest.fixture(params=["sqlite", "postgresql"])
def target(request, tmp_path):
    if request.param == "sqlite":
        yield str(tmp_path / "history.sqlite")
        return
    if not PG_URL:
        if IN_CI:
            pytest.fail("RUNNER_TEST_POSTGRES_URL is not set in CI: .ci/run starts a PostgreSQL server for these tests")
        pytest.skip("no PostgreSQL server: set RUNNER_TEST_POSTGRES_URL (.ci/postgres start DIR prints one)")
    pytest.importorskip("psycopg", reason="psycopg 3 (the history extra) is not installed")
    import psycopg

    schema = "t" + uuid.uuid4().hex[:12]  # each test its own schema of the one database
    with psycopg.connect(PG_URL, autocommit=True) as db:
        db.execute(f"CREATE SCHEMA {schema}")
    sep = "&" if "?" in PG_URL else "?"
    yield f"{PG_URL}{sep}options=-csearch_path%3D{schema}"
    with psycopg.connect(PG_URL, autocommit=True) as db:
        db.execute(f"DROP SCHEMA {schema} CASCADE")


def test_a_night_goes_in_and_its_series_come_out(target):
    with hs.open_store(target) as store:
        assert store.add(record(night(0)), "r0/results.json") == 5
        assert store.add(record(night(24, seed=2)), "r1/results.json") == 5
        series = store.series("vm", "policy=fifo,priority=80", night(0).cells[1].spec_hash, "2027")
        points = series[(KEY, "latency.p99")]
        assert [p.started_at[:10] for p in points] == ["2026-11-01", "2026-11-02"]
        assert all(p.samples == 2_000 and p.low is not None and p.low <= p.value <= p.high for p in points)
        merged = store.histogram("vm", "policy=fifo,priority=80", night(0).cells[1].spec_hash, KEY, "latency")
        assert merged is not None and merged.count == 4_000  # two nights' histograms, merged exactly
        assert [n.environment["kernel"] for n in store.nights("vm")] == ["6.12.8", "6.12.8"]


def test_the_same_cell_added_twice_is_kept_once(target):
    """A shard's run with --history, then the merge of the shards with --history: the cells are the same nights."""
    with hs.open_store(target) as store:
        assert store.add(record(night(0)), "shard/results.json") == 5
        assert store.add(record(night(0)), "merged/results.json") == 0
        assert len(store.cells()) == 5


def _add_in_a_process(target: str, hour: int) -> None:
    with hs.open_store(target) as store:
        store.add(record(night(hour, seed=hour)), f"r{hour}/results.json")


def test_two_writers_at_once_both_land(target):
    """Two shards of a night finishing together: one waits for the other (WAL, busy timeout, one transaction each)."""
    context = multiprocessing.get_context("fork")
    writers = [context.Process(target=_add_in_a_process, args=(target, hour)) for hour in (1, 2, 3, 4)]
    for w in writers:
        w.start()
    for w in writers:
        w.join(120)
        assert w.exitcode == 0
    with hs.open_store(target) as store:
        assert len(store.nights()) == 4 and len(store.cells()) == 20


def test_a_newer_schema_is_refused_naming_both_versions(target):
    with hs.open_store(target) as store:
        store._run("UPDATE meta SET value = '7' WHERE key = 'schema_version'")
        if store.dialect == "postgresql":
            store.db.commit()
    with pytest.raises(hs.HistoryError) as caught, hs.open_store(target):
        pass
    assert caught.value.exit_code == ExitCode.INVALID_INPUT
    assert "schema is version 7, this runner knows up to 1" in str(caught.value)


def test_a_corrupt_file_is_invalid_input(tmp_path):
    path = tmp_path / "h.sqlite"
    path.write_bytes(b"this is no database at all, just text\n" * 200)
    with pytest.raises(hs.HistoryError) as caught, hs.open_store(str(path)):
        pass
    assert caught.value.exit_code == ExitCode.INVALID_INPUT and "not a runner history, or a corrupt one" in str(caught.value)


def test_another_sqlite_database_is_not_taken_for_a_history(tmp_path):
    path = str(tmp_path / "other.db")
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE accounts (id INTEGER)")
    with pytest.raises(hs.HistoryError) as caught, hs.open_store(path):
        pass
    assert caught.value.exit_code == ExitCode.INVALID_INPUT and "not a runner history" in str(caught.value)


def test_a_history_locked_past_the_timeout_is_a_run_error(tmp_path, monkeypatch):
    path = str(tmp_path / "h.sqlite")
    with hs.open_store(path):
        pass
    monkeypatch.setattr(hs, "BUSY_TIMEOUT_S", 0.2)
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(hs.HistoryError) as caught, hs.open_store(path) as store:
            store.add(record(night(0)), "r/results.json")
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert caught.value.exit_code == ExitCode.RUN_ERROR and "locked by another writer" in str(caught.value)


def test_a_full_disk_is_a_run_error_and_adds_nothing(tmp_path, monkeypatch):
    """SQLite says SQLITE_FULL for a full disk as for a page limit: the limit stands in for the disk."""
    path = str(tmp_path / "h.sqlite")
    with hs.open_store(path):
        pass
    real = sqlite3.connect

    def small(*args, **kwargs):
        db = real(*args, **kwargs)
        db.execute("PRAGMA max_page_count = 12")
        return db

    monkeypatch.setattr(sqlite3, "connect", small)
    with pytest.raises(hs.HistoryError) as caught, hs.open_store(path) as store:
        store.add(record(night(0)), "r/results.json")
    assert caught.value.exit_code == ExitCode.RUN_ERROR and "the disk is full" in str(caught.value)
    monkeypatch.setattr(sqlite3, "connect", real)
    with hs.open_store(path) as store:
        assert store.nights() == []  # the night's transaction was rolled back whole


def test_environment_changes_are_said_in_words():
    before, after = facts(night(0)), facts(night(24, kernel="6.12.9"))
    assert "kernel 6.12.8 → 6.12.9" in changes(before, after)
    assert changes(before, before) == []
    assert changes({}, after) == []  # a fact a night did not record is no change


def test_the_cpu_model_is_read_as_proc_cpuinfo_names_it():
    from runner.run.machine import cpu_model

    assert cpu_model("processor\t: 0\nmodel name\t: Intel(R) Xeon(R) Gold 6338\n\nprocessor\t: 1\nmodel name\t: x\n") == (
        "Intel(R) Xeon(R) Gold 6338"
    )
    assert cpu_model("processor : 0\nBogoMIPS : 108\n\nHardware : BCM2835\nModel : Raspberry Pi 4 Model B Rev 1.4\n") == (
        "Raspberry Pi 4 Model B Rev 1.4"
    )
    assert cpu_model("") is None and cpu_model(None) is None


def test_a_history_path_that_is_a_link_is_refused_not_followed(tmp_path):
    """Nothing the runner writes follows a link it did not make: SQLite would create or open what the link names."""
    (tmp_path / "h.sqlite").symlink_to(tmp_path / "elsewhere.sqlite")
    with pytest.raises(hs.HistoryError) as caught, hs.open_store(str(tmp_path / "h.sqlite")):
        pass
    assert caught.value.exit_code == ExitCode.INVALID_INPUT and "expected the history file itself" in str(caught.value)
    assert not (tmp_path / "elsewhere.sqlite").exists()


def test_a_urls_password_is_never_shown():
    assert hs.shown("postgresql://lab:s3cret@db.example:5432/nights") == "postgresql://lab:***@db.example:5432/nights"
    assert hs.shown("postgresql://lab@db.example/nights") == "postgresql://lab@db.example/nights"
    assert hs.shown("/var/lib/runner/history.sqlite") == "/var/lib/runner/history.sqlite"


def test_a_night_and_the_change_points_it_reported_go_in_together_or_not_at_all(target, monkeypatch):
    """A night whose regression was reported, stored without its change point (the write of it failed, the runner was
    killed between the two), would report the same change again the next night: one transaction holds both."""
    from runner.history.apply import judged_into
    from runner.report.compare import DEFAULT_THRESHOLDS

    with hs.open_store(target) as store:
        for hour in range(5):
            judged_into(store, night(hour * 24, seed=hour + 1), f"r{hour}", list(DEFAULT_THRESHOLDS))
    regressed = with_latencies(night(5 * 24), "policy=fifo,priority=80", [v * 5 for v in latencies(2_000, seed=9)])
    real = hs.Store._run

    def failing(self, text, args=()):
        if text.startswith("INSERT INTO change_points"):
            raise sqlite3.OperationalError("disk I/O error")
        return real(self, text, args)

    monkeypatch.setattr(hs.Store, "_run", failing)
    with pytest.raises(hs.HistoryError), hs.open_store(target) as store:
        judged_into(store, regressed, "r5", list(DEFAULT_THRESHOLDS))
    monkeypatch.setattr(hs.Store, "_run", real)
    with hs.open_store(target) as store:
        assert len(store.nights()) == 5 and store.change_points() == []
        verdict = judged_into(store, regressed, "r5", list(DEFAULT_THRESHOLDS))
        assert verdict.change_points and len(store.change_points()) == len(verdict.change_points)
