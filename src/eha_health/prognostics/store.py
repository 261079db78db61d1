"""Health history: every diagnosis of every actuator, in one SQLite file (WAL, transactions).

CLI (:mod:`eha_health.cli.prognostics`): ``eha-health history add RUN.csv|BAG.mcap --actuator ID
[--time-h T] [--usage U]`` -> :meth:`HistoryStore.add_diagnosis`; ``history list
[--actuator ID] [--json]`` -> :meth:`HistoryStore.list_tests`; ``history import FILE.csv
[--maintenance M.csv]`` -> :meth:`HistoryStore.import_files` (the files: :mod:`.history_csv`; the
records and their checks: :mod:`.records`); ``history repair --actuator ID --fault gm|fsj|bkl|all
--time-h T`` -> :meth:`HistoryStore.record_repair`; ``--history DB`` defaults to
:func:`default_history_path`. Bad input raises :class:`PrognosticsError` (a ValueError)
with one line naming the problem (exit code 2); the store is then unchanged.

Schema version 2 (``PRAGMA user_version`` and table ``schema_version``; a version-1 file is
migrated when first opened for writing, :meth:`HistoryStore._migrate`):

* ``tests``: one row per diagnosis: ``actuator_id``, ``time_h`` (operating hours, the
  prognostics clock), ``wall_time_utc`` (ISO 8601), ``sim_time_s`` (ROS / simulated stamp
  [s], optional), ``usage`` and ``usage_unit`` (flight hours or cycles, optional), ``k_gm,
  k_fsj, k_bkl`` in [0, ``physics.faults.FAULT_UPPER``] and ``std_gm, std_fsj, std_bkl`` >= 0
  or NULL (not stated: a HISTORY.csv row without std; estimated when read, from the actuator's
  whole series, :func:`fill_missing_std`; version 1 stored the estimate of the imported file
  alone), ``method``, ``cost`` and
  ``fit_rms`` (JSON, per-channel RMS: fit quality), ``discrepancy`` (verdict), ``warnings``
  (JSON), ``source_path``, ``source_hash`` (sha256 of the recording -- each test window of a bag
  of several with its window id, :func:`recording_hash` --, or of the diagnosis inputs when there
  is no file, or when the file is a monitor's MCAP log still being written, which a live test's
  ``source_path`` names; UNIQUE: the same recording twice adds no row),
  ``software_version``; UNIQUE (actuator_id, time_h).
* ``maintenance``: ``actuator_id``, ``time_h``, ``fault`` (gm, fsj, bkl, all), ``action``
  (repair, replace), ``wall_time_utc``, ``note``. A fault's trend restarts at its last
  maintenance: tests at or after that time count.

Appends are validated first, then written in one ``BEGIN IMMEDIATE`` transaction: a writer
killed mid-append leaves the previous state (SQLite's atomic commit), never a partial row.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import sqlite3
import time
import urllib.parse
from pathlib import Path
from typing import Callable

import numpy as np

from ..physics.faults import FAULT_KEYS, FAULT_UPPER
from ..signals.channels import MEASURED
from .config import PrognosticsError, Settings, load_settings
from .history_csv import check_maintenance_times, read_history_csv, read_maintenance_csv
from .records import (K_COLUMNS, MAINT_FAULTS, STD_COLUMNS, DuplicateRow, History, HealthRecord, MaintenanceRecord,
                      check_maintenance, check_maintenance_time, check_order, check_record, history_from_records,
                      now_utc, replacements, usage_fall_notes, batch_usage_notes)


SCHEMA_VERSION = 2
#: s a writer waits for another writer's transaction before it gives up (SQLite busy timeout)
BUSY_TIMEOUT_S = 60.0
#: s between two asks of a waiting writer's ``cancelled()`` (:meth:`HistoryStore._begin_immediate`)
LOCK_POLL_S = 0.25

_TESTS = f"""
CREATE TABLE IF NOT EXISTS {{name}} (
    id INTEGER PRIMARY KEY,
    actuator_id TEXT NOT NULL CHECK (length(actuator_id) > 0),
    time_h REAL NOT NULL CHECK (time_h >= 0),
    wall_time_utc TEXT NOT NULL,
    sim_time_s REAL,
    usage REAL,
    usage_unit TEXT,
    k_gm REAL NOT NULL CHECK (k_gm BETWEEN 0 AND {FAULT_UPPER!r}),
    k_fsj REAL NOT NULL CHECK (k_fsj BETWEEN 0 AND {FAULT_UPPER!r}),
    k_bkl REAL NOT NULL CHECK (k_bkl BETWEEN 0 AND {FAULT_UPPER!r}),
    std_gm REAL CHECK (std_gm >= 0),
    std_fsj REAL CHECK (std_fsj >= 0),
    std_bkl REAL CHECK (std_bkl >= 0),
    method TEXT,
    cost REAL,
    fit_rms TEXT,
    discrepancy TEXT,
    warnings TEXT,
    source_path TEXT,
    source_hash TEXT NOT NULL UNIQUE,
    software_version TEXT NOT NULL,
    UNIQUE (actuator_id, time_h)
)"""
_INDEX = "CREATE INDEX IF NOT EXISTS tests_by_actuator ON tests (actuator_id, time_h)"
_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL, applied_utc TEXT NOT NULL);
{_TESTS.format(name="tests")};
CREATE TABLE IF NOT EXISTS maintenance (
    id INTEGER PRIMARY KEY,
    actuator_id TEXT NOT NULL,
    time_h REAL NOT NULL CHECK (time_h >= 0),
    fault TEXT NOT NULL CHECK (fault IN ({', '.join(repr(f) for f in MAINT_FAULTS)})),
    action TEXT NOT NULL CHECK (action IN ('repair', 'replace')),
    wall_time_utc TEXT NOT NULL,
    note TEXT,
    UNIQUE (actuator_id, time_h, fault)
);
{_INDEX};
"""

