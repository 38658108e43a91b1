"""The history's store: SQLite in one file (the default) or PostgreSQL by URL, with a versioned schema.  The I/O.

SQLite is the standard library's: one file, written in WAL mode with a busy timeout, each night
added in one `BEGIN IMMEDIATE` transaction, so two writers at once (two shards of a night
finishing together) both land, one after the other.  PostgreSQL (`--history postgresql://...`)
keeps one history for a lab whose hosts share it, through psycopg 3 (the `history` extra); the
same tables, the same statements.

The schema is versioned (`meta.schema_version`), its migrations are code (`MIGRATIONS`, applied in
order in the transaction that opens the store), and a store of a newer schema than this runner
knows is refused, naming both versions, never written.  Whatever goes wrong is a `HistoryError`
with its exit code: a file that is no history (or corrupt), or of a newer schema, is invalid input
(2); a store locked past the timeout, a full disk or an unreachable server is a run error (4).
The night's results.json is always written before the history is touched (session, merge), so no
error here loses it.

Rows are keyed by host, cell id, cell spec hash, thread and figure; a cell's night by when it
started, which also makes adding the same cell twice (a shard's run, then the merge of the shards)
a no-op for the second.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Optional

from runner.errors import ExitCode, RunnerError
from runner.histogram import Histogram, merge
from runner.history.night import NightRecord

SCHEMA_VERSION = 1
BUSY_TIMEOUT_S = float(os.environ.get("RUNNER_HISTORY_TIMEOUT", "60"))  # how long a writer waits for another


class HistoryError(RunnerError):
    """The history could not be read or written; the exit code says whose the problem is."""

    def __init__(self, message: str, code: ExitCode = ExitCode.RUN_ERROR):
        super().__init__(message)
        self.exit_code = code


_PK = {"sqlite": "INTEGER PRIMARY KEY", "postgresql": "BIGSERIAL PRIMARY KEY"}
_BIG = {"sqlite": "INTEGER", "postgresql": "BIGINT"}
_REAL = {"sqlite": "REAL", "postgresql": "DOUBLE PRECISION"}


def _migration_1(dialect: str) -> list[str]:
    pk, big, real = _PK[dialect], _BIG[dialect], _REAL[dialect]
    key = "host TEXT NOT NULL, cell TEXT NOT NULL, spec_hash TEXT NOT NULL, started_at TEXT NOT NULL"
    return [
        f"CREATE TABLE nights (id {pk}, host TEXT NOT NULL, started_at TEXT NOT NULL, finished_at TEXT NOT NULL, "
        "added_at TEXT NOT NULL, scenario TEXT NOT NULL, scenario_hash TEXT NOT NULL, runner_version TEXT NOT NULL, "
        "shard TEXT NOT NULL, results TEXT NOT NULL, environment TEXT NOT NULL)",
        f"CREATE TABLE cells (night_id {big} NOT NULL REFERENCES nights(id), {key}, status TEXT NOT NULL, "
        f"duration_ns {big} NOT NULL, repeats INTEGER NOT NULL, PRIMARY KEY (host, cell, spec_hash, started_at))",
        f"CREATE TABLE figures ({key}, thread TEXT NOT NULL, figure TEXT NOT NULL, value {real} NOT NULL, samples {big}, "
        f"low {real}, high {real}, events {big}, exposure {real}, se {real}, few INTEGER NOT NULL, "
        "PRIMARY KEY (host, cell, spec_hash, thread, figure, started_at))",
        f"CREATE TABLE histograms ({key}, thread TEXT NOT NULL, kind TEXT NOT NULL, buckets TEXT NOT NULL, "
        f"min {big} NOT NULL, max {big} NOT NULL, PRIMARY KEY (host, cell, spec_hash, thread, kind, started_at))",
        f"CREATE TABLE change_points ({key}, thread TEXT NOT NULL, figure TEXT NOT NULL, reported_at TEXT NOT NULL, "
        "words TEXT NOT NULL, PRIMARY KEY (host, cell, spec_hash, thread, figure, started_at))",
    ]


MIGRATIONS = {1: _migration_1}
"""Each schema version's statements, from the one before (a new version adds an entry; rows are never rewritten in place)."""


@dataclass(frozen=True)
class Point:
    """One night of one figure's series."""

    started_at: str
    value: float
    samples: Optional[int]
    low: Optional[float]
    high: Optional[float]
    events: Optional[int]
    exposure: Optional[float]
    se: Optional[float]
    few: bool


@dataclass(frozen=True)
class Night:
    """One night as stored: when, where, what ran, and its environment's facts."""

    host: str
    started_at: str
    scenario: str
    runner_version: str
    results: str
    environment: dict[str, str]


@dataclass(frozen=True)
class ChangePoint:
    cell: str
    spec_hash: str
    thread: str
    figure: str
    started_at: str
    reported_at: str
    words: str


