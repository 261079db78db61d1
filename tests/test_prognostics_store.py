"""Health history store: a real SQLite file, real transactions, a real writer killed mid-append."""
import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from eha_health.prognostics.config import PrognosticsError, load_settings
from eha_health.prognostics.history_csv import read_history_csv
from eha_health.prognostics.records import HealthRecord
from eha_health.prognostics.store import SCHEMA_VERSION, HistoryStore, as_history, backfill_note
from waiting import wait_until

SRC = str(Path(__file__).resolve().parents[1] / "src")


def rec(a="A1", t=0.0, k=(0.1, 0.2, 0.3), std=(0.001, 0.002, 0.003), **kw):
    return HealthRecord(a, t, k, std, **kw)


def snapshot(path):
    con = sqlite3.connect(path)
    try:
        return (con.execute("SELECT * FROM tests ORDER BY id").fetchall(),
                con.execute("SELECT * FROM maintenance ORDER BY id").fetchall())
    finally:
        con.close()


def test_schema_is_versioned_and_wal(tmp_path):
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        assert st.schema_version == SCHEMA_VERSION
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    assert con.execute("SELECT version FROM schema_version").fetchall() == [(SCHEMA_VERSION,)]
    con.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    con.commit()
    con.close()
    with pytest.raises(PrognosticsError, match="newer"):
        HistoryStore(db)


def test_append_list_and_same_recording_twice(tmp_path):
    db = tmp_path / "h.sqlite"
    run = tmp_path / "run.csv"
    run.write_text("t,position\n0,1\n")
    from eha_health.prognostics.store import sha256_file
    with HistoryStore(db) as st:
        assert st.add_tests([rec(t=0.0, source_path=str(run), source_hash=sha256_file(run), usage=10.0)]) == 1
        assert st.add_tests([rec(t=50.0, k=(0.2, 0.2, 0.3))]) == 1
        # the same file again (by content hash), and the same diagnosis inputs again: no row
        assert st.add_tests([rec(t=100.0, source_hash=sha256_file(run))]) == 0
        assert st.add_tests([rec(t=50.0, k=(0.2, 0.2, 0.3))]) == 0
        rows = st.list_tests("A1")
    assert [r["time_h"] for r in rows] == [0.0, 50.0]
    assert rows[0]["usage"] == 10.0 and rows[0]["std_bkl"] == 0.003 and rows[0]["software_version"]


@pytest.mark.parametrize("bad, message", [
    ([rec(t=10.0), rec(t=5.0)], "times out of order"),
    ([rec(t=10.0), rec(t=10.0, k=(0.2, 0.2, 0.2))], "duplicate row"),
    ([rec(t=10.0), rec(t=20.0, std=(float("nan"), 0.1, 0.1))], "std_gm"),
    ([rec(t=10.0), rec(t=20.0, std=(0.1, -0.1, 0.1))], "negative"),
    ([rec(t=10.0), rec(t=20.0, k=(0.1, 1.6, 0.1))], r"k_fsj=1.6 outside \[0, 1.5\]"),
    ([rec(t=10.0), rec(t=20.0, k=(-0.01, 0.1, 0.1))], "outside"),
    ([rec(t=1.0)], "times out of order"),     # before the latest stored test
    # the stamp of a record made in Python is checked as a HISTORY.csv's is (it was not before 2026-12-07)
    ([rec(t=10.0), rec(t=20.0, sim_time_s=float("nan"))], r"sim_time_s must be a time stamp \[s\] >= 0, got nan"),
    ([rec(t=10.0, sim_time_s=-3.0)], r"sim_time_s must be a time stamp \[s\] >= 0, got -3.0"),
])
def test_bad_batches_leave_the_store_unchanged(tmp_path, bad, message):
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec(t=2.0, k=(0.0, 0.0, 0.0))])
    before = snapshot(db)
    with HistoryStore(db) as st:
        with pytest.raises(PrognosticsError, match=message) as e:
            st.add_tests(bad)
    assert "\n" not in str(e.value)
    assert isinstance(e.value, ValueError)
    assert snapshot(db) == before


def test_usage_rate_is_the_current_units(tmp_path):
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec(t=0.0, usage=0.0), rec(t=100.0, usage=180.0)])
        # a replaced unit counts from zero: its first test is appended before the replacement is
        # recorded (a repair cannot lie after the latest test), so the store takes the fall
        st.add_tests([rec(t=200.0, usage=20.0)])
        assert st.history().actuators["A1"].usage_per_hour() is None    # one test of the new unit
        st.record_repair("A1", "all", 200.0, action="replace")
        st.add_tests([rec(t=300.0, usage=200.0)])
        assert st.history().actuators["A1"].usage_per_hour() == pytest.approx(1.8)   # the new unit only
    # a usage that does not grow gives no usage RUL (its rate would be 0 or round-off)
    with HistoryStore(db) as st:
        st.add_tests([HealthRecord("B", t, (0.1, 0.2, 0.3), (0.001, 0.002, 0.003), usage=5.0)
                      for t in (0.0, 10.0, 20.0)])
        assert st.history().actuators["B"].usage_per_hour() is None