TEST_COLUMNS = ("actuator_id", "time_h", "wall_time_utc", "sim_time_s", "usage", "usage_unit", *K_COLUMNS,
                *STD_COLUMNS, "method", "cost", "fit_rms", "discrepancy", "warnings",
                "source_path", "source_hash", "software_version")


def default_history_path(settings: Settings | None = None) -> Path:
    """``$EHA_HEALTH_HISTORY`` if set, else ``history.default_path`` of data/prognostics.yaml."""
    env = os.environ.get("EHA_HEALTH_HISTORY")
    return Path(env or (settings or load_settings()).history.default_path).expanduser()


def check_writable(path: Path) -> None:
    """Refuse a history path no append can go to, in one line: a ``.csv`` or a directory."""
    if path.suffix.lower() == ".csv":     # it would be a SQLite file no command reads as one
        raise PrognosticsError(f"{path}: a HISTORY.csv is read, not written: the history to write "
                               f"to is a SQLite file (import a CSV into one: eha-health history import)")
    if path.is_dir():
        raise PrognosticsError(f"{path}: a directory, not a history file (the SQLite file to write to)")


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def recording_hash(path: str | Path, window: int | None = None, file_hash: str | None = None) -> str:
    """Identity of a recorded test: the sha256 of its file (a CSV, a bag of one test), or for test
    window ``window`` of a bag of several, the sha256 of that and the window id: a bag of N tests
    is N recordings. ``file_hash``: the file's sha256 if already known."""
    h = file_hash or sha256_file(path)
    return h if window is None else hashlib.sha256(f"{h}#test={int(window)}".encode()).hexdigest()


