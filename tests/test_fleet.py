"""Fleet batch on a real Dask LocalCluster (worker processes, loopback), a real SQLite store,
real bags and CSVs from ``fleet simulate``; kill-and-resume with a client killed by SIGKILL."""
from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

pytest.importorskip("distributed")

from eha_health.bench.fleet import simulate_fleet  # noqa: E402
from eha_health.cli import main as cli_main  # noqa: E402
from eha_health.fleet import (FleetError, diagnose_fleet, failures_path, find_recordings,  # noqa: E402
                              read_manifest)
from eha_health.fleet.batch import WORKER_ENVIRON, dask_client, format_summary  # noqa: E402
from waiting import wait_until  # noqa: E402
from eha_health.fleet.recordings import Recording, complete_identity  # noqa: E402
from eha_health.prognostics.store import HistoryStore, backfill_note, sha256_file  # noqa: E402

METHOD = "deterministic"   # the fastest real method keeps these tests short; the bench runs the default
ROOT = Path(__file__).resolve().parents[1]


def _rows(db: Path) -> list[dict]:
    with HistoryStore(db) as st:
        return st.list_tests()


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fleet_bags")
    simulate_fleet(2, 2, seed=3, out=out, fmt="mcap")
    return out


@pytest.fixture(scope="module")
def client():
    before = {k: os.environ.get(k) for k in WORKER_ENVIRON}
    with dask_client(workers=2) as c:
        # the nanny's pre-spawn environment stays out of this process (a numba compile here would
        # otherwise raise: threads launched at one NUMBA_NUM_THREADS, the config read at another)
        assert {k: os.environ.get(k) for k in WORKER_ENVIRON} == before
        yield c
    assert {k: os.environ.get(k) for k in WORKER_ENVIRON} == before


def test_numba_compiles_in_this_process_after_a_local_cluster():
    """numba's threads launched here, then a LocalCluster (its nanny applies the workers'
    NUMBA_NUM_THREADS=1 to this process's environment), then a function compiled here: numba
    re-reads its config at every compile and raised when the variable had changed since its
    threads started (prognose after a fleet batch, with its filter not yet in the cache)."""
    import numba
    import numpy as np

    @numba.njit(parallel=True)
    def total(x):
        s = 0.0
        for i in numba.prange(len(x)):
            s += x[i]
        return s
    assert total(np.ones(8)) == 8.0                     # the thread pool is up
    with dask_client(workers=1, setup=False) as c:
        assert c.submit(int, "3").result(timeout=120) == 3

    @numba.njit
    def plus_one(x):                                    # compiled now, after the cluster
        return x + 1
    assert plus_one(1) == 2


def test_simulate_is_reproducible_and_the_manifest_points_at_its_files(bags, tmp_path):
    recs = read_manifest(bags / "manifest.csv")
    assert len(recs) == 4 and {r.actuator_id for r in recs} == {"U000", "U001"}
    for r in recs:
        assert r.path.is_file() and r.path.is_relative_to(bags.resolve())
    # a folder: the recordings in its sub-folders, identified by the manifest above them
    found = sorted(find_recordings([bags]), key=lambda r: str(r.path))
    assert [(r.path, r.actuator_id, r.time_h) for r in found] == \
        [(r.path, r.actuator_id, r.time_h) for r in sorted(recs, key=lambda r: str(r.path))]
    # the last tests of each actuator are degraded, the first ones healthy (the run-to-failure laws)
    assert all(max(r.truth.values()) == 0.0 for r in recs if r.time_h == 0.0)
    assert all(max(r.truth.values()) > 0.2 for r in recs if r.time_h > 0.0)
    again = tmp_path / "again"
    simulate_fleet(2, 2, seed=3, out=again, fmt="mcap")
    assert (again / "manifest.csv").read_text() == (bags / "manifest.csv").read_text()
    for r in recs:
        assert sha256_file(r.path) == sha256_file(again / r.path.relative_to(bags.resolve()))
    other = tmp_path / "other"
    simulate_fleet(2, 2, seed=4, out=other, fmt="csv")
    assert (other / "manifest.csv").read_text() != (bags / "manifest.csv").read_text()