def test_repair_rules(tmp_path):
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec(t=0.0), rec(t=100.0)])
        before = snapshot(db)
        with pytest.raises(PrognosticsError, match="unknown actuator 'B'"):
            st.record_repair("B", "gm", 50.0)
        with pytest.raises(PrognosticsError, match="in the future"):
            st.record_repair("A1", "gm", 150.0)
        with pytest.raises(PrognosticsError, match="unknown fault"):
            st.record_repair("A1", "valve", 50.0)
        assert snapshot(db) == before
        st.record_repair("A1", "gm", 100.0)
        st.record_repair("A1", "all", 50.0, action="replace")
        with pytest.raises(PrognosticsError, match="duplicate maintenance"):
            st.record_repair("A1", "gm", 100.0)
        h = st.history().actuators["A1"]
        assert st.list_maintenance("A1")[0]["fault"] == "all"
    assert h.since_repair("gm").tolist() == [False, True]      # at or after the gm repair at 100 h
    assert h.since_repair("fsj").tolist() == [False, True]     # after the 'all' replacement at 50 h


def test_missing_std_is_the_series_scatter(tmp_path):
    rng = np.random.default_rng(5)
    t = np.arange(30) * 50.0
    k = np.clip(0.0008 * t + rng.normal(0, 0.02, len(t)), 0, 1.5)
    p = tmp_path / "h.csv"
    p.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\n" + "".join(f"A,{a},{b},0,0\n" for a, b in zip(t, k)))
    assert read_history_csv(p)[0].std == (None, None, None)            # not stated: estimated when read
    std = as_history(p).actuators["A"].std
    assert np.all((0.7 * 0.02 < std[:, 0]) & (std[:, 0] < 1.3 * 0.02))
    assert np.all(std[:, 1] == load_settings().history.default_std)     # a flat series: the floor


def test_missing_std_is_estimated_from_every_test_held(tmp_path):
    """The daily workflow: one test per actuator per file. Each import alone has no scatter of its
    own (schema 1 stored the floor 0.002 for every one); read, the std is the whole series'."""
    rng = np.random.default_rng(8)
    t = np.arange(25) * 40.0
    k = np.clip(0.1 + 0.0002 * t + rng.normal(0, 0.005, len(t)), 0, 1.5)
    rows = [f"A,{a},{b},0,0\n" for a, b in zip(t, k)]
    whole = tmp_path / "whole.csv"
    whole.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\n" + "".join(rows))
    with HistoryStore(tmp_path / "daily.sqlite") as st:
        for i, row in enumerate(rows):
            day = tmp_path / f"day{i}.csv"
            day.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\n" + row)
            assert st.import_csv(day) == 1
        assert all(r["std_gm"] is None for r in st.list_tests())        # stored as not stated
        daily = st.history().actuators["A"].std
    with HistoryStore(tmp_path / "once.sqlite") as st:
        assert st.import_csv(whole) == len(t)
        once = st.history().actuators["A"].std
    assert np.array_equal(daily, once) and np.array_equal(once, as_history(whole).actuators["A"].std)
    assert np.all((0.6 * 0.005 < daily[:, 0]) & (daily[:, 0] < 1.4 * 0.005)), daily[0]