# ----------------------------------------------------------------------------- SQLite store
class HistoryStore:
    """The SQLite health history (created on first use). Use as a context manager."""

    def __init__(self, path: str | Path | None = None, settings: Settings | None = None, readonly: bool = False,
                 cancelled: Callable[[], bool] | None = None, on_wait: Callable[[str], None] | None = None):
        """``readonly``: read what is there and write nothing -- no schema into an empty file, no
        switch to WAL (a file refused, or only read, stays byte for byte as it was); a path with no
        file is refused and nothing is created there.
        ``cancelled``: asked while a write waits for another writer's lock; True gives up
        (:class:`LockWaitStopped`); ``on_wait`` hears once that a write waits."""
        self.settings = settings or load_settings()
        self.path = Path(path) if path is not None else default_history_path(self.settings)
        self.readonly = readonly
        self.cancelled, self.on_wait = cancelled, on_wait
        self._said_wait = False   # on_wait hears of a wait once
        if readonly:
            if self.path.is_dir():
                raise PrognosticsError(f"{self.path}: a directory, not a history file")
            if not self.path.exists():
                raise PrognosticsError(f"{self.path}: no such history file (read-only: nothing created)")
        else:
            check_writable(self.path)
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:    # a read-only filesystem, no permission
                raise ReadOnlyHistory(f"{self.path}: cannot create its folder ({e.strerror}); nothing "
                                      f"written") from None
        try:
            self.conn, ver = self._connect()
            # a damaged file must be refused here, not fail later mid-query (fuzzing found both)
            check = self.conn.execute("PRAGMA quick_check").fetchone()[0]
            if check != "ok":
                raise sqlite3.DatabaseError("integrity check: " + " ".join(str(check).split()))
        except (sqlite3.DatabaseError, UnicodeDecodeError) as e:   # sqlite's own message may quote damaged bytes
            if isinstance(e, sqlite3.OperationalError) and (ro := self._read_only(e)) is not None:
                raise ro from None
            raise PrognosticsError(f"{self.path}: not a history database ({' '.join(str(e).split())[:200]})") from None
        if ver > SCHEMA_VERSION:
            self.conn.close()
            raise PrognosticsError(f"{self.path}: history schema version {ver} is newer than this software's "
                                   f"({SCHEMA_VERSION})")
        if ver == 0:
            # judged before anything is written: a foreign file is refused as it was
            tables = {r[0] for r in self.conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            if tables - {"schema_version", "tests", "maintenance"}:
                self.conn.close()
                raise PrognosticsError(f"{self.path}: an SQLite file that is not a history (tables {sorted(tables)})")
        if readonly:
            if ver == 0:   # an empty file (or one whose creation never committed) reads as an empty history
                self.conn.close()
                self.conn = sqlite3.connect(":memory:", isolation_level=None)
                self.conn.executescript(_SCHEMA)
            else:
                self._check_columns()
            return
        try:
            self._to_wal()
            self.conn.execute("PRAGMA synchronous=FULL")
            self.conn.execute("PRAGMA foreign_keys=ON")
            if ver == 0:
                with self._immediate():
                    if self.schema_version == 0:     # not created meanwhile by another writer
                        for stmt in filter(str.strip, _SCHEMA.split(";")):
                            self.conn.execute(stmt)
                        self._stamp_version()
            else:
                self._check_columns()
                if ver < SCHEMA_VERSION:
                    self._migrate()
        except BaseException:
            self.conn.close()
            raise

    def _connect(self) -> tuple[sqlite3.Connection, int]:
        """A connection and the file's ``user_version``. A WAL file in a folder this process cannot
        write (a read-only filesystem) cannot be opened the usual way: SQLite creates its ``-shm``
        beside it. Read-only, such a file is opened immutable (SQLite's URI ``immutable=1``: no
        locks, no ``-shm``) -- no writer can create the ``-shm`` there either, so none is running.

        Read-only opens use SQLite's ``mode=ro``: a plain open creates a missing file, and its close
        checkpoints the ``-wal`` into the file -- a write. A WAL file read so keeps a ``-wal`` and a
        ``-shm`` beside it (created empty where there were none), as any SQLite reader without
        write access leaves them; the next writer's close checkpoints and removes them."""
        uri = f"file:{urllib.parse.quote(str(self.path.resolve()))}"
        conn = sqlite3.connect(f"{uri}?mode=ro" if self.readonly else str(self.path), uri=self.readonly,
                               timeout=BUSY_TIMEOUT_S, isolation_level=None)
        try:
            return conn, _user_version(conn)
        except sqlite3.OperationalError as e:
            conn.close()
            if not self.readonly or self._read_only(e) is None or not self.path.is_file():
                raise
        wal = self.path.with_name(self.path.name + "-wal")
        if wal.is_file() and wal.stat().st_size > 0:   # immutable would read the file without them
            raise ReadOnlyHistory(f"{self.path}: {wal.name} beside it holds changes not yet in the file, and "
                                  f"SQLite cannot read them in a read-only folder (it needs to create "
                                  f"{self.path.name}-shm): copy the file and its {wal.name} to a writable folder")
        conn = sqlite3.connect(f"{uri}?immutable=1", uri=True, isolation_level=None)
        return conn, _user_version(conn)

    def _read_only(self, e: sqlite3.OperationalError) -> "ReadOnlyHistory | None":
        """A file SQLite cannot open or write because it or its folder is read-only, as one line
        that says so (it is not "not a history database"), else None."""
        if (getattr(e, "sqlite_errorcode", 0) & 0xFF) not in (sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_READONLY):
            return None
        folder = self.path.parent
        if not os.access(folder, os.W_OK):
            what = (f"its folder {folder} is read-only (a read-only filesystem, or no write permission): SQLite "
                    f"creates the history's {self.path.name}-wal and -shm there")
        elif self.path.exists() and not os.access(self.path, os.W_OK):
            what = "the file is read-only (a read-only filesystem, or no write permission)"
        else:
            return None
        tail = ("; nothing written (`eha-health prognose` and `history list` read it there)" if not self.readonly
                else "")
        return ReadOnlyHistory(f"{self.path}: {what}{tail}")

    def _to_wal(self) -> None:
        """Switch the file to WAL. A new file that several writers open at once: SQLite refuses
        the switch at once (SQLITE_BUSY without its busy handler, which could deadlock) while
        another holds a lock, so the switch is tried again, with backoff, up to the busy timeout."""
        self._retry_busy("PRAGMA journal_mode=WAL", backoff=True)

    def _retry_busy(self, stmt: str, backoff: bool) -> None:
        """Execute ``stmt`` until no other connection's lock refuses it, up to :data:`BUSY_TIMEOUT_S`,
        asking :meth:`_waiting` between tries; ``backoff``: sleep between them (a statement SQLite
        refuses at once, without its busy wait)."""
        deadline, pause = time.monotonic() + BUSY_TIMEOUT_S, 0.005
        while True:
            try:
                self.conn.execute(stmt)
                return
            except sqlite3.OperationalError as e:
                if not _busy(e) or time.monotonic() > deadline:
                    raise self._locked(e) from None
                self._waiting()
                if backoff:
                    time.sleep(pause)
                    pause = min(2 * pause, LOCK_POLL_S)

    def _locked(self, e: sqlite3.OperationalError) -> Exception:
        """A busy or read-only file as one line that names it (the CLI's exit code 2), other errors as they are."""
        if not _busy(e):
            return self._read_only(e) or e
        return PrognosticsError(f"{self.path}: the history is locked by another process (waited "
                                f"{BUSY_TIMEOUT_S:g} s: {e}); nothing was written")

    def _migrate(self) -> None:
        """Version 1 -> 2: the std columns may be NULL (not stated). SQLite cannot change a
        column's constraint, so the table is rebuilt -- created, copied, dropped, renamed -- in one
        transaction (a writer killed midway leaves version 1 as it was). The stds a version-1
        import estimated stay as stored."""
        with self._immediate():
            if self.schema_version == 1:      # not migrated meanwhile by another writer
                cols = ",".join(("id",) + TEST_COLUMNS)
                self.conn.execute(_TESTS.format(name="tests_v2"))
                self.conn.execute(f"INSERT INTO tests_v2 ({cols}) SELECT {cols} FROM tests")
                self.conn.execute("DROP TABLE tests")
                self.conn.execute("ALTER TABLE tests_v2 RENAME TO tests")
                self.conn.execute(_INDEX)
                self._stamp_version()

    def _waiting(self) -> None:
        """A write waits for another writer: say so once, give up if the caller is stopping."""
        if self.cancelled is not None and self.cancelled():
            raise LockWaitStopped(f"{self.path}: the history is locked by another process, and the wait for it "
                                  f"was stopped; nothing written")
        if self.on_wait is not None and not self._said_wait:
            self._said_wait = True
            self.on_wait(f"{self.path}: the history is locked by another process: waiting for it (up to "
                         f"{BUSY_TIMEOUT_S:g} s)")

    def _begin_immediate(self) -> None:
        """BEGIN IMMEDIATE, waiting up to :data:`BUSY_TIMEOUT_S` for another writer in steps of
        :data:`LOCK_POLL_S` (SQLite's busy wait cannot be interrupted: a monitor told to stop
        waited the whole minute), asking :meth:`_waiting` between them."""
        self.conn.execute(f"PRAGMA busy_timeout = {int(LOCK_POLL_S * 1000)}")
        try:
            self._retry_busy("BEGIN IMMEDIATE", backoff=False)
        finally:
            self.conn.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")

    @contextlib.contextmanager
    def _immediate(self):
        """One write transaction (BEGIN IMMEDIATE): all of it is committed, or none of it."""
        self._begin_immediate()
        try:
            yield
            self.conn.execute("COMMIT")
        except BaseException as e:
            self.conn.execute("ROLLBACK")
            # a file read-only under a writable folder opens, read-only: the first write fails
            if isinstance(e, sqlite3.OperationalError) and (ro := self._read_only(e)) is not None:
                raise ro from None
            raise

    def _stamp_version(self) -> None:
        self.conn.execute("INSERT INTO schema_version VALUES (?, ?)", (SCHEMA_VERSION, now_utc()))
        self.conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    def _check_columns(self) -> None:
        """A damaged schema can parse and pass the integrity check yet miss a column (fuzzing found it)."""
        want = {"tests": ("id",) + TEST_COLUMNS, "schema_version": ("version", "applied_utc"),
                "maintenance": ("id", "actuator_id", "time_h", "fault", "action", "wall_time_utc", "note")}
        for table, cols in want.items():
            have = {r[1] for r in self.conn.execute(f"PRAGMA table_info({table})")}
            lost = [c for c in cols if c not in have]
            if lost:
                self.conn.close()
                raise PrognosticsError(f"{self.path}: not a history database (table {table} lacks "
                                       f"{', '.join(lost)})")

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> "HistoryStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def schema_version(self) -> int:
        return int(self.conn.execute("PRAGMA user_version").fetchone()[0])

    # ------------------------------------------------------------------ appends
    def holds_test(self, actuator_id: str, time_h: float, sim_time_s: float | None) -> bool:
        """Whether the store has this test by another path: the same actuator, operating time and
        window stamp (a monitor appends a test live, hashed by its channels; ``history add`` or a
        batch of the monitor's log brings it again, hashed by the file). No stamp: not known. Only
        for a test read from a file: a live test at a stored time and stamp is another session's
        (a simulated clock restarts at 0), :meth:`add_tests`."""
        return sim_time_s is not None and self.conn.execute(
            "SELECT 1 FROM tests WHERE actuator_id = ? AND time_h = ? AND sim_time_s = ?",
            (actuator_id, float(time_h), float(sim_time_s))).fetchone() is not None

    def holds_values(self, r: HealthRecord) -> bool:
        """Whether the store has a test of the same actuator at the same time with the same three
        K: the same test, hashed otherwise (a HISTORY.csv row imported again after a std column
        was added to it, or imported under schema version 1, whose hash held the estimated std)."""
        return self.conn.execute(
            "SELECT 1 FROM tests WHERE actuator_id = ? AND time_h = ? AND k_gm = ? AND k_fsj = ? AND k_bkl = ?",
            (r.actuator_id, float(r.time_h), *map(float, r.k))).fetchone() is not None

    def find_recording(self, source_hash: str) -> dict | None:
        """The stored test with this source hash (actuator_id, time_h), or None."""
        row = self.conn.execute("SELECT actuator_id, time_h FROM tests WHERE source_hash = ?",
                                (source_hash,)).fetchone()
        return None if row is None else {"actuator_id": row[0], "time_h": row[1]}

    def count_tests(self) -> int:
        return int(self.conn.execute("SELECT COUNT(*) FROM tests").fetchone()[0])

    def check_next_time(self, actuator_id: str, time_h: float, sim_time_s: float | None, where: str,
                        latest: dict[str, float] | None = None, backfill: bool = False) -> None:
        """Raise the error :meth:`add_tests` would give a test of ``actuator_id`` at ``time_h``
        (a bad actuator id or time, out of order, a duplicate), before the work of diagnosing it; a test the store holds by
        another path (:meth:`holds_test`) passes: adding it is a no-op. ``latest``: the store's
        :meth:`latest_times`, where the caller checks many; ``backfill``: a test older than the
        latest may come (:meth:`add_tests`)."""
        r = HealthRecord(actuator_id, float(time_h), (0.0,) * 3, (0.0,) * 3)
        check_record(r, where)
        if not self.holds_test(actuator_id, time_h, sim_time_s):
            if backfill:
                self._check_free([(where, r)])
            else:
                check_order([(where, r)], self.latest_times() if latest is None else latest)

    def has_test_at(self, actuator_id: str, time_h: float) -> bool:
        """Whether the actuator has a stored test at ``time_h`` [h] (exactly)."""
        return self.conn.execute("SELECT 1 FROM tests WHERE actuator_id = ? AND time_h = ?",
                                 (actuator_id, float(time_h))).fetchone() is not None

    def _check_free(self, items: list[tuple[str, HealthRecord]]) -> None:
        """No stored test at an item's actuator and time (a back-filled test's own check)."""
        for where, r in items:
            if self.has_test_at(r.actuator_id, r.time_h):
                raise DuplicateRow(f"{where}: duplicate row: actuator {r.actuator_id} already has a test at "
                                   f"time_h={r.time_h:g} (the history)", r)

    def usage_notes(self, records: list[HealthRecord], maintenance: list[MaintenanceRecord] | None = None) -> list[str]:
        """Notes for records whose usage count falls against the test before them, or below which
        the test after them falls, stored tests and ``records`` together in time order, where no
        replacement (stored, or in ``maintenance``: a MAINTENANCE.csv coming with the records)
        lies between (:func:`records.usage_fall_notes`; one note per actuator). Kept -- a replaced
        unit's first tests may come before its replacement is recorded -- but a usage count falls
        only then, or by a typing error (the usage rate counts from the fall,
        :meth:`ActuatorHistory.usage_per_hour`). Records the store holds already are not new."""
        replaced = replacements(maintenance)
        new: dict[str, list] = {}
        for r in records:
            if r.usage is not None:
                new.setdefault(r.actuator_id, []).append((r.time_h, r.usage, True))
        tests: dict[str, list] = {}
        for a, batch in new.items():
            # one read per actuator: its stored tests, and which of the records it holds already
            stored = self.conn.execute("SELECT time_h, usage FROM tests WHERE actuator_id = ?", (a,)).fetchall()
            held = {t for t, _u in stored}
            tests[a] = [(t, u, False) for t, u in stored if u is not None] + [x for x in batch if x[0] not in held]
            replaced.setdefault(a, []).extend(t for (t,) in self.conn.execute(
                "SELECT time_h FROM maintenance WHERE actuator_id = ? AND action = 'replace'", (a,)))
        return usage_fall_notes(tests, replaced)

    def later_tests(self, actuator_id: str, time_h: float) -> list[float]:
        """Times [h] of the actuator's stored tests after ``time_h`` whose prognosis reads a test at
        ``time_h``, in order: those before every fault has had a maintenance after it (a test after
        an ``all`` replacement does not read the old unit's tests)."""
        t = float(time_h)
        ends = [self.conn.execute("SELECT MIN(time_h) FROM maintenance WHERE actuator_id = ? AND time_h > ? "
                                  "AND fault IN (?, 'all')", (actuator_id, t, f)).fetchone()[0] for f in FAULT_KEYS]
        end = math.inf if None in ends else max(ends)
        return [u for (u,) in self.conn.execute("SELECT time_h FROM tests WHERE actuator_id = ? AND time_h > ? "
                                                "ORDER BY time_h", (actuator_id, t)) if u < end]

    def backfill_notes(self, records: list[HealthRecord]) -> list[str]:
        """Notes for records that go in before later stored tests of their actuator (``--backfill``)
        and that the store does not hold yet: the RULs given at those later tests -- published by the
        monitor, printed by ``prognose`` -- were computed without them and would now read otherwise.
        One note per actuator; call before the append."""
        by: dict[str, list[float]] = {}
        for r in records:
            by.setdefault(r.actuator_id, []).append(float(r.time_h))
        notes = []
        for a, times in sorted(by.items()):
            new = [t for t in sorted(set(times)) if not self.has_test_at(a, t)]
            later = self.later_tests(a, new[0]) if new else []
            new = [t for t in new if later and t < later[-1]]      # a stored test after it
            if new:
                notes.append(backfill_note(a, new, later))
        return notes

    def _writable(self) -> None:
        if self.readonly:
            raise PrognosticsError(f"{self.path}: opened read-only; nothing written")

    def latest_times(self) -> dict[str, float]:
        """Each actuator's latest stored test time [h]."""
        return {a: t for a, t in self.conn.execute("SELECT actuator_id, MAX(time_h) FROM tests GROUP BY actuator_id")}

    def add_tests(self, records: list[HealthRecord], wheres: list[str] | None = None, backfill: bool = False) -> int:
        """Append validated records in one transaction; returns the rows added.

        Each actuator's tests come in time order, after its latest stored one -- or, with
        ``backfill``, at any time the actuator has no test at yet (a recording that failed once and
        is fixed, an older log found later; a repair recorded after it still restarts the trend).

        A record whose ``source_hash`` is already stored for the same actuator adds nothing
        (the same recording twice); for another actuator it is an error. So does a record of a test
        the store holds by another path (:meth:`holds_values`; a record read from a file also
        :meth:`holds_test`): a live record with other K at a stored time is a duplicate row.
        """
        self._writable()
        items = self._prepare(records, wheres)
        with self._immediate():
            return self._insert_tests(items, backfill)

    @staticmethod
    def _prepare(records: list[HealthRecord], wheres: list[str] | None) -> list[tuple[str, HealthRecord]]:
        wheres = wheres or [r.where or f"test {i + 1} (actuator {r.actuator_id}, time_h={r.time_h})"
                            for i, r in enumerate(records)]
        for w, r in zip(wheres, records):
            check_record(r, w)
            r.source_hash = r.source_hash or r.content_hash()
        return list(zip(wheres, records))

    def _insert_tests(self, items: list[tuple[str, HealthRecord]], backfill: bool) -> int:
        """:meth:`add_tests` inside a write transaction."""
        known = {}
        hashes = [r.source_hash for _, r in items]
        for i in range(0, len(hashes), 500):
            part = hashes[i:i + 500]
            q = f"SELECT source_hash, actuator_id FROM tests WHERE source_hash IN ({','.join('?' * len(part))})"
            known.update(dict(self.conn.execute(q, part).fetchall()))
        new, seen = [], set()
        for w, r in items:
            owner = known.get(r.source_hash)
            if owner is not None and owner != r.actuator_id:
                raise PrognosticsError(f"{w}: this recording is already in the history for actuator {owner}")
            if owner is not None or r.source_hash in seen:
                continue
            # a live test (no file, or a log still being written) is the first path by which a test
            # comes: the same one again has its hash or its K; another diagnosis at its time and stamp
            # is a duplicate row (probe 11)
            if r.source_path is not None and not r.live and self.holds_test(r.actuator_id, r.time_h, r.sim_time_s) \
                    or self.holds_values(r):
                continue
            seen.add(r.source_hash)
            new.append((w, r))
        if backfill:
            check_order(new)
            self._check_free(new)
        else:
            check_order(new, self.latest_times())
        q = f"INSERT INTO tests ({','.join(TEST_COLUMNS)}) VALUES ({','.join('?' * len(TEST_COLUMNS))})"
        self.conn.executemany(q, [r.row() for _, r in new])
        return len(new)

    def add_diagnosis(self, diagnosis, actuator_id: str, time_h: float, usage: float | None = None,
                      usage_unit: str | None = None, source_path: str | Path | None = None,
                      response=None, sim_time_s: float | None = None, discrepancy: str | None = None,
                      source_window: int | None = None, backfill: bool = False,
                      log_path: str | Path | None = None) -> bool:
        """Append one :class:`eha_health` Diagnosis; True if a row was added (``backfill``: :meth:`add_tests`).

        The source hash is that of ``source_path`` (CSV or bag; ``source_window``: the test window
        of a bag of several, :func:`recording_hash`) if given, else of the ``response`` channels
        and the window stamp ``sim_time_s``, else of the diagnosis result itself. ``log_path``
        (without ``source_path``): the log a live test is being recorded into (the monitor's MCAP
        log), stored as ``source_path`` but not hashed -- it is still open, its hash not yet known --
        and the test is a live one (:meth:`add_tests`).
        """
        k = diagnosis.faults.as_tuple()
        std = tuple(diagnosis.std[f"k_{n}"] for n in FAULT_KEYS)
        if source_path is not None:
            if not Path(source_path).is_file():
                raise PrognosticsError(f"{source_path}: no such recording")
            h = recording_hash(source_path, source_window)
        elif response is not None:
            hh = hashlib.sha256()
            for c in ("t", "command", *MEASURED):
                hh.update(np.ascontiguousarray(getattr(response, c), float).tobytes())
            if sim_time_s is not None:
                # where the window lies: two tests of a noise-free simulation can hold the same
                # samples (every test after the first starts from the same state)
                hh.update(f"@{float(sim_time_s)!r}".encode())
            h = hh.hexdigest()
        else:
            h = None
        named = source_path if source_path is not None else log_path
        rec = HealthRecord(actuator_id, float(time_h), k, std, usage=usage, usage_unit=usage_unit, sim_time_s=sim_time_s,
                         method=diagnosis.method, cost=float(diagnosis.cost), fit_rms=dict(diagnosis.rms),
                         discrepancy=discrepancy, warnings=list(diagnosis.warnings),
                         source_path=None if named is None else str(named), source_hash=h, live=source_path is None)
        return self.add_tests([rec], [f"diagnosis for actuator {actuator_id} at time_h={time_h:g}"], backfill) == 1

    def import_csv(self, path: str | Path, records: list[HealthRecord] | None = None, backfill: bool = False) -> int:
        """Append the rows of a HISTORY.csv (each row hashed: importing twice adds nothing);
        ``records``: its rows already read (:func:`read_history_csv`); ``backfill``: :meth:`add_tests`."""
        return self.import_files(path, records=records, backfill=backfill)[0]

    def import_files(self, path: str | Path, maintenance_path: str | Path | None = None,
                     records: list[HealthRecord] | None = None,
                     maintenance: list[MaintenanceRecord] | None = None, backfill: bool = False) -> tuple[int, int]:
        """Append a HISTORY.csv and its MAINTENANCE.csv (:mod:`.history_csv`) in one transaction:
        both or nothing. Returns (tests added, actions added); what the store holds already adds
        nothing, so an export imports twice without a change. ``records`` / ``maintenance``: the
        files already read."""
        self._writable()
        if maintenance is None and maintenance_path is not None:
            maintenance = read_maintenance_csv(maintenance_path)
        recs = read_history_csv(path) if records is None else records
        items = self._prepare(recs, [r.where or f"{Path(path).name} row {i + 1}" for i, r in enumerate(recs)])
        mname = Path(maintenance_path).name if maintenance_path is not None else "maintenance"
        with self._immediate():
            n = self._insert_tests(items, backfill)
            m = self._insert_maintenance([(f"{mname} row {i + 1}", r) for i, r in enumerate(maintenance or [])],
                                         same_ok=True)
        return n, m

    def record_repair(self, actuator_id: str, fault: str, time_h: float, action: str = "repair",
                      note: str | None = None) -> None:
        """Record a repair or replacement of one fault's part (or ``all``): its trend restarts."""
        self._writable()
        with self._immediate():
            self._insert_maintenance([("", MaintenanceRecord(actuator_id, time_h, str(fault).lower().removeprefix("k_"),
                                                             action, note))])

    def _insert_maintenance(self, items: list[tuple[str, MaintenanceRecord]], same_ok: bool = False) -> int:
        """Inside a write transaction: maintenance actions of actuators with tests, none after the
        actuator's latest test (a repair "in the future"). An action on the same actuator, fault
        and time as a stored one is a duplicate -- skipped with ``same_ok`` where the action is the
        same too (an import read twice). Returns the rows added."""
        latest = self.latest_times()
        added = 0
        for where, m in items:
            at = f"{where}: " if where else ""
            check_maintenance(m, where or f"{m.action} of {m.fault} on {m.actuator_id}")
            check_maintenance_time(m, latest, where, self.path)
            row = self.conn.execute("SELECT action FROM maintenance WHERE actuator_id = ? AND time_h = ? AND fault = ?",
                                    (m.actuator_id, float(m.time_h), m.fault)).fetchone()
            if row is not None:
                if same_ok and row[0] == m.action:
                    continue
                raise PrognosticsError(f"{at}duplicate maintenance: {m.actuator_id} {m.fault} already recorded at "
                                       f"time_h={m.time_h:g} ({row[0]})")
            self.conn.execute("INSERT INTO maintenance (actuator_id, time_h, fault, action, wall_time_utc, note) "
                              "VALUES (?, ?, ?, ?, ?, ?)", (m.actuator_id, float(m.time_h), m.fault, m.action,
                                                            m.wall_time_utc or now_utc(), m.note))
            added += 1
        return added

    # ------------------------------------------------------------------ reads
    def actuator_ids(self) -> list[str]:
        return [r[0] for r in self.conn.execute("SELECT DISTINCT actuator_id FROM tests ORDER BY actuator_id")]

    def _require(self, actuator_id: str | None) -> None:
        if actuator_id is not None and actuator_id not in self.actuator_ids():
            raise PrognosticsError(f"unknown actuator {actuator_id!r} in {self.path}")

    def list_tests(self, actuator_id: str | None = None) -> list[dict]:
        """Stored tests (dicts with the schema's columns), by actuator and time; ``backfilled``:
        stored after a later test of its actuator (``--backfill``), so the RULs given at those
        later tests did not see it."""
        self._require(actuator_id)
        # the least id among the actuator's later tests (a window over time, latest first): below
        # the test's own id, a later test was stored first
        q = (f"SELECT id, {','.join(TEST_COLUMNS)}, COALESCE(MIN(id) OVER (PARTITION BY actuator_id ORDER BY "
             f"time_h DESC ROWS BETWEEN UNBOUNDED PRECEDING AND 1 PRECEDING) < id, 0) FROM tests")
        args: tuple = ()
        if actuator_id is not None:
            q, args = q + " WHERE actuator_id = ?", (actuator_id,)
        rows = self.conn.execute(q + " ORDER BY actuator_id, time_h", args).fetchall()
        out = []
        for row in rows:
            d = dict(zip(("id",) + TEST_COLUMNS + ("backfilled",), row))
            d["backfilled"] = bool(d["backfilled"])
            for c in ("fit_rms", "warnings"):
                d[c] = json.loads(d[c]) if d[c] else None
            out.append(d)
        return out

    def list_maintenance(self, actuator_id: str | None = None) -> list[dict]:
        self._require(actuator_id)
        q = "SELECT actuator_id, time_h, fault, action, wall_time_utc, note FROM maintenance"
        args: tuple = ()
        if actuator_id is not None:
            q, args = q + " WHERE actuator_id = ?", (actuator_id,)
        cols = ("actuator_id", "time_h", "fault", "action", "wall_time_utc", "note")
        return [dict(zip(cols, r)) for r in self.conn.execute(q + " ORDER BY actuator_id, time_h", args)]

    @contextlib.contextmanager
    def snapshot(self):
        """Reads in one transaction: one state of the file (a writer between two reads must not
        give a repair without its test)."""
        self.conn.execute("BEGIN")      # deferred: the snapshot is taken by the first read
        try:
            yield
        finally:
            self.conn.execute("COMMIT")

    def history(self) -> History:
        """All tests and maintenance as arrays for the prognostics, in one :meth:`snapshot`."""
        q = f"SELECT actuator_id, time_h, {','.join(K_COLUMNS + STD_COLUMNS)}, usage FROM tests"
        with self.snapshot():
            recs = [HealthRecord(a, t, (g, f, b), (sg, sf, sb), usage=u) for a, t, g, f, b, sg, sf, sb, u in
                    self.conn.execute(q)]
            reps = list(self.conn.execute("SELECT actuator_id, time_h, fault, action FROM maintenance"))
        return history_from_records(recs, reps, self.settings.history.default_std)


def _user_version(conn: sqlite3.Connection) -> int:
    """The file's ``user_version``, on a connection that decodes text it did not write (a damaged
    page) with replacement characters instead of raising mid-query."""
    conn.text_factory = lambda b: b.decode("utf-8", "replace")
    return conn.execute("PRAGMA user_version").fetchone()[0]


class LockWaitStopped(PrognosticsError):
    """A write gave up waiting for another writer's lock because its caller's ``cancelled()`` said so."""


class ReadOnlyHistory(PrognosticsError):
    """The history file or its folder is read-only: it can be read, not written."""


def backfill_note(actuator_id: str, times: list[float], later: list[float]) -> str:
    """The line said when tests at ``times`` [h] go in before the stored tests at ``later``."""
    at = ", ".join(f"{t:g}" for t in times[:5]) + (", ..." if len(times) > 5 else "")
    span = f"{later[0]:g} h" if len(later) == 1 else f"{later[0]:g}-{later[-1]:g} h"
    return (f"back-filled: actuator {actuator_id}: {len(times)} test(s) at {at} h go in before {len(later)} later "
            f"stored test(s) ({span}); the RULs given at those tests (by the monitor, by prognose) were computed "
            f"without them, and prognose now reads them in their place")


def _busy(e: sqlite3.OperationalError) -> bool:
    """Whether an SQLite error is another connection's lock (SQLITE_BUSY / SQLITE_LOCKED)."""
    return (getattr(e, "sqlite_errorcode", 0) & 0xFF) in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED)