def test_bag_metadata_names_the_actuator_and_time(bags, tmp_path):
    src = read_manifest(bags / "manifest.csv")[1]
    shutil.copy(src.path, tmp_path / "lone.mcap")
    (tmp_path / "notes.csv").write_text("t,command\n0,0\n")
    found = {r.path.name: r for r in find_recordings([tmp_path])}
    complete_identity(found["lone.mcap"])
    assert (found["lone.mcap"].actuator_id, found["lone.mcap"].time_h, found["lone.mcap"].usage) == \
        (src.actuator_id, src.time_h, src.usage)
    with pytest.raises(FleetError, match="CSV recording has no metadata"):
        complete_identity(found["notes.csv"])
    # cut off (no summary): the metadata, written first, is still found by reading the file through
    (tmp_path / "cut.mcap").write_bytes(src.path.read_bytes()[:200_000])
    cut = Recording(tmp_path / "cut.mcap")
    complete_identity(cut)
    assert (cut.actuator_id, cut.time_h) == (src.actuator_id, src.time_h)
    (tmp_path / "bare.mcap").write_bytes(src.path.read_bytes()[:8] + b"\0" * 64)
    with pytest.raises(ValueError):
        complete_identity(Recording(tmp_path / "bare.mcap"))


def test_manifest_paths_may_not_leave_its_folder(tmp_path, capsys):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "manifest.csv").write_text("actuator_id,time_h,path\nA1,0,../secret.mcap\n")
    with pytest.raises(FleetError, match="leaves the manifest's folder"):
        read_manifest(tmp_path / "m" / "manifest.csv")
    (tmp_path / "m" / "manifest.csv").write_text("actuator_id,time_h,path\nA1,-3,a.mcap\n")
    rc = cli_main(["fleet", "diagnose", "--manifest", str(tmp_path / "m" / "manifest.csv"),
                   "--history", str(tmp_path / "h.sqlite")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "time_h must be a finite number >= 0" in err[0]
    assert cli_main(["fleet", "simulate", "--actuators", "0", "--tests", "2", "--out", str(tmp_path / "x")]) == 2


def test_fleet_diagnose_on_a_local_cluster_is_idempotent_and_logs_failures(bags, client, tmp_path):
    db = tmp_path / "history.sqlite"
    recs = read_manifest(bags / "manifest.csv")
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n" + b"not a bag" * 50)
    (tmp_path / "manifest.csv").write_text(
        "actuator_id,time_h,path\nU900,5,broken.mcap\nU901,5,missing.csv\n")
    bad = read_manifest(tmp_path / "manifest.csv")
    # three recordings per task: a failed file in a task with good ones fails alone
    s = diagnose_fleet(recs + bad, db, method=METHOD, client=client, per_task=3)
    assert (s["diagnosed"], s["skipped"], s["failed"]) == (4, 0, 2), s
    reasons = {Path(f["path"]).name: f["reason"] for f in s["failures"]}
    assert "broken.mcap" in reasons["broken.mcap"] and "cannot read" in reasons["missing.csv"]
    logged = failures_path(db).read_text().splitlines()
    assert logged[0].startswith("wall_time_utc,path,source_hash") and len(logged) == 3
    rows = _rows(db)
    assert len(rows) == 4
    for row, rec in zip(sorted(rows, key=lambda r: r["source_path"]), sorted(recs, key=lambda r: str(r.path))):
        assert (row["actuator_id"], row["time_h"], row["usage"]) == (rec.actuator_id, rec.time_h, rec.usage)
        assert row["source_hash"] == sha256_file(rec.path) and row["method"] == METHOD
        for k, name in zip(("k_gm", "k_fsj", "k_bkl"), ("k_gm", "k_fsj", "k_bkl")):
            assert abs(row[k] - rec.truth[name]) < 0.05, (row, rec.truth)
    # set up once per worker, numba on one thread inside the tasks, the work spread over both workers
    assert len(s["worker_setup"]) == 2 and all(w["setups"] == 1 for w in s["worker_setup"])
    assert all(w["numba_threads"] == 1 for w in s["worker_setup"]) and s["task_numba_threads"] == [1]
    assert sum(w["tasks"] for w in s["worker_setup"]) == 5   # broken.mcap ran and failed on a worker
    # worker processes start without Dask's malloc trim threshold (it turns glibc's adaptive mmap
    # threshold off: thousands of page faults per diagnosis) and with numba's pool at one thread
    env = client.run(lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("NUMBA_NUM_THREADS")))
    assert set(env.values()) == {(None, "1")}, env
    again = diagnose_fleet(recs, db, method=METHOD, client=client)
    assert (again["diagnosed"], again["skipped"], again["failed"]) == (0, 4, 0)
    assert len(_rows(db)) == 4


def _count(db: Path) -> int:
    if not db.is_file():
        return 0
    try:
        with sqlite3.connect(db, timeout=30) as c:
            return c.execute("SELECT count(*) FROM tests").fetchone()[0]
    except sqlite3.OperationalError:   # the schema is not created yet
        return 0


def test_a_client_killed_mid_batch_resumes_with_no_duplicate_and_no_lost_row(client, tmp_path):
    fleet = tmp_path / "csv_fleet"
    simulate_fleet(2, 5, seed=11, out=fleet, fmt="csv")
    recs = read_manifest(fleet / "manifest.csv")
    db = tmp_path / "history.sqlite"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "eha_health.cli", "fleet", "diagnose", "--manifest",
                             str(fleet / "manifest.csv"), "--history", str(db), "--workers", "1", "--method", METHOD],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    started = []
    try:
        wait_until(lambda: _count(db) >= 2, 600, "the killed client's first stored rows", {"client": proc})
        started = psutil.Process(proc.pid).children(recursive=True)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        for p in started:   # the worker processes this test started through the client it killed
            try:
                p.kill()
            except psutil.NoSuchProcess:
                pass
    before = _count(db)
    assert 2 <= before < len(recs), f"the client finished {before} of {len(recs)} before the kill: no resume tested"
    with sqlite3.connect(db) as c:
        assert c.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    s = diagnose_fleet(recs, db, method=METHOD, client=client)
    assert (s["skipped"], s["diagnosed"], s["failed"]) == (before, len(recs) - before, 0), s
    rows = _rows(db)
    assert len(rows) == len(recs) == len({r["source_hash"] for r in rows})
    assert {(r["actuator_id"], r["time_h"]) for r in rows} == {(r.actuator_id, r.time_h) for r in recs}