V1_TESTS = """CREATE TABLE schema_version (version INTEGER NOT NULL, applied_utc TEXT NOT NULL);
CREATE TABLE tests (id INTEGER PRIMARY KEY, actuator_id TEXT NOT NULL CHECK (length(actuator_id) > 0),
    time_h REAL NOT NULL CHECK (time_h >= 0), wall_time_utc TEXT NOT NULL, sim_time_s REAL, usage REAL,
    usage_unit TEXT, k_gm REAL NOT NULL CHECK (k_gm BETWEEN 0 AND 1.5),
    k_fsj REAL NOT NULL CHECK (k_fsj BETWEEN 0 AND 1.5), k_bkl REAL NOT NULL CHECK (k_bkl BETWEEN 0 AND 1.5),
    std_gm REAL NOT NULL CHECK (std_gm >= 0), std_fsj REAL NOT NULL CHECK (std_fsj >= 0),
    std_bkl REAL NOT NULL CHECK (std_bkl >= 0), method TEXT, cost REAL, fit_rms TEXT, discrepancy TEXT,
    warnings TEXT, source_path TEXT, source_hash TEXT NOT NULL UNIQUE, software_version TEXT NOT NULL,
    UNIQUE (actuator_id, time_h));
CREATE TABLE maintenance (id INTEGER PRIMARY KEY, actuator_id TEXT NOT NULL, time_h REAL NOT NULL
    CHECK (time_h >= 0), fault TEXT NOT NULL CHECK (fault IN ('gm', 'fsj', 'bkl', 'all')),
    action TEXT NOT NULL CHECK (action IN ('repair', 'replace')), wall_time_utc TEXT NOT NULL, note TEXT,
    UNIQUE (actuator_id, time_h, fault));
CREATE INDEX tests_by_actuator ON tests (actuator_id, time_h);
INSERT INTO schema_version VALUES (1, '2026-11-20T00:00:00+00:00');
INSERT INTO tests (actuator_id, time_h, wall_time_utc, k_gm, k_fsj, k_bkl, std_gm, std_fsj, std_bkl, method,
    source_hash, software_version) VALUES ('A', 0, 'w', 0.1, 0.0, 0.0, 0.002, 0.002, 0.002, 'import', 'h0', '0.1'),
    ('A', 50, 'w', 0.2, 0.0, 0.0, 0.002, 0.002, 0.002, 'import', 'h1', '0.1');
INSERT INTO maintenance (actuator_id, time_h, fault, action, wall_time_utc) VALUES ('A', 50, 'gm', 'repair', 'w');
PRAGMA user_version = 1;
"""


def test_a_version_1_history_is_read_as_is_and_migrated_when_written(tmp_path):
    db = tmp_path / "v1.sqlite"
    con = sqlite3.connect(db)
    con.executescript(V1_TESTS)
    con.close()
    before = snapshot(db)
    with HistoryStore(db, readonly=True) as st:           # read: nothing written, not even the migration
        assert st.schema_version == 1 and len(st.list_tests()) == 2
    assert snapshot(db) == before
    with HistoryStore(db) as st:
        assert st.schema_version == SCHEMA_VERSION
        assert snapshot(db) == before                     # every row and maintenance kept, ids too
        assert st.import_csv(_csv(tmp_path, "A,100,0.3,0,0\n")) == 1
        h = st.history().actuators["A"]
    assert h.std[:2, 0].tolist() == [0.002, 0.002] and h.std[2, 0] > 0 and h.repairs == [(50.0, "gm", "repair")]
    con = sqlite3.connect(db)
    assert [v for v, _ in con.execute("SELECT * FROM schema_version ORDER BY version")] == [1, SCHEMA_VERSION]
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert con.execute("SELECT name FROM sqlite_master WHERE name = 'tests_by_actuator'").fetchone()
    con.close()


def _csv(tmp_path, rows, header="actuator_id,time_h,k_gm,k_fsj,k_bkl"):
    p = tmp_path / f"h{abs(hash(rows))}.csv"
    p.write_text(header + "\n" + rows)
    return p


def test_a_row_imported_again_with_its_std_adds_nothing(tmp_path):
    """The same test (actuator, time, three K) hashed otherwise -- its row now has a std -- is the
    same test: nothing added, not a duplicate-row error."""
    with HistoryStore(tmp_path / "h.sqlite") as st:
        assert st.import_csv(_csv(tmp_path, "A,0,0.1,0,0\nA,50,0.2,0,0\n")) == 2
        assert st.import_csv(_csv(tmp_path, "A,0,0.1,0,0,0.01,0.01,0.01\nA,50,0.2,0,0,0.01,0.01,0.01\n"
                                  "A,100,0.3,0,0,0.01,0.01,0.01\n",
                                  "actuator_id,time_h,k_gm,k_fsj,k_bkl,std_gm,std_fsj,std_bkl")) == 1
        with pytest.raises(PrognosticsError, match="duplicate row"):      # another K at that time is not
            st.import_csv(_csv(tmp_path, "A,100,0.31,0,0\n"))