def as_history(obj, settings: Settings | None = None, maintenance: str | Path | None = None,
               notes: list[str] | None = None) -> History:
    """A :class:`History` from a History, a HistoryStore, or a path (``.csv``: HISTORY.csv, else
    SQLite). ``maintenance``: the MAINTENANCE.csv of a HISTORY.csv (:mod:`.history_csv`); a
    SQLite history holds its own. ``notes``: gets what a HISTORY.csv read says (a last line with
    no end of line, :func:`.history_csv.read_history_csv`; a usage count that falls,
    :func:`records.batch_usage_notes`)."""
    if isinstance(obj, History):
        return obj
    if isinstance(obj, HistoryStore):
        return obj.history()
    path = Path(obj)
    if path.is_dir():
        raise PrognosticsError(f"{path}: a directory, not a history (a SQLite history file or a HISTORY.csv)")
    if not path.is_file():
        raise PrognosticsError(f"{path}: no such history file")
    if path.suffix.lower() == ".csv":
        s = settings or load_settings()
        maint = read_maintenance_csv(maintenance) if maintenance is not None else []
        recs = read_history_csv(path, notes)
        check_maintenance_times(recs, maint, path, maintenance)
        if notes is not None:
            notes += batch_usage_notes(recs, maint)
        return history_from_records(recs, [(m.actuator_id, m.time_h, m.fault, m.action) for m in maint],
                                    s.history.default_std)
    if maintenance is not None:
        raise PrognosticsError(f"{maintenance}: a MAINTENANCE.csv goes with a HISTORY.csv; the SQLite history "
                               f"{path} holds its own maintenance (eha-health history import --maintenance adds one)")
    with HistoryStore(path, settings, readonly=True) as st:
        return st.history()


# module-level conveniences for the CLI: open, act, close
def add_diagnosis(db: str | Path | None, diagnosis, actuator_id: str, time_h: float, **kw) -> bool:
    with HistoryStore(db) as st:
        return st.add_diagnosis(diagnosis, actuator_id, time_h, **kw)


def import_csv(db: str | Path | None, path: str | Path) -> int:
    with HistoryStore(db) as st:
        return st.import_csv(path)


def record_repair(db: str | Path | None, actuator_id: str, fault: str, time_h: float, **kw) -> None:
    with HistoryStore(db) as st:
        st.record_repair(actuator_id, fault, time_h, **kw)


def list_tests(db: str | Path | None, actuator_id: str | None = None) -> list[dict]:
    with HistoryStore(db, readonly=True) as st:
        return st.list_tests(actuator_id)