def test_dask_config_gives_hand_started_workers_the_local_cluster_settings(tmp_path, capsys):
    """``fleet dask-config`` written where Dask looks: a worker's nanny would spawn it with the
    same environment as a LocalCluster's (Dask's malloc trim threshold removed, numba on one
    thread) and the same worker settings (read by a fresh interpreter, as ``dask worker`` does)."""
    assert cli_main(["fleet", "dask-config"]) == 0
    (tmp_path / "eha-health.yaml").write_text(capsys.readouterr().out)
    probe = ("import json, dask, distributed\n"
             "from distributed.nanny import _get_env_variables\n"
             "print(json.dumps([_get_env_variables('distributed.nanny.pre-spawn-environ'),\n"
             "                  dask.config.get('distributed.worker.profile.enabled'),\n"
             "                  dask.config.get('distributed.admin.tick.interval')]))\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    out = subprocess.run([sys.executable, "-c", probe], env={**env, "DASK_CONFIG": str(tmp_path)},
                         capture_output=True, text=True, check=True).stdout
    spawn_env, profile, tick = json.loads(out)
    assert "MALLOC_TRIM_THRESHOLD_" not in spawn_env and spawn_env["NUMBA_NUM_THREADS"] == "1"
    assert spawn_env["OMP_NUM_THREADS"] == "1" and profile is False and tick == "1s"