def test_import_csv_twice_and_bad_csv(tmp_path):
    db = tmp_path / "h.sqlite"
    good = tmp_path / "hist.csv"
    good.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl,std_gm\nA,0,0,0,0,0.001\nA,50,0.1,0,0,0.001\n"
                    "B,0,0.2,0.1,0,\n")
    with HistoryStore(db) as st:
        assert st.import_csv(good) == 3
        assert st.import_csv(good) == 0
        # a missing std is stored as not stated, and read as the documented floor (one test)
        assert st.list_tests("B")[0]["std_gm"] is None
        assert st.history().actuators["B"].std[0, 0] == st.settings.history.default_std
    cases = {
        "actuator_id,time_h,k_gm,k_fsj\nA,0,0,0\n": "missing column",
        "actuator_id,time_h,k_gm,k_fsj,k_bkl\nA,0,0,0,x\n": "k_bkl 'x' is not a number",
        "actuator_id,time_h,k_gm,k_fsj,k_bkl\nA,50,0,0,0\nA,10,0,0,0\n": "line 3: times out of order",
        "actuator_id,time_h,k_gm,k_fsj,k_bkl\nA,50,0,0,0\nA,50,0,0,0\n": "duplicate row",
        "actuator_id,time_h,k_gm,k_fsj,k_bkl,std_gm\nA,0,0,0,0,nan\n": "std_gm",
        "actuator_id,time_h,k_gm,k_fsj,k_bkl\n": "empty",
    }
    for text, message in cases.items():
        bad = tmp_path / "bad.csv"
        bad.write_text(text)
        with pytest.raises(PrognosticsError, match=message):
            read_history_csv(bad)


WRITER = textwrap.dedent("""
    import sys
    sys.path.insert(0, {src!r})
    from eha_health.prognostics.records import HealthRecord
    from eha_health.prognostics.store import HistoryStore
    batch = int(sys.argv[2])
    with HistoryStore(sys.argv[1]) as st:
        t = 0.0
        for i in range(100000):
            recs = [HealthRecord("W", t + j, (0.1, 0.2, 0.3), (0.01, 0.01, 0.01), method="stress",
                               fit_rms={{"position": 1e-6}}, warnings=["w"] * 20) for j in range(batch)]
            st.add_tests(recs)
            t += batch
            print(i + 1, flush=True)
""")


def test_writer_killed_mid_append_leaves_no_partial_batch(tmp_path):
    db = tmp_path / "h.sqlite"
    script = tmp_path / "writer.py"
    script.write_text(WRITER.format(src=SRC))
    batch = 400
    proc = subprocess.Popen([sys.executable, str(script), str(db), str(batch)], stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        done = 0
        while done < 3:   # wait for committed batches (condition, not sleep)
            line = proc.stdout.readline()
            assert line, "writer exited early"
            done = int(line)
            assert time.monotonic() < deadline, "writer too slow"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    n = con.execute("SELECT COUNT(*) FROM tests").fetchone()[0]
    assert n >= 3 * batch and n % batch == 0
    nulls = con.execute("SELECT COUNT(*) FROM tests WHERE method IS NULL OR warnings IS NULL OR "
                        "source_hash IS NULL").fetchone()[0]
    assert nulls == 0
    con.close()
    with HistoryStore(db) as st:      # and the store still appends
        assert st.add_tests([rec("W", 1e9)]) == 1


def test_diagnosis_appended_once(tmp_path):
    """A real diagnosis of a simulated test, appended twice from the same recording: one row."""
    from eha_health import Faults, diagnose, load, simulate
    r = simulate(kind="reference", faults=Faults(0.3, 0.1, 0.0),
                 params=load("reference").with_effect_names(["sensor_noise"]), seed=3)
    csv = tmp_path / "run.csv"
    r.to_csv(csv)
    d = diagnose(r, method="deterministic", seed=0)
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        assert st.add_diagnosis(d, "A7", 12.0, source_path=csv, usage=3.0) is True
        assert st.add_diagnosis(d, "A7", 60.0, source_path=csv) is False
        assert st.add_diagnosis(d, "A7", 60.0, response=r) is True        # no file: hash of the channels
        assert st.add_diagnosis(d, "A7", 90.0, response=r) is False
        # a live monitor gives the window's stamp: the same samples at another stamp are another
        # test (a noise-free simulation repeats them: every test after the first starts alike);
        # at the same stamp, the same test
        assert st.add_diagnosis(d, "A7", 100.0, response=r, sim_time_s=8.0) is True
        assert st.add_diagnosis(d, "A7", 110.0, response=r, sim_time_s=12.0) is True
        assert st.add_diagnosis(d, "A7", 120.0, response=r, sim_time_s=12.0) is False
        rows = st.list_tests("A7")
    assert len(rows) == 4
    assert rows[0]["k_gm"] == pytest.approx(d.faults.k_gm) and rows[0]["std_gm"] == pytest.approx(d.std["k_gm"])
    assert rows[0]["method"] == "deterministic" and set(rows[0]["fit_rms"]) == set(d.rms)
    assert json.dumps(rows)   # JSON-ready for `history list --json`


def test_a_refused_or_only_read_file_is_left_byte_for_byte(tmp_path):
    from eha_health.prognostics.rul import prognose
    other = tmp_path / "other.sqlite"
    con = sqlite3.connect(other)
    con.execute("CREATE TABLE foo (x)")
    con.execute("INSERT INTO foo VALUES (1)")
    con.commit()
    con.close()
    before = other.read_bytes()
    for opener in (lambda: HistoryStore(other), lambda: HistoryStore(other, readonly=True), lambda: prognose(other)):
        with pytest.raises(PrognosticsError, match="not a history"):
            opener()
        assert other.read_bytes() == before          # was switched to WAL before it was refused
    zero = tmp_path / "zero.sqlite"
    zero.write_bytes(b"")
    with pytest.raises(PrognosticsError, match="the history is empty"):
        prognose(zero)
    with HistoryStore(zero, readonly=True) as st:
        assert st.list_tests() == [] and st.actuator_ids() == []
        with pytest.raises(PrognosticsError, match="read-only"):
            st.add_tests([rec(t=1.0)])
    assert zero.read_bytes() == b""                   # a read wrote the whole schema into it
    # a real store read while it holds tests: the same answer, and nothing written
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec(t=0.0), rec(t=10.0)])
    snap = snapshot(db)
    with HistoryStore(db, readonly=True) as st:
        assert [r["time_h"] for r in st.list_tests("A1")] == [0.0, 10.0]
        with pytest.raises(PrognosticsError, match="read-only"):
            st.record_repair("A1", "gm", 10.0)
    assert snapshot(db) == snap