def is_url(target: str) -> bool:
    return target.startswith(("postgresql://", "postgres://"))


class Store:
    """An open history: read a series, add a night.  Use `open_store` (a context manager closes it)."""

    def __init__(self, target: str, connection: Any, dialect: str):
        self.target = target
        self.db = connection
        self.dialect = dialect

    # ------------------------------------------------------------ plumbing

    def _sql(self, text: str) -> str:
        return text.replace("?", "%s") if self.dialect == "postgresql" else text

    def _run(self, text: str, args: Sequence[Any] = ()) -> Any:
        return self.db.execute(self._sql(text), tuple(args))

    @contextmanager
    def _write(self) -> Iterator[None]:
        """One transaction that holds the write lock from its start (SQLite: BEGIN IMMEDIATE, waiting the busy timeout)."""
        with _translated(self.target, "cannot write the history"):
            self._run("BEGIN IMMEDIATE" if self.dialect == "sqlite" else "BEGIN")
            try:
                if self.dialect == "postgresql":
                    self._run("SELECT pg_advisory_xact_lock(7377117)")  # one writer of the schema at a time
                yield
            except BaseException:
                try:
                    self._run("ROLLBACK")
                except Exception:
                    pass  # SQLite already rolled back (a full disk does): the error to say is the first one
                raise
            self._run("COMMIT")

    def close(self) -> None:
        try:
            self.db.close()
        except Exception:
            pass

    # ------------------------------------------------------------ schema

    def prepare(self) -> None:
        """Check the schema's version and migrate it to this runner's, in one transaction; refuse a newer one."""
        with self._write():
            version = self._version()
            if version > SCHEMA_VERSION:
                raise HistoryError(
                    f"runner: history {self.target}: its schema is version {version}, this runner knows up to "
                    f"{SCHEMA_VERSION}; use a newer runner (pip install -U runner), the history is left as it is",
                    ExitCode.INVALID_INPUT,
                )
            for number in range(version + 1, SCHEMA_VERSION + 1):
                for statement in MIGRATIONS[number](self.dialect):
                    self._run(statement)
                self._run("UPDATE meta SET value = ? WHERE key = 'schema_version'", (str(number),))

    def _version(self) -> int:
        """The stored schema version: 0 for a new, empty store; a store holding other tables is refused."""
        tables = self._tables()
        if "meta" not in tables:
            if tables - {"sqlite_sequence"}:
                raise HistoryError(
                    f"runner: history {self.target}: a database of something else (tables {', '.join(sorted(tables))}), not a "
                    "runner history; give a new file or a runner history",
                    ExitCode.INVALID_INPUT,
                )
            self._run("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
            self._run("INSERT INTO meta (key, value) VALUES ('schema_version', '0')")
            return 0
        row = self._run("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        try:
            return int(row[0])
        except (TypeError, ValueError, IndexError):
            raise HistoryError(
                f"runner: history {self.target}: no schema version in it; not a runner history", ExitCode.INVALID_INPUT
            ) from None

    def _tables(self) -> set[str]:
        if self.dialect == "sqlite":
            rows = self._run("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()
        else:
            rows = self._run("SELECT table_name FROM information_schema.tables WHERE table_schema = current_schema()").fetchall()
        return {r[0] for r in rows}

    # ------------------------------------------------------------ writing

    def add(self, night: NightRecord, results: str, change_points: Sequence[ChangePoint] = ()) -> int:
        """Add a night and the change points it reported in one transaction (never one without the other: a night kept
        without its change point would report it again the next night); return how many of its cells were new (a cell
        already there is left as it is)."""
        added = 0
        now = datetime.now(timezone.utc).isoformat(timespec="seconds")
        with self._write():
            for point in change_points:
                self._change_point(night.host, point)
            row = self._run(
                "INSERT INTO nights (host, started_at, finished_at, added_at, scenario, scenario_hash, runner_version, shard, results, "
                "environment) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
                (
                    night.host,
                    night.started_at,
                    night.finished_at,
                    now,
                    night.scenario,
                    night.scenario_hash,
                    night.runner_version,
                    night.shard,
                    results,
                    json.dumps(night.environment, sort_keys=True),
                ),
            ).fetchone()
            night_id = row[0]
            for cell in night.cells:
                key = (night.host, cell.cell, cell.spec_hash, cell.started_at)
                there = self._run("SELECT 1 FROM cells WHERE host = ? AND cell = ? AND spec_hash = ? AND started_at = ?", key).fetchone()
                if there:
                    continue
                added += 1
                self._run(
                    "INSERT INTO cells (night_id, host, cell, spec_hash, started_at, status, duration_ns, repeats) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    (night_id, *key, cell.status, cell.duration_ns, cell.repeats),
                )
                for f in cell.figures:
                    self._run(
                        "INSERT INTO figures (host, cell, spec_hash, started_at, thread, figure, value, samples, low, high, events, "
                        "exposure, se, few) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (*key, f.thread, f.figure, f.value, f.samples, f.low, f.high, f.events, f.exposure, f.se, int(f.few)),
                    )
                for thread, kind, hist in cell.histograms:
                    self._run(
                        "INSERT INTO histograms (host, cell, spec_hash, started_at, thread, kind, buckets, min, max) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (*key, thread, kind, json.dumps(hist.buckets, separators=(",", ":")), hist.min, hist.max),
                    )
        return added

    def _change_point(self, host: str, point: ChangePoint) -> None:
        """Record a change point (in the caller's transaction); one already there is left as it is."""
        there = self._run(
            "SELECT 1 FROM change_points WHERE host = ? AND cell = ? AND spec_hash = ? AND thread = ? AND figure = ? AND started_at = ?",
            (host, point.cell, point.spec_hash, point.thread, point.figure, point.started_at),
        ).fetchone()
        if not there:
            self._run(
                "INSERT INTO change_points (host, cell, spec_hash, started_at, thread, figure, reported_at, words) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (host, point.cell, point.spec_hash, point.started_at, point.thread, point.figure, point.reported_at, point.words),
            )

    # ------------------------------------------------------------ reading

    def _read(self, text: str, args: Sequence[Any] = ()) -> list[Any]:
        with _translated(self.target, "cannot read the history"):
            rows = self._run(text, args).fetchall()
            if self.dialect == "postgresql":
                self.db.rollback()  # a read holds no transaction open between nights
            return list(rows)

    def series(self, host: str, cell: str, spec_hash: str, before: str) -> dict[tuple[str, str], list[Point]]:
        """Every figure's series of a cell and spec on a host, nights before `before` (ISO time), oldest first, by (thread, figure)."""
        rows = self._read(
            "SELECT thread, figure, started_at, value, samples, low, high, events, exposure, se, few FROM figures "
            "WHERE host = ? AND cell = ? AND spec_hash = ? AND started_at < ? ORDER BY started_at",
            (host, cell, spec_hash, before),
        )
        out: dict[tuple[str, str], list[Point]] = {}
        for thread, figure, *rest in rows:
            started, value, samples, low, high, events, exposure, se, few = rest
            out.setdefault((thread, figure), []).append(Point(started, value, samples, low, high, events, exposure, se, bool(few)))
        return out

    def spec_hashes(self, host: str, cell: str) -> list[tuple[str, str]]:
        """(spec hash, first night) of each history a cell has on a host, oldest first."""
        rows = self._read(
            "SELECT spec_hash, MIN(started_at) FROM cells WHERE host = ? AND cell = ? GROUP BY spec_hash ORDER BY 2", (host, cell)
        )
        return [(r[0], r[1]) for r in rows]

    def nights(self, host: Optional[str] = None, since: str = "") -> list[Night]:
        """Every night, oldest first (of one host when given), from `since` (ISO time) on."""
        where, args = "WHERE started_at >= ?", [since]
        if host is not None:
            where, args = where + " AND host = ?", [since, host]
        rows = self._read(
            f"SELECT host, started_at, scenario, runner_version, results, environment FROM nights {where} ORDER BY started_at", args
        )
        return [Night(r[0], r[1], r[2], r[3], r[4], json.loads(r[5])) for r in rows]

    def cells(self, since: str = "") -> list[tuple[str, str, str, str, str]]:
        """(host, cell, spec hash, started_at, status) of every cell night, oldest first."""
        rows = self._read("SELECT host, cell, spec_hash, started_at, status FROM cells WHERE started_at >= ? ORDER BY started_at", (since,))
        return [(r[0], r[1], r[2], r[3], r[4]) for r in rows]

    def all_figures(self, since: str = "") -> list[tuple[str, str, str, str, str, Point]]:
        """(host, cell, spec hash, thread, figure, point) of every figure of every night from `since` on, oldest first."""
        rows = self._read(
            "SELECT host, cell, spec_hash, thread, figure, started_at, value, samples, low, high, events, exposure, se, few "
            "FROM figures WHERE started_at >= ? ORDER BY started_at",
            (since,),
        )
        return [(r[0], r[1], r[2], r[3], r[4], Point(r[5], r[6], r[7], r[8], r[9], r[10], r[11], r[12], bool(r[13]))) for r in rows]

    def histogram(
        self, host: str, cell: str, spec_hash: str, thread: str, kind: str, since: str = "", before: str = "~"
    ) -> Optional[Histogram]:
        """One thread's histogram of `kind` over every night from `since` on (and before `before`), merged (exact to the bucket)."""
        rows = self._read(
            "SELECT buckets, min, max FROM histograms WHERE host = ? AND cell = ? AND spec_hash = ? AND thread = ? AND kind = ? "
            "AND started_at >= ? AND started_at < ?",
            (host, cell, spec_hash, thread, kind, since, before),
        )
        return merge(Histogram(buckets=[tuple(b) for b in json.loads(r[0])], min=r[1], max=r[2]) for r in rows)

    def change_points(self, host: Optional[str] = None) -> list[ChangePoint]:
        where, args = ("WHERE host = ?", (host,)) if host is not None else ("", ())
        rows = self._read(
            f"SELECT cell, spec_hash, thread, figure, started_at, reported_at, words FROM change_points {where} ORDER BY started_at", args
        )
        return [ChangePoint(*r) for r in rows]


@contextmanager
def _translated(target: str, what: str) -> Iterator[None]:
    """sqlite3's and psycopg's errors as HistoryErrors with the exit code whose problem they are."""
    import sqlite3

    try:
        yield
    except HistoryError:
        raise
    except sqlite3.DatabaseError as exc:
        raise _sqlite_error(target, what, exc) from None
    except OSError as exc:
        raise HistoryError(f"runner: {what} {target}: {exc.strerror or exc}") from None
    except Exception as exc:
        if type(exc).__module__.startswith("psycopg"):
            raise HistoryError(f"runner: {what} {shown(target)}: {str(exc).strip() or type(exc).__name__}") from None
        raise


def _sqlite_error(target: str, what: str, exc: Exception) -> HistoryError:
    text = str(exc)
    if "locked" in text or "busy" in text:
        return HistoryError(
            f"runner: {what} {target}: it is locked by another writer past {BUSY_TIMEOUT_S:g} s (RUNNER_HISTORY_TIMEOUT); "
            "the night's results are kept: add them later with `runner history FILE --import RESULTS`"
        )
    if "full" in text:
        return HistoryError(
            f"runner: {what} {target}: the disk is full; the night's results are kept: free some space, then add them with "
            "`runner history FILE --import RESULTS`"
        )
    if "not a database" in text or "malformed" in text or "corrupt" in text:
        return HistoryError(
            f"runner: history {target}: not a runner history, or a corrupt one ({text}); give another file, or move this one away",
            ExitCode.INVALID_INPUT,
        )
    if "readonly" in text or "unable to open" in text:
        return HistoryError(f"runner: {what} {target}: {text}; choose a file you may write", ExitCode.INVALID_INPUT)
    return HistoryError(f"runner: {what} {target}: {text}")


def shown(target: str) -> str:
    """A URL without its password."""
    if "@" in target and "://" in target:
        scheme, rest = target.split("://", 1)
        credentials, host = rest.rsplit("@", 1)
        user = credentials.split(":", 1)[0]
        return f"{scheme}://{user}:***@{host}" if ":" in credentials else target
    return target


@contextmanager
def open_store(target: str) -> Iterator[Store]:
    """The history at `target` (a file, or a postgresql:// URL), its schema checked and migrated; closed on exit."""
    store = _connect(target)
    try:
        store.prepare()
        yield store
    finally:
        store.close()


def _connect(target: str) -> Store:
    if is_url(target):
        try:
            import psycopg
        except ImportError:
            raise HistoryError(
                f"runner: history {shown(target)}: PostgreSQL needs psycopg 3: pip install 'runner[history]'", ExitCode.INVALID_INPUT
            ) from None
        with _translated(target, "cannot connect to the history"):
            return Store(target, psycopg.connect(target, connect_timeout=int(BUSY_TIMEOUT_S)), "postgresql")
    import sqlite3

    if os.path.isdir(target):
        raise HistoryError(f"runner: history {target}: a folder; expected a history file (it is made when absent)", ExitCode.INVALID_INPUT)
    from runner.safefs import check_target

    for path in (target, target + "-wal", target + "-shm"):  # SQLite writes beside it too: no link there is followed
        try:
            check_target(path)
        except OSError as exc:
            raise HistoryError(
                f"runner: history {path}: {exc.strerror}; expected the history file itself", ExitCode.INVALID_INPUT
            ) from None
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        raise HistoryError(f"runner: history {target}: no folder {folder} to make it in", ExitCode.INVALID_INPUT)
    with _translated(target, "cannot open the history"):
        db = sqlite3.connect(target, timeout=BUSY_TIMEOUT_S, isolation_level=None)
        store = Store(target, db, "sqlite")
        mode = db.execute("PRAGMA journal_mode=WAL").fetchone()
        if mode and mode[0] != "wal":
            store.close()
            raise HistoryError(f"runner: cannot open the history {target}: its file system refuses SQLite's WAL mode ({mode[0]})")
        db.execute("PRAGMA synchronous=NORMAL")
        return store