def test_a_csv_that_starts_before_the_test_and_lacks_a_column_is_diagnosed_and_says_so(tmp_path):
    """A fleet's CSV from a logger started 0.3 s before the test, with no current column: the worker's
    task cuts it where the command starts the sequence, diagnoses it from the channels it has, and the
    cut leads its warnings (before: one line, a missing column, and no diagnosis)."""
    import numpy as np
    from eha_health import Faults, simulate
    from eha_health.fleet.worker import diagnose_recording
    from eha_health.physics.params import load
    truth = (0.3, 0.4, 0.3)
    r = simulate(params=load("reference").with_effect_names(["sensor_noise"]), faults=Faults(*truth), seed=777)
    cols = ("t", "command", "position", "velocity", "pressure")
    rest = 300
    data = [np.arange(len(r.t) + rest) / 1000.0] + [np.concatenate([np.full(rest, getattr(r, c)[0]), getattr(r, c)])
                                                    for c in cols[1:]]
    f = tmp_path / "pretrigger_no_current.csv"
    np.savetxt(f, np.column_stack(data), delimiter=",", header=",".join(cols), comments="")
    out = diagnose_recording(str(f), load("monitor"))
    assert "error" not in out, out.get("error")
    assert max(abs(k - v) for k, v in zip(out["k"], truth)) <= 0.01, out["k"]
    assert out["warnings"][0].startswith("the FDI test starts at t = 0.3 s") and set(out["rms"]) == set(cols[2:])


def test_a_monitor_log_of_several_tests_is_one_recording_per_test(client, tmp_path, capsys):
    """A monitor log holds every test it appended (metadata history/test_<id> each): the batch
    diagnoses each test window, stores each once, and 'history add --test' knows them as the same
    recordings. Before, the batch took the file's first window only."""
    from eha_health import Faults, load, simulate
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    p = load("reference").with_effect_names(["sensor_noise"])
    bag, db = tmp_path / "monitor_log.mcap", tmp_path / "h.sqlite"
    truth = {1: 0.30, 2: 0.33, 3: 0.36}
    with BagWriter(bag) as w:
        w.add_metadata("eha_health", {"actuator_id": "ACT-9"})
        for tid, k in truth.items():
            write_run(w, simulate(kind="reference", faults=Faults(k_gm=k), params=p, seed=tid), test_id=tid,
                      start_ns=tid * 8_000_000_000)
            w.add_metadata(f"history/test_{tid}", {"time_h": f"{100 * tid}", "usage": f"{250 * tid}",
                                                   "sim_time_s": f"{8.0 * tid}"})
    # test 1 was appended live by the monitor that wrote the log (its row hashed by the channels)
    from eha_health.prognostics.records import HealthRecord
    with HistoryStore(db) as st:
        st.add_tests([HealthRecord("ACT-9", 100.0, (0.3, 0.0, 0.0), (0.001,) * 3, usage=250.0, sim_time_s=8.0,
                                   source_hash="live-monitor-row")])
    s = diagnose_fleet(find_recordings([bag]), db, method=METHOD, client=client)
    assert (s["diagnosed"], s["skipped"], s["failed"]) == (2, 1, 0), s      # test 1: the same test, not again
    assert (s["recordings"], s["files"]) == (3, 1)
    rows = _rows(db)
    assert [(r["actuator_id"], r["time_h"], r["usage"]) for r in rows] == [
        ("ACT-9", 100.0, 250.0), ("ACT-9", 200.0, 500.0), ("ACT-9", 300.0, 750.0)]
    assert [r["k_gm"] for r in rows] == [pytest.approx(k, abs=0.02) for k in truth.values()]
    assert len({r["source_hash"] for r in rows}) == 3 and [r["sim_time_s"] for r in rows] == [8.0, 16.0, 24.0]
    again = diagnose_fleet(find_recordings([bag]), db, method=METHOD, client=client)
    assert (again["diagnosed"], again["skipped"], again["failed"]) == (0, 3, 0)
    assert cli_main(["history", "add", str(bag), "--test", "2", "--actuator", "ACT-9", "--history", str(db),
                     "--quiet"]) == 0
    assert "already in" in capsys.readouterr().out and len(_rows(db)) == 3
    # the test the monitor appended live, given another time or actuator: refused, not stored twice
    for other in (["--actuator", "ACT-9", "--time-h", "5"], ["--actuator", "OTHER", "--time-h", "400"]):
        assert cli_main(["history", "add", str(bag), "--test", "1", "--history", str(db), "--quiet", *other]) == 2
        err = capsys.readouterr().err
        assert "the monitor appended it live for actuator ACT-9 at time_h 100" in err, err
    assert cli_main(["history", "add", str(bag), "--test", "3", "--actuator", "ACT-9 ", "--time-h", "400",
                     "--history", str(db), "--quiet"]) == 2
    assert "leading or trailing spaces" in capsys.readouterr().err and len(_rows(db)) == 3