def test_a_read_only_open_creates_nothing_and_writes_nothing(tmp_path):
    """A read-only open of a missing path created an empty file there, and its close checkpointed
    a -wal left by a writer into the file: now it refuses the path and leaves the file as it was."""
    missing = tmp_path / "sub" / "none.sqlite"
    for where in (missing, tmp_path / "none.sqlite"):
        with pytest.raises(PrognosticsError, match="no such history file") as err:
            HistoryStore(where, readonly=True)
        assert str(where) in str(err.value)
        assert not where.exists() and not where.parent.joinpath(where.name + "-wal").exists()
    assert not missing.parent.exists()
    with pytest.raises(PrognosticsError, match="a directory"):
        HistoryStore(tmp_path, readonly=True)
    # a writer that died with its last test in the -wal only: read, it is there; the file stays as it was
    live = sqlite3.connect(tmp_path / "live.sqlite")   # kept open: the store's close does not checkpoint
    with HistoryStore(tmp_path / "live.sqlite") as st:
        st.add_tests([rec(t=0.0), rec(t=10.0)])
        copy = tmp_path / "copy"
        copy.mkdir()
        for suffix in ("", "-wal"):
            (copy / f"h.sqlite{suffix}").write_bytes((tmp_path / f"live.sqlite{suffix}").read_bytes())
    live.close()
    db, wal = copy / "h.sqlite", copy / "h.sqlite-wal"
    before, wal_before = db.read_bytes(), wal.read_bytes()
    assert len(wal_before) > 0
    with HistoryStore(db, readonly=True) as st:
        assert [r["time_h"] for r in st.list_tests("A1")] == [0.0, 10.0]
    assert db.read_bytes() == before and wal.read_bytes() == wal_before


#: one `eha-health` process that says it is ready, then starts its command when told to go
_AT_GO = """
import os, sys
from eha_health.cli import main
ready, go = sys.argv[1:3]
open(ready, "w").close()
while not os.path.exists(go):
    pass
sys.exit(main(sys.argv[3:]))
"""