def _monitor_log(path, truth: dict, records: dict, actuator="ACT-7", extra: dict | None = None):
    """A monitor log of tests ``truth`` {test id: K_GM} whose ``records`` {test id: time_h} it appended."""
    from eha_health import Faults, load, simulate
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    p = load("reference").with_effect_names(["sensor_noise"])
    path.parent.mkdir(parents=True, exist_ok=True)
    with BagWriter(path) as w:
        w.add_metadata("eha_health", {"actuator_id": actuator, **(extra or {})})
        for tid, k in truth.items():
            write_run(w, simulate(kind="reference", faults=Faults(k_gm=k), params=p, seed=tid), test_id=tid,
                      start_ns=tid * 8_000_000_000)
            if tid in records:
                w.add_metadata(f"history/test_{tid}", {"time_h": f"{records[tid]}", "sim_time_s": f"{8.0 * tid}"})
    return path


def test_a_monitor_log_with_one_appended_test_of_several_stores_that_test(client, tmp_path):
    """A monitor whose store refused its first two tests logs three windows and one record
    (history/test_3): before, the batch stored window 1's diagnosis under test 3's time."""
    bag = _monitor_log(tmp_path / "log.mcap", {1: 0.1, 2: 0.3, 3: 0.5}, {3: 30.0})
    s = diagnose_fleet(find_recordings([bag]), tmp_path / "h.sqlite", method=METHOD, client=client)
    assert (s["diagnosed"], s["skipped"], s["failed"]) == (1, 0, 0), s
    (row,) = _rows(tmp_path / "h.sqlite")
    assert (row["actuator_id"], row["time_h"], row["sim_time_s"]) == ("ACT-7", 30.0, 24.0)
    assert row["k_gm"] == pytest.approx(0.5, abs=0.02)


def test_every_recording_of_a_batch_is_counted_and_none_is_filed_under_another_actuator(client, tmp_path):
    """diagnosed + skipped + failed = recordings, also where the store gets a test only once it is
    diagnosed (two files of one test: a log and a copy with one more metadata record); a file the
    history holds for another actuator fails, as `history add` refuses it; a test earlier than its
    actuator's latest fails before its diagnosis; a manifest may list a test once."""
    a = _monitor_log(tmp_path / "a" / "log.mcap", {1: 0.2}, {1: 10.0})
    b = _monitor_log(tmp_path / "b" / "log.mcap", {1: 0.2}, {1: 10.0}, extra={"note": "copied"})
    db = tmp_path / "h.sqlite"
    s = diagnose_fleet(find_recordings([a.parent, b.parent]), db, method=METHOD, client=client)
    assert (s["recordings"], s["diagnosed"], s["skipped"], s["failed"]) == (2, 1, 1, 0), s
    assert len(_rows(db)) == 1
    (tmp_path / "a" / "manifest.csv").write_text("actuator_id,time_h,path\nOTHER,50,log.mcap\n")
    s = diagnose_fleet(find_recordings([a.parent]), db, method=METHOD, client=client)
    assert (s["diagnosed"], s["skipped"], s["failed"]) == (0, 0, 1), s
    assert "the same recording is in the history for actuator ACT-7, not OTHER" in s["failures"][0]["reason"]
    late = _monitor_log(tmp_path / "c" / "log.mcap", {1: 0.2}, {1: 5.0}, extra={"note": "an earlier test"})
    s = diagnose_fleet(find_recordings([late]), db, method=METHOD, client=client)
    assert (s["diagnosed"], s["skipped"], s["failed"], s["batch_time_s"]) == (0, 0, 1, 0.0), s
    assert "not stored" in s["failures"][0]["reason"] and "--backfill" in s["failures"][0]["reason"]
    assert len(_rows(db)) == 1
    s = diagnose_fleet(find_recordings([late]), db, method=METHOD, client=client, backfill=True)
    assert (s["diagnosed"], s["skipped"], s["failed"]) == (1, 0, 0), s
    assert [r["time_h"] for r in _rows(db)] == [5.0, 10.0]
    # the RUL given at 10 h did not see the test at 5 h: the summary says so
    assert s["backfilled"] == [backfill_note("ACT-7", [5.0], [10.0])] and "back-filled" in format_summary(s)
    assert "the RULs given at those tests" in s["backfilled"][0] and "5 h go in before 1 later" in s["backfilled"][0]
    (tmp_path / "a" / "manifest.csv").write_text("actuator_id,time_h,path\nX,50,log.mcap\nY,60,log.mcap\n")
    with pytest.raises(FleetError, match="line 3.*log.mcap is listed already"):
        read_manifest(tmp_path / "a" / "manifest.csv")
    with pytest.raises(FleetError, match="HISTORY.csv is read, not written"):
        diagnose_fleet(find_recordings([b.parent]), tmp_path / "h.csv", method=METHOD, client=client)


def test_successive_batches_on_one_client_lose_no_task(bags, client, tmp_path):
    """A persistent cluster runs batch after batch. The monitor model was scattered under its
    content hash, the same key every batch: re-scattered while the previous batch's release was
    deleting it, a task failed with 'lost dependencies' (7 of 12 successive batches, measured)."""
    (rec,) = [r for r in read_manifest(bags / "manifest.csv")][:1]
    for i in range(8):
        s = diagnose_fleet([rec], tmp_path / f"h{i}.sqlite", method=METHOD, client=client)
        assert (s["diagnosed"], s["failed"]) == (1, 0), (i, s["failures"])


def _bag_of_two_tests(bag, metadata=None):
    """An MCAP log of two noisy reference tests, windows 1 (K_BKL 0.2) and 2 (0.5), and ``metadata``."""
    from eha_health import Faults, load, simulate
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    p = load("reference").with_effect_names(["sensor_noise"])
    with BagWriter(bag) as w:
        for tid, k in ((1, 0.2), (2, 0.5)):
            write_run(w, simulate(kind="reference", faults=Faults(k_bkl=k), params=p, seed=tid), test_id=tid,
                      start_ns=tid * 8_000_000_000)
        for name, rec in (metadata or {}).items():
            w.add_metadata(name, rec)
    return bag