def test_writers_that_create_one_history_at_once_all_land(tmp_path):
    """`history import` processes that open a new file at the same instant: SQLite refuses the
    switch to WAL at once (no busy handler) while another holds a lock -- before, about 10 % of
    such writers died with a 'database is locked' traceback -- and each stamped the schema version.
    Now all land, and the version is stamped once."""
    writers, rounds = 4, 8
    csvs = []
    for i in range(writers):
        path = tmp_path / f"w{i}.csv"
        path.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\n" + "".join(
            f"W{i},{10.0 * j},{0.01 * j},0,0\n" for j in range(3)))
        csvs.append(path)
    failed = []
    for r in range(rounds):
        db, go = tmp_path / f"r{r}.sqlite", tmp_path / f"go{r}"
        ready = [tmp_path / f"ready{r}_{i}" for i in range(writers)]
        ps = [subprocess.Popen([sys.executable, "-c", _AT_GO, str(ready[i]), str(go), "history", "import",
                                str(c), "--history", str(db)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               text=True) for i, c in enumerate(csvs)]
        # every writer imported and ready -- or one exited before (its error is reported below)
        names = [f"writer {i}" for i in range(writers)]
        wait_until(lambda: all(x.exists() for x in ready) or any(p.poll() is not None for p in ps), 300,
                   "every writer ready", dict(zip(names, ps)), may_exit=names)
        go.touch()
        outs = [(p.wait(timeout=300), p.stderr.read()) for p in ps]
        failed += [(r, rc, err.strip().splitlines()[-1:]) for rc, err in outs if rc != 0]
        con = sqlite3.connect(db)
        assert con.execute("SELECT COUNT(*) FROM tests").fetchone()[0] == 3 * sum(rc == 0 for rc, _ in outs)
        assert con.execute("SELECT version FROM schema_version").fetchall() == [(SCHEMA_VERSION,)]
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        con.close()
    assert not failed, failed


def test_a_history_locked_past_the_busy_timeout_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    from eha_health.cli import main
    from eha_health.prognostics import store
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec("A1", 0.0)])
    before = snapshot(db)
    csv_path = tmp_path / "more.csv"
    csv_path.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\nA1,10,0.1,0.2,0.3\n")
    other = sqlite3.connect(db, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")          # another writer that holds its transaction
    monkeypatch.setattr(store, "BUSY_TIMEOUT_S", 0.5)    # the 60 s default, shortened for the test
    try:
        with pytest.raises(PrognosticsError, match="locked by another process.*nothing was written"):
            with HistoryStore(db) as st:
                st.add_tests([rec("A1", 10.0)])
        assert main(["history", "import", str(csv_path), "--history", str(db)]) == 2
        err = capsys.readouterr().err.strip()
        assert "locked by another process" in err and len(err.splitlines()) == 1
        # readers are not held up by a writer (WAL)
        assert len(as_history(db).actuators["A1"].time_h) == 1
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert snapshot(db) == before


def test_a_history_is_read_as_one_snapshot(tmp_path):
    """A writer that commits a post-repair test and its repair between the read of the tests and
    the read of the maintenance: the history read holds neither (before, it held the repair without
    the test: a state the file never held, and the fault had 0 tests since its repair)."""
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec("A1", 10.0 * i, (0.01 * i, 0.0, 0.0)) for i in range(6)])
    with HistoryStore(db, readonly=True) as st:
        fired = []

        def writer_between(stmt):
            if "FROM maintenance" in stmt and not fired:
                fired.append(stmt)
                with HistoryStore(db) as w:
                    w.add_tests([rec("A1", 60.0, (0.0, 0.0, 0.0))])
                    w.record_repair("A1", "gm", 55.0)

        st.conn.set_trace_callback(writer_between)
        h = st.history().actuators["A1"]
        st.conn.set_trace_callback(None)
    assert fired
    assert len(h.time_h) == 6 and h.repairs == []
    h = as_history(db).actuators["A1"]
    assert len(h.time_h) == 7 and h.since_repair("gm").sum() == 1


def test_no_store_is_made_of_a_csv_path_a_bad_import_or_an_id_with_spaces(tmp_path, capsys):
    from eha_health.cli import main
    with pytest.raises(PrognosticsError, match="HISTORY.csv is read, not written"):
        HistoryStore(tmp_path / "h.csv")
    assert not (tmp_path / "h.csv").exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\nA1,10,2.0,0,0\n")
    assert main(["history", "import", str(bad), "--history", str(tmp_path / "new.sqlite")]) == 2
    assert "k_gm" in capsys.readouterr().err and not (tmp_path / "new.sqlite").exists()
    # a CSV's cells are stripped when read; an id given otherwise (the monitor's parameter, the API) is checked
    with HistoryStore(tmp_path / "new.sqlite") as st:
        st.add_tests([rec("A1", 10.0)])
        with pytest.raises(PrognosticsError, match="actuator id 'A1 ' has leading or trailing spaces"):
            st.add_tests([rec("A1 ", 20.0)])
        assert [r["actuator_id"] for r in st.list_tests()] == ["A1"]