def test_a_manifest_names_the_test_window_of_a_bag_of_several(client, tmp_path, capsys):
    """A rig log of several tests without history records: the manifest's `test` column names
    the window of each row; a window the bag lacks fails alone, naming the windows it has."""
    bag, db = _bag_of_two_tests(tmp_path / "rig_log.mcap"), tmp_path / "h.sqlite"
    (tmp_path / "manifest.csv").write_text("actuator_id,time_h,path,test\nR,10,rig_log.mcap,1\nR,20,rig_log.mcap,2\n"
                                           "R,30,rig_log.mcap,5\n")
    s = diagnose_fleet(read_manifest(tmp_path / "manifest.csv"), db, method=METHOD, client=client)
    assert (s["diagnosed"], s["failed"]) == (2, 1), s
    assert "test 5: no complete test window 5 (complete: [1, 2])" in s["failures"][0]["reason"]
    assert [round(r["k_bkl"], 1) for r in _rows(db)] == [0.2, 0.5]
    assert cli_main(["history", "add", str(bag), "--test", "2", "--actuator", "R", "--history", str(db),
                     "--time-h", "40", "--quiet"]) == 0
    assert "already in" in capsys.readouterr().out and len(_rows(db)) == 2
    (tmp_path / "bad.csv").write_text("actuator_id,time_h,path,test\nR,10,rig_log.mcap,two\n")
    with pytest.raises(FleetError, match="test 'two' is not a test window id"):
        read_manifest(tmp_path / "bad.csv")


def test_a_bag_whose_marks_complete_no_window_fails_alone(client, tmp_path):
    """A rig log stopped mid-test (a start mark, no end mark, no dropped/ record) was read whole and
    diagnosed as a test; its manifest row fails alone now, naming the marks it has."""
    from eha_health import Faults, load, simulate
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    from bagmarks import WithoutEnd
    db = tmp_path / "h.sqlite"
    _bag_of_two_tests(tmp_path / "whole.mcap")
    with BagWriter(tmp_path / "stopped.mcap") as w:
        write_run(WithoutEnd(w), simulate(kind="reference", faults=Faults(k_bkl=0.3),
                                          params=load("reference").with_effect_names(["sensor_noise"]), seed=3), test_id=3)
    (tmp_path / "manifest.csv").write_text("actuator_id,time_h,path\nR,10,stopped.mcap\nR,20,whole.mcap\n")
    s = diagnose_fleet(read_manifest(tmp_path / "manifest.csv"), db, method=METHOD, client=client)
    assert (s["diagnosed"], s["failed"]) == (1, 1), s
    (f,) = s["failures"]
    assert ("no complete test window: the marks on /eha/test_window are of test(s) 3 (start only), none with "
            "both its start and end mark") in f["reason"], f
    assert [round(r["k_bkl"], 1) for r in _rows(db)] == [0.2]


def test_a_window_the_monitor_cut_off_at_its_stop_is_not_diagnosed(client, tmp_path):
    """A monitor log records a window its stop cut off (dropped/test_<id>): a manifest row naming
    it, or a row without `test` (the bag's first window) where that one was cut off, fails alone
    and says why, as `history add` refuses it (until 2026-11-30 it was diagnosed as a whole test)."""
    from eha_health.io.bagrun import DROPPED_META
    db = tmp_path / "h.sqlite"
    _bag_of_two_tests(tmp_path / "mon.mcap", {DROPPED_META.format(1): {
        "reason": "the monitor stopped while its samples were still arriving"}})
    (tmp_path / "manifest.csv").write_text("actuator_id,time_h,path,test\nR,10,mon.mcap,1\nR,15,mon.mcap,\n"
                                           "R,20,mon.mcap,2\n")
    s = diagnose_fleet(read_manifest(tmp_path / "manifest.csv"), db, method=METHOD, client=client)
    assert (s["diagnosed"], s["failed"]) == (1, 2), s
    for f in s["failures"]:
        assert "test window 1 was cut off by the monitor's stop (the monitor stopped while" in f["reason"], f
    assert [round(r["k_bkl"], 1) for r in _rows(db)] == [0.5]