def test_a_test_older_than_the_latest_goes_in_only_with_backfill(tmp_path, capsys):
    """The store takes an actuator's tests in time order; a recording that failed once and was
    fixed, or an older log found later, goes in with backfill -- where the actuator has no test at
    that time -- and the history reads it in its place."""
    from eha_health.cli import main
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec("A1", t, (0.01 * t / 10, 0.0, 0.0), usage=2.0 * t) for t in (0.0, 10.0, 30.0, 40.0)])
        st.record_repair("A1", "gm", 40.0)
        before = snapshot(db)
        with pytest.raises(PrognosticsError, match="times out of order.*--backfill"):
            st.add_tests([rec("A1", 20.0, (0.02, 0.0, 0.0), usage=40.0)])
        assert snapshot(db) == before
        with pytest.raises(PrognosticsError, match="duplicate row.*time_h=30"):
            st.add_tests([rec("A1", 30.0, (0.5, 0.0, 0.0))], backfill=True)
        assert st.add_tests([rec("A1", 20.0, (0.02, 0.0, 0.0), usage=40.0)], backfill=True) == 1
        assert st.add_tests([rec("A1", 20.0, (0.02, 0.0, 0.0), usage=40.0)], backfill=True) == 0   # the same again
        # a usage above the next stored test's is kept, with a note
        assert "below the 99 of the test back-filled at time_h=25" in " ".join(
            st.usage_notes([rec("A1", 25.0, usage=99.0)]))
        # ... also where it is not the batch's first usage (only the first was looked at: an
        # independent probe, 2026-11-29), and a fall within the batch itself
        assert "below the 99 of the test back-filled at time_h=25" in " ".join(
            st.usage_notes([rec("A1", 5.0, usage=10.0), rec("A1", 25.0, usage=99.0)]))
        assert "usage falls for actuator A2: 3 at time_h=60 after 8 at time_h=50; kept" in " ".join(
            st.usage_notes([rec("A2", 50.0, usage=8.0), rec("A2", 60.0, usage=3.0)]))
    h = as_history(db).actuators["A1"]
    assert h.time_h.tolist() == [0.0, 10.0, 20.0, 30.0, 40.0] and h.since_repair("gm").sum() == 1
    old = tmp_path / "old.csv"
    old.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\nA1,5,0.005,0,0\nA1,15,0.015,0,0\n")
    assert main(["history", "import", str(old), "--history", str(db)]) == 2
    assert "--backfill" in capsys.readouterr().err
    assert main(["history", "import", str(old), "--history", str(db), "--backfill"]) == 0
    assert as_history(db).actuators["A1"].time_h.tolist() == [0.0, 5.0, 10.0, 15.0, 20.0, 30.0, 40.0]
    # the RULs given at the later tests did not see them: said once per actuator, the first's later tests
    err = capsys.readouterr().err
    assert "back-filled: actuator A1: 2 test(s) at 5, 15 h go in before 4 later stored test(s) (10-40 h)" in err
    assert main(["history", "import", str(old), "--history", str(db), "--backfill"]) == 0   # held: nothing to say
    assert "back-filled" not in capsys.readouterr().err
    # and the history keeps saying which tests came in after later ones
    with HistoryStore(db, readonly=True) as st:
        assert {t["time_h"]: t["backfilled"] for t in st.list_tests("A1")} == {
            0.0: False, 5.0: True, 10.0: False, 15.0: True, 20.0: True, 30.0: False, 40.0: False}
    assert main(["history", "list", "--history", str(db)]) == 0
    out = capsys.readouterr().out
    assert sum("(back-filled" in line for line in out.splitlines()) == 3


def test_a_back_filled_test_is_said_to_change_only_the_tests_before_every_fault_restarts(tmp_path):
    """A test back-filled at 275 h before an `all` replacement at 575 h: the note named all 15 later
    tests (300-1000 h), though the tests from 600 h on read only the new unit's (an independent
    probe, 2026-11-29). One fault repaired alone leaves the others reading it."""
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec("R", 50.0 * i) for i in range(1, 21)])
        st.record_repair("R", "gm", 425.0)
        assert st.later_tests("R", 275.0) == [50.0 * i for i in range(6, 21)]     # fsj, bkl still read it
        st.record_repair("R", "all", 575.0, action="replace")
        assert st.later_tests("R", 275.0) == [300.0, 350.0, 400.0, 450.0, 500.0, 550.0]
        assert st.later_tests("R", 800.0) == [850.0, 900.0, 950.0, 1000.0]
        note = st.backfill_notes([rec("R", 275.0)])
    assert note == [backfill_note("R", [275.0], [300.0, 350.0, 400.0, 450.0, 500.0, 550.0])]
    assert "6 later stored test(s) (300-550 h)" in note[0]


def _read_only_folder(folder: Path):
    """A runner of argv with ``folder`` read-only, as on a read-only medium: a non-root process
    runs with the folder chmod 0555; root ignores permissions, so it runs in a user and mount
    namespace where the folder is bind-mounted read-only (EROFS, no privilege needed), or the
    test is skipped where the kernel forbids that."""
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    if os.geteuid() != 0:
        def run(argv):
            folder.chmod(0o555)
            try:
                return subprocess.run(argv, capture_output=True, text=True, env=env, timeout=600)
            finally:
                folder.chmod(0o755)
        return run
    wrap = ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
            'mount --bind -o ro "$0" "$0" && exec "$@"', str(folder)]
    try:
        probe = subprocess.run(wrap + ["sh", "-c", 'touch "$0/x"', str(folder)], capture_output=True, timeout=60)
    except FileNotFoundError:
        pytest.skip("running as root, and no unshare(1) for a read-only bind mount")
    if probe.returncode == 0 or (folder / "x").exists():
        pytest.skip(f"running as root, and no unprivileged read-only bind mount here: {probe.stderr!r}")
    return lambda argv: subprocess.run(wrap + argv, capture_output=True, text=True, env=env, timeout=600)


def test_a_history_on_a_read_only_medium_is_read_and_writers_say_it_is_read_only(tmp_path):
    """WAL needs a -shm beside the file, which SQLite cannot create on a read-only medium: the
    readers read the file as it is, the writers say what is read-only (probe 11 found all of
    them saying "not a history database")."""
    ro = tmp_path / "ro"
    ro.mkdir()
    db = ro / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([rec("ACT-7", t, k=(0.01 * i, 0.02 * i, 0.0)) for i, t in enumerate((100.0, 500.0, 1000.0))])
    assert sorted(p.name for p in ro.iterdir()) == ["h.sqlite"]      # closed: no -wal, no -shm
    before, stored = db.read_bytes(), snapshot(db)
    csv_in = tmp_path / "more.csv"
    csv_in.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\nACT-7,1100,0.05,0.06,0\n")
    run = _read_only_folder(ro)
    cli = [sys.executable, "-m", "eha_health.cli"]

    got = run(cli + ["history", "list", "--history", str(db), "--json"])
    assert got.returncode == 0, got.stderr
    assert [t["time_h"] for t in json.loads(got.stdout)["tests"]] == [100.0, 500.0, 1000.0]
    got = run(cli + ["prognose", "--actuator", "ACT-7", "--history", str(db), "--json"])
    assert got.returncode == 0, got.stderr
    assert "ACT-7" in json.loads(got.stdout)["actuators"]

    for argv in (["history", "repair", "--actuator", "ACT-7", "--fault", "gm", "--time-h", "1000"],
                 ["history", "import", str(csv_in)]):
        got = run(cli + argv + ["--history", str(db)])
        assert got.returncode == 2 and got.stdout == ""
        line, = got.stderr.splitlines()
        assert "read-only" in line and "nothing written" in line and "not a history" not in line, line
    got = run(cli + ["history", "import", str(csv_in), "--history", str(ro / "new.sqlite")])
    assert got.returncode == 2 and "its folder" in got.stderr and "read-only" in got.stderr, got.stderr

    # the monitor's step: the test is not appended, and says why; the RUL is the stored history's
    step = textwrap.dedent(f"""
        import json
        from eha_health import Faults, diagnose, load, simulate
        from eha_health.monitoring.prognosis import PrognosisStep
        r = simulate(kind="reference", faults=Faults(k_gm=0.02),
                     params=load("reference").with_effect_names(["sensor_noise"]), seed=5)
        d = diagnose(r, method="deterministic")
        out = PrognosisStep({str(db)!r}, "ACT-7").after_diagnosis(d, 1100.0)
        new = PrognosisStep({str(ro / "new.sqlite")!r}, "ACT-7").after_diagnosis(d, 1100.0)
        print(json.dumps({{"appended": out.appended, "error": out.error, "rul": out.prognosis is not None,
                          "new": new.error}}))
    """)
    got = run([sys.executable, "-c", step])
    assert got.returncode == 0, got.stderr
    out = json.loads(got.stdout.splitlines()[-1])
    assert not out["appended"] and out["rul"], out
    assert "not appended" in out["error"] and "read-only" in out["error"] and "not a history" not in out["error"]
    # no file there to read either: the error says the folder is read-only, not that the file is missing
    assert "not appended" in out["new"] and "read-only" in out["new"] and "no such" not in out["new"], out

    assert db.read_bytes() == before and snapshot(db) == stored
    assert sorted(p.name for p in ro.iterdir()) == ["h.sqlite"]

    # a -wal left with changes not in the file (a writer that died): read immutable, the file would
    # lack them, so the reader refuses and says what to do
    live = sqlite3.connect(tmp_path / "live.sqlite")   # open while copied: its -wal holds the tests
    with HistoryStore(tmp_path / "live.sqlite") as st:
        st.add_tests([rec("ACT-7", 100.0)])
        for suffix in ("", "-wal"):
            (ro / f"w.sqlite{suffix}").write_bytes((tmp_path / f"live.sqlite{suffix}").read_bytes())
    live.close()
    got = run(cli + ["history", "list", "--history", str(ro / "w.sqlite")])
    assert got.returncode == 2 and "w.sqlite-wal" in got.stderr and "copy" in got.stderr, got.stderr
