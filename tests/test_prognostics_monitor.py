"""The monitor's history and RUL: the ROS-free prognosis step on a real SQLite file with real diagnoses,
then the real node graph, its /diagnostics read by an independent subscriber and its latched eha/rul."""
import csv
import json
import sqlite3

import numpy as np
import pytest
import yaml

from eha_health import Faults, diagnose, load, simulate
from eha_health.monitoring.health import HealthPolicy, escalate
from eha_health.monitoring.prognosis import PrognosisStep, rul_values
from eha_health.physics.faults import FAULT_KEYS
from eha_health.prognostics.config import load_settings
from eha_health.prognostics.store import HistoryStore
from eha_health.prognostics.thresholds import threshold_values

RATE = 1.5e-3      # K_GM per hour after onset at 100 h: threshold 0.816 near 640 h


def gm_at(t):
    return RATE * max(t - 100.0, 0.0)


def seed_history(path, n=9, dt=40.0, actuator="eha"):
    """A worn history: gm rising linearly, 1-sd error 0.004."""
    rng = np.random.default_rng(3)
    csvp = path.with_suffix(".csv")
    with open(csvp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl"])
        for i in range(n):
            t = dt * i
            w.writerow([actuator, t, round(max(0.0, gm_at(t) + rng.normal(0, 0.004)), 5), 0, 0, 0.004, 0.002, 0.002])
    with HistoryStore(path) as st:
        st.import_csv(csvp)
    return dt * (n - 1)


def count(db):
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT COUNT(*) FROM tests").fetchone()[0]
    finally:
        con.close()


def young_among_a_fleet(tmp_path, monkeypatch):
    """A history: eha with a young gm trend (2 points since its onset at 100 h: it takes the fleet
    prior) among 24 synthetic actuators, whose prior is fitted 4 at a time."""
    from eha_health.bench.rul import synthetic_history_csv
    from eha_health.prognostics import prior_cache
    monkeypatch.setattr(prior_cache, "BATCH", 4)
    db = tmp_path / "h.sqlite"
    seed_history(db, n=5)
    with HistoryStore(db) as st:
        st.import_csv(synthetic_history_csv(tmp_path / "fleet.csv", 24, n_tests=12, seed=4))
    return db


def stopped_in_the_prior_fit(step, run):
    """``run()`` in another thread, ``step.stop()`` once it asks whether to go on with the fleet prior; its result."""
    import threading
    asked, stopped = threading.Event(), threading.Event()
    own = step._priors.cancelled

    def ask():                  # the first ask waits until the test has stopped the step
        asked.set()
        stopped.wait(300)
        return own()
    step._priors.cancelled = ask
    got = {}
    worker = threading.Thread(target=lambda: got.update(out=run()))
    worker.start()
    assert asked.wait(600), "the step never started the fleet prior"
    step.stop()
    stopped.set()
    worker.join(600)
    return got["out"]


@pytest.fixture(scope="module")
def diagnosis_at_500h():
    p = load("reference").with_effect_names(["sensor_noise"])
    r = simulate(kind="reference", faults=Faults(k_gm=gm_at(500.0)), params=p, seed=5)
    return diagnose(r, method="deterministic"), r


def test_step_appends_prognoses_and_escalates(tmp_path, diagnosis_at_500h):
    d, r = diagnosis_at_500h
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    step = PrognosisStep(db, "eha", next_check_h=200.0, warn_p_fail=0.05, error_p_fail=0.2)
    out = step.after_diagnosis(d, last + 180.0, sim_time_s=12.5, response=r)
    assert out.appended and out.error is None and count(db) == 10
    with HistoryStore(db) as st:
        row = st.list_tests("eha")[-1]
    assert row["time_h"] == last + 180.0 and row["sim_time_s"] == 12.5 and row["wall_time_utc"]
    assert row["k_gm"] == pytest.approx(d.faults.k_gm) and row["method"] == "deterministic"
    ov = out.prognosis["overall"]
    # ~0.6 at 500 h with ~140 h to go: failure before a check 200 h away is likely
    assert ov["dominant_fault"] == "gm" and ov["p_fail_next"] >= 0.2
    assert 50 < ov["rul_median_h"] < 300
    assert step.level(out)[0] == "ERROR"
    vals = rul_values(out)
    for f in ("", *(f"_{k}" for k in FAULT_KEYS)):
        for key in ("rul_median_h", "rul_p05_h", "rul_p95_h", "p_fail_next"):
            assert key + f in vals
    assert vals["rul_median_h"] == ov["rul_median_h"] and vals["rul_median_h_fsj"] == "none"
    v = escalate(HealthPolicy().verdict(1, 0, d), *step.level(out), vals)
    assert v.level == "ERROR" and "P(failure before the next check" in v.message and v.values["dominant_fault"] == "gm"

    # the same window again (its samples and its stamp, as the monitor gives them) adds no row; an
    # earlier operating time is refused, the RUL still given
    again = step.after_diagnosis(d, last + 300.0, sim_time_s=12.5, response=r)
    assert not again.appended and again.error is None and count(db) == 10
    d2 = diagnose(simulate(kind="reference", faults=Faults(k_gm=0.3),
                           params=load("reference").with_effect_names(["sensor_noise"]), seed=6), method="deterministic")
    bad = step.after_diagnosis(d2, 10.0)
    assert not bad.appended and "out of order" in bad.error and bad.prognosis is not None and count(db) == 10
    # the RUL is the stored history's: it counts from the latest stored test, not from the refused one
    # (probe 11: time_h + rul_median_h was off by the difference)
    assert out.rul_time_h == last + 180.0 and vals["rul_time_h"] == last + 180.0
    assert bad.rul_time_h == last + 180.0 and rul_values(bad)["rul_time_h"] == last + 180.0
    assert rul_values(bad)["operating_time_h"] == 10.0
    # the hint names the monitor's knob, not the command line's (probe 11: "goes in with --backfill")
    assert "operating_hours parameter" in bad.error and "goes in with --backfill" not in bad.error
    # a lenient next check: nothing to warn about
    calm = PrognosisStep(db, "eha", next_check_h=1.0).after_diagnosis(d2, 5.0)
    assert PrognosisStep(db, "eha", next_check_h=1.0).level(calm)[0] == "OK"


def test_step_refuses_bad_settings_and_survives_a_bad_file(tmp_path, diagnosis_at_500h):
    from eha_health.prognostics.config import PrognosticsError
    with pytest.raises(PrognosticsError, match="warn_p_fail"):
        PrognosisStep(tmp_path / "h.sqlite", "eha", warn_p_fail=0.5, error_p_fail=0.1)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    out = PrognosisStep(junk, "eha").after_diagnosis(diagnosis_at_500h[0], 1.0)
    assert not out.appended and "not a history" in out.error and out.prognosis is None
    assert junk.read_bytes() == b"this is not a database" * 100


def test_a_prognosis_that_fails_is_a_history_error_not_a_failed_diagnosis(tmp_path, diagnosis_at_500h):
    """Settings whose requirement the healthy actuator breaks: no threshold. The step appends the
    diagnosed test and says why there is no RUL; it raised before, and the node reported the
    window "not diagnosed" (an independent probe, 2026-11-29), and its status and key values
    carry the line."""
    from eha_health.monitoring.prognosis import rul_values
    from eha_health.prognostics.config import load_settings
    from eha_health.prognostics.thresholds import _thresholds
    tight = load_settings(overrides={"requirements": [{"name": "r", "metric": "sine_peak_error", "limit": 1e-5}]})
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    step = PrognosisStep(db, "eha", settings=tight)
    _thresholds.cache_clear()
    out = step.after_diagnosis(diagnosis_at_500h[0], last + 180.0)
    assert out.appended and count(db) == 10 and out.prognosis is None
    assert "already breaks requirement(s) r" in out.error
    assert rul_values(out)["history_error"] == out.error
    level, _ = step.level(out)
    assert level == "OK"       # no RUL to warn on; the node escalates the error itself (WARN)


def test_monitor_node_appends_and_publishes_the_rul(tmp_path, capsys):
    from eha_health.io.bagrun import history_times
    from eha_health.ros.graph import Graph
    from msg_bridge import contract as C
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    log = tmp_path / "mon.mcap"
    # the user's parameters YAML: the sine requirement 5 % tighter (the gm threshold comes sooner)
    mine = tmp_path / "mine.yaml"
    mine.write_text(yaml.safe_dump({"requirements": [
        {**r.__dict__, "limit": r.limit * (0.95 if r.name == "sine_peak_error" else 1.0)}
        for r in load_settings().requirements]}))
    params = {"history": str(db), "operating_hours": last + 180.0, "next_check_h": 200.0,
              "prognostics_settings": str(mine)}
    with Graph(faults=Faults(k_gm=gm_at(last + 180.0)), method="deterministic", log_path=log,
               monitor_params=params) as g:
        seen = g.listen(C.DIAGNOSTICS, "independent_listener")   # an independent node reads /diagnostics
        res = g.run_test()
        assert res["prognosis"].appended, res["message"]

        def with_rul():     # the test's (the stored history's RUL, given at start, has no test_id)
            return [st for m in seen for st in m.status if {"rul_median_h", "test_id"} <= {kv.key for kv in st.values}]
        g.spin_until(with_rul, 300.0, "/diagnostics with the RUL")
        st = with_rul()[-1]
        kv = {k.key: k.value for k in st.values}
        got = g.listen(C.RUL, "late_rul")   # a late subscriber still gets the latched prognosis
        g.spin_until(lambda: got, 120.0, "latched eha/rul")
    ov = res["prognosis"].prognosis["overall"]
    assert st.hardware_id == "eha" and st.level == bytes([2])          # ERROR: failure likely before the check
    assert "P(failure before the next check" in st.message
    assert float(kv["rul_median_h"]) == pytest.approx(ov["rul_median_h"], rel=1e-5)
    assert kv["dominant_fault"] == "gm" and float(kv["p_fail_next_gm"]) >= 0.2 and kv["rul_median_h_bkl"] == "none"
    assert "no degradation" in kv["rul_reason_bkl"] and "rul_reason_gm" not in kv      # why bkl has none
    assert float(kv["k_gm"]) == pytest.approx(gm_at(last + 180.0), abs=0.02)
    rul = json.loads(got[0].data)
    assert rul["actuator_id"] == "eha" and rul["time_h"] == last + 180.0
    thr = threshold_values(load_settings(mine))["gm"]
    assert rul["faults"]["gm"]["threshold"] == pytest.approx(thr, abs=1e-4) and thr < threshold_values()["gm"] - 0.005
    assert rul["overall"]["rul_median_h"] == ov["rul_median_h"]
    with HistoryStore(db) as hs:
        row = hs.list_tests("eha")[-1]
    assert count(db) == 10 and row["time_h"] == last + 180.0 and row["sim_time_s"] is not None
    assert row["wall_time_utc"] and row["method"] == "deterministic"
    # the row names its recording, the monitor's log (until 2026-11-30 null); hashed by its channels:
    # the log was still being written
    assert row["source_path"] == str(log.absolute()) and row["source_hash"]
    # the monitor's log says where the test went: history add of the log finds the same time
    assert history_times(log, res["test_id"])["time_h"] == last + 180.0
    # ... and the same test: history add of the log (hashed by the file, not by the channels as the
    # monitor did) recognises it by its actuator, time and window stamp, and adds nothing, undiagnosed
    from eha_health.cli import main as cli_main
    capsys.readouterr()
    assert cli_main(["history", "add", str(log), "--actuator", "eha", "--history", str(db),
                     "--method", "deterministic", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert count(db) == 10 and f"is already in {db} (actuator eha, time_h {last + 180.0:g}" in out, out
    assert out.endswith("appended by the monitor): nothing added\n"), out


def test_status_says_what_the_history_checks_did(tmp_path):
    from eha_health.monitoring.prognosis import Outcome
    from eha_health.prognostics.rul import prognose
    t = np.arange(24) * 50.0
    gm = np.where(t >= 600, 0.001 * (t - 600) + 0.02, 0.001 * t)     # repaired at 600 h, not recorded
    bkl = 0.0004 * t
    bkl[10] += 0.2                                                     # a failed diagnosis
    p = tmp_path / "h.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl"])
        w.writerows(["A", ti, g, 0.0, b, 0.005, 0.001, 0.005] for ti, g, b in zip(t, gm, bkl))
    prog = prognose(p, thresholds={"gm": 0.8, "fsj": 0.9, "bkl": 0.85})["actuators"]["A"]
    vals = rul_values(Outcome(True, prog, time_h=float(t[-1])))
    assert vals["unrecorded_repair_h_gm"] == 600.0 and vals["outliers_h_bkl"] == "500"
    assert not any(k.endswith("_fsj") and k.startswith(("unrecorded", "outliers", "last_test")) for k in vals)
    assert "last_test_off_trend_gm" not in vals


def test_a_lower_bound_on_p_fail_escalates_and_is_published(tmp_path):
    """A next check beyond the prediction horizon leaves P(fail before it) bounded below only
    (p_fail_next_min): the status follows the bound and says '>='."""
    from eha_health.monitoring.prognosis import Outcome
    db = tmp_path / "h.sqlite"
    seed_history(db)
    step = PrognosisStep(db, "eha", next_check_h=50.0, warn_p_fail=0.05, error_p_fail=0.2)
    ov = {"rul_median_h": None, "rul_p05_h": None, "rul_p95_h": None, "p_fail_next": None,
          "p_fail_next_min": 0.3, "dominant_fault": "gm", "reason": "the next check lies beyond the horizon"}
    F = {**ov, "p_fail_next_min": 0.3}
    out = Outcome(True, {"faults": {f: dict(F) for f in FAULT_KEYS}, "overall": ov}, time_h=10.0)
    level, why = step.level(out)
    assert level == "ERROR" and ">= 0.300" in why
    # one comparison: the level's threshold in words (probe 11: ">= 0.300 (...) >= 0.2")
    assert why.count(">=") == 1 and why.endswith("at or above the ERROR level 0.2")
    kv = rul_values(out)
    assert kv["p_fail_next"] == "none" and kv["p_fail_next_min"] == 0.3 and kv["p_fail_next_min_gm"] == 0.3


def test_a_warning_from_one_test_off_its_trend_says_to_test_again(tmp_path):
    # a flat gm, then one test 0.25 up: a failed diagnosis or wear that jumped. The prognosis mixes
    # both futures, so the warning is half a single test's doing: the status says to test again.
    from eha_health.monitoring.prognosis import Outcome
    from eha_health.prognostics.rul import prognose
    rng = np.random.default_rng(2)
    p = tmp_path / "h.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl"])
        for i in range(12):
            w.writerow(["eha", 50.0 * i, 0.05 + rng.normal(0, 0.004) + (0.25 if i == 11 else 0.0), 0, 0,
                        0.004, 0.004, 0.004])
    prog = prognose(p, "eha", next_check_h=200.0)["actuators"]["eha"]
    assert prog["faults"]["gm"].get("last_test_off_trend") is True
    step = PrognosisStep(tmp_path / "unused.sqlite", "eha", next_check_h=200.0, warn_p_fail=0.05, error_p_fail=0.9)
    level, why = step.level(Outcome(True, prog))
    assert level == "WARN", (level, prog["overall"])
    assert "the last gm test is off its trend" in why and "test again" in why
    # the threshold follows the probability it judges, not "test again" (probe 11: "test again >= 0.05")
    assert why.endswith(": test again") and ">=" not in why.split(";")[1]
    assert why.split(";")[0].endswith("), at or above the WARN level 0.05")


def test_step_on_the_usage_clock(tmp_path, diagnosis_at_500h):
    """prognosis.clock usage (the monitor's prognostics_settings): with the usage of each test the
    step prognoses on it; a test without one is appended and the prognosis refused in one line,
    never raised."""
    d, r = diagnosis_at_500h
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    con = sqlite3.connect(db)
    con.execute("UPDATE tests SET usage = 2.0 * time_h")          # 2 cycles per hour so far
    con.commit()
    con.close()
    s = load_settings(overrides={"prognosis": {"clock": "usage"}})
    step = PrognosisStep(db, "eha", next_check_h=200.0, settings=s)
    out = step.after_diagnosis(d, last + 180.0, response=r, usage=2.0 * (last + 180.0))
    assert out.appended and out.error is None and out.prognosis["overall"]["clock"] == "usage"
    # even usage: the hours are those of the time clock (50 < RUL < 300 h as in the test above)
    assert 50 < out.prognosis["overall"]["rul_median_h"] < 300
    assert out.prognosis["faults"]["gm"]["rul_median_usage"] == pytest.approx(
        2.0 * out.prognosis["faults"]["gm"]["rul_median_h"], rel=0.15)
    d2 = diagnose(simulate(kind="reference", faults=Faults(k_gm=0.62),
                           params=load("reference").with_effect_names(["sensor_noise"]), seed=7), method="deterministic")
    nousage = step.after_diagnosis(d2, last + 220.0)
    assert nousage.appended and nousage.prognosis is None and "the usage clock needs a usage" in nousage.error


def test_a_stopped_step_appends_its_test_and_cuts_the_fleet_prior_fit_short(tmp_path, diagnosis_at_500h, monkeypatch):
    """The node's shutdown: :meth:`PrognosisStep.stop` from another thread while the step fits the
    fleet prior of a shared history (a young actuator takes it). The test is appended, the fit ends
    at its next batch, the outcome says why there is no RUL. Before 2026-11-29 the shutdown waited
    for the whole fit (about 20 s on 1000 actuators) and the node could be killed mid-way."""
    db = young_among_a_fleet(tmp_path, monkeypatch)
    step = PrognosisStep(db, "eha", next_check_h=50.0)
    out = stopped_in_the_prior_fit(step, lambda: step.after_diagnosis(diagnosis_at_500h[0], 200.0))
    assert out.appended and out.prognosis is None and count(db) == 5 + 24 * 12 + 1
    assert "fleet prior stopped after 0 of" in out.error and "the monitor is stopping" in out.error
    assert rul_values(out)["history_error"] == out.error
    # a step stopped before it runs appends and does not prognose at all
    later = step.after_diagnosis(diagnosis_at_500h[0], 240.0)
    assert later.appended and later.prognosis is None and later.error.startswith("prognosis skipped")
    # the history is whole: a fresh step gives the RUL, with the fleet prior
    from eha_health.prognostics.rul import prognose
    fresh = PrognosisStep(db, "eha", next_check_h=50.0).after_diagnosis(diagnosis_at_500h[0], 280.0)
    assert fresh.appended and fresh.error is None and fresh.prognosis["faults"]["gm"]["rul_median_h"] is not None
    assert fresh.prognosis == prognose(db, "eha", 50.0)["actuators"]["eha"]


def test_a_step_waiting_for_the_write_lock_says_so_and_a_stop_ends_the_wait(tmp_path, diagnosis_at_500h):
    """Probe 11: a monitor stopped while another process held the history's write lock waited out
    SQLite's busy timeout (60 s) in silence, and `launch` kills it after 10 s. The step now says it
    waits and gives up when stopped: the test is not appended (its window is in the MCAP log)."""
    import threading
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    before = count(db)
    other = sqlite3.connect(db, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")            # another writer that holds its transaction
    said = []
    waiting = threading.Event()
    step = PrognosisStep(db, "eha", next_check_h=50.0, on_wait=lambda m: (said.append(m), waiting.set()))
    got = {}
    worker = threading.Thread(target=lambda: got.update(out=step.after_diagnosis(diagnosis_at_500h[0], last + 40)))
    try:
        worker.start()
        assert waiting.wait(600), "the step never said it waits for the lock"
        step.stop()
        worker.join(600)
        assert not worker.is_alive()
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert len(said) == 1 and "locked by another process: waiting for it" in said[0]
    out = got["out"]
    assert not out.appended and out.prognosis is None and "the wait for it was stopped" in out.error
    assert count(db) == before


def test_another_diagnosis_at_a_stored_time_and_stamp_is_refused_not_dropped(tmp_path, diagnosis_at_500h):
    """A simulated graph restarts its stamps at 0, so a new session's first test comes at the time and
    window stamp of a stored one. It was dropped without a word (probe 11: not appended, no error);
    the same recording again still adds nothing and says nothing."""
    d, r = diagnosis_at_500h
    db = tmp_path / "h.sqlite"
    step = PrognosisStep(db, "eha")
    assert step.after_diagnosis(d, 0.0, sim_time_s=0.0, response=r).appended
    again = step.after_diagnosis(d, 0.0, sim_time_s=0.0, response=r)
    assert not again.appended and again.error is None and count(db) == 1
    r2 = simulate(kind="reference", faults=Faults(k_gm=0.45, k_fsj=0.6, k_bkl=0.4),
                  params=load("reference").with_effect_names(["sensor_noise"]), seed=8)
    other = step.after_diagnosis(diagnose(r2, method="deterministic"), 0.0, sim_time_s=0.0, response=r2)
    assert not other.appended and "duplicate row" in other.error and "time_h=0" in other.error
    # it says how to give the test its own time (probe 11 gave no hint)
    assert other.error.endswith("set operating_hours to this test's operating hours"), other.error
    assert rul_values(other)["history_error"] == other.error and count(db) == 1
    with HistoryStore(db) as st:
        assert st.list_tests("eha")[0]["k_gm"] == pytest.approx(d.faults.k_gm)     # the stored one stays


@pytest.mark.graph
def test_a_new_session_whose_test_collides_with_a_stored_one_is_refused_loudly(tmp_path):
    """Two monitor sessions on one history (probe 11's launch, then launch --faults): the second
    session's test has the first one's time and stamp and another K. The status says it was not
    appended and is raised to WARN, and the log records the refusal (not as appended)."""
    from eha_health.io.mcaplog import read_bag
    from eha_health.ros.graph import Graph
    from msg_bridge import contract as C
    db = tmp_path / "h.sqlite"
    with Graph(method="deterministic", log_path=tmp_path / "one.mcap", monitor_params={"history": str(db)}) as g:
        first = g.run_test()
    assert first["prognosis"].appended and count(db) == 1
    log = tmp_path / "two.mcap"
    with Graph(faults=Faults(k_gm=0.15), method="deterministic", log_path=log,
               monitor_params={"history": str(db)}) as g:
        seen = g.listen(C.DIAGNOSTICS, "independent_listener")
        res = g.run_test()

        def status():
            return [st for m in seen for st in m.status if any(kv.key == "history_appended" for kv in st.values)]
        g.spin_until(status, 300.0, "/diagnostics of the test")
    st = status()[-1]
    kv = {k.key: k.value for k in st.values}
    assert not res["prognosis"].appended and "duplicate row" in res["prognosis"].error
    assert float(kv["k_gm"]) < 0.3 and st.level == bytes([1]) and res["level"] == "WARN"    # K alone says OK
    assert kv["history_appended"] == "False" and "duplicate row" in kv["history_error"] and count(db) == 1
    assert "set operating_hours to this test's operating hours" in kv["history_error"]
    meta = read_bag(log, topics=[]).metadata
    tid = res["test_id"]
    assert f"history/test_{tid}" not in meta
    assert "duplicate row" in meta[f"history_refused/test_{tid}"]["error"]
    assert "set operating_hours" in meta[f"history_refused/test_{tid}"]["error"]


@pytest.mark.parametrize("param, value, says", [
    ("history", "{tmp}", "a directory, not a history file"),
    ("history", "{tmp}/h.csv", "a HISTORY.csv is read, not written"),
    ("actuator_id", "", "empty actuator id"),
    ("actuator_id", " ACT-1", "has leading or trailing spaces"),
])
def test_a_monitor_given_a_history_it_cannot_append_to_is_refused_at_start(tmp_path, param, value, says):
    """Probe 11: these started ("diagnoses appended, RUL on eha/rul") and refused every test. Now
    the node refuses to start, in one line naming the problem, before it makes a log."""
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from eha_health.ros import teardown
    from eha_health.ros.monitor import MonitorNode
    args = {"history": str(tmp_path / "ok.sqlite"), "log_path": str(tmp_path / "mon.mcap"),
            param: value.format(tmp=tmp_path)}
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        with pytest.raises(ValueError, match=says) as e:
            node = MonitorNode(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in args.items()])
            teardown(None, [node])
        assert "\n" not in str(e.value)
    finally:
        teardown(None, [], ctx)
    assert not (tmp_path / "mon.mcap").exists() and not (tmp_path / "ok.sqlite").exists()


def test_the_monitor_script_given_a_directory_as_history_exits_2_with_one_line(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root / "src"), str(root)]))
    # a deadline for a node that would run on (before the fix it started and waited for tests)
    out = subprocess.run([sys.executable, "-m", "eha_health.ros.monitor", "--ros-args", "-p", f"history:={tmp_path}",
                          "-p", f"log_path:={tmp_path / 'mon.mcap'}"], env=env, capture_output=True, text=True,
                         timeout=120)
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert out.returncode == 2 and len(lines) == 1 and "a directory, not a history file" in lines[0], out.stderr
    assert not (tmp_path / "mon.mcap").exists()


@pytest.mark.graph
def test_eha_rul_of_a_refused_test_counts_from_the_latest_stored_one(tmp_path, monkeypatch):
    """A test refused as out of order: eha/rul still gives the stored history's RUL, whose time is
    that of its latest test (probe 11: it carried the refused test's time, 1000 h off). The log's
    metadata names the history by its absolute path though it was given relative (probe 11)."""
    from eha_health.io.mcaplog import read_bag
    from eha_health.ros.graph import Graph
    from msg_bridge import contract as C
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    monkeypatch.chdir(tmp_path)
    with Graph(method="deterministic", log_path="mon.mcap",
               monitor_params={"history": "h.sqlite", "operating_hours": 10.0}) as g:
        res = g.run_test()
        got = g.listen(C.RUL, "late_rul")
        g.spin_until(lambda: got, 120.0, "latched eha/rul")
    assert not res["prognosis"].appended and "out of order" in res["prognosis"].error and count(db) == 9
    rul = json.loads(got[-1].data)
    assert rul["time_h"] == last and rul["test_time_h"] == 10.0 and rul["source"] == "test"
    assert read_bag(tmp_path / "mon.mcap", topics=[]).metadata[f"history_refused/test_{res['test_id']}"][
        "history"] == str(db)
    assert rul["overall"]["rul_median_h"] == res["prognosis"].prognosis["overall"]["rul_median_h"]


@pytest.mark.graph
def test_a_window_not_diagnosed_after_a_good_test_keeps_the_rul_in_the_status(tmp_path):
    """Probe 11: after a good test, one window that could not be diagnosed (marks of a test 777
    with no samples) made /diagnostics drop the RUL while the latched eha/rul still held it. The
    status says the window was not diagnosed and keeps the RUL and the time it counts from."""
    from eha_health.ros import msg_class, qos
    from eha_health.ros.graph import Graph
    from msg_bridge import contract as C
    from msg_bridge import convert as cv
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    params = {"history": str(db), "operating_hours": last + 180.0, "next_check_h": 200.0}
    with Graph(faults=Faults(k_gm=gm_at(last + 180.0)), method="deterministic", monitor_params=params) as g:
        seen = g.listen(C.DIAGNOSTICS, "independent_listener")
        good = g.run_test()
        assert good["prognosis"].appended and good["prognosis"].prognosis is not None, good["message"]
        marker = g.nodes[-1]      # the listener node also publishes the bogus marks
        pub = marker.create_publisher(msg_class(C.TEST_WINDOW), C.TEST_WINDOW.name, qos(C.TEST_WINDOW))
        g.spin_until(lambda: pub.get_subscription_count() >= 1, 120.0, "marks publisher matched")
        at = 10_000 * 10**9       # far after the graph's samples: the window has none
        pub.publish(cv.window_msg(at, "start", 777))
        pub.publish(cv.window_msg(at + 10**9, "end", 777))

        def status_777():
            return [st for m in seen for st in m.status
                    if any(kv.key == "test_id" and kv.value == "777" for kv in st.values)]
        g.spin_until(status_777, 300.0, "/diagnostics of test 777")
    st = status_777()[-1]
    kv = {k.key: k.value for k in st.values}
    assert "test 777 not diagnosed" in st.message and st.level == bytes([2]) and "error" in kv
    ov = good["prognosis"].prognosis["overall"]
    assert float(kv["rul_median_h"]) == pytest.approx(ov["rul_median_h"], rel=1e-5)
    assert float(kv["rul_time_h"]) == last + 180.0 and kv["dominant_fault"] == "gm"
    assert "history_appended" not in kv and "P(failure before the next check" in st.message


def test_the_usage_clock_refusal_names_the_monitors_knobs(tmp_path, diagnosis_at_500h):
    """Probe 11: the monitor said "(history add --usage, or a usage column); or use --clock time",
    knobs it does not have; its own are the usage parameter and prognostics_settings."""
    d, r = diagnosis_at_500h
    db = tmp_path / "h.sqlite"
    last = seed_history(db)      # no usage
    step = PrognosisStep(db, "eha", settings=load_settings(overrides={"prognosis": {"clock": "usage"}}))
    out = step.after_diagnosis(d, last + 180.0, response=r, usage=1000.0)
    assert out.appended and out.prognosis is None and "the usage clock needs a usage that grows" in out.error
    assert "usage parameter" in out.error and "prognostics_settings" in out.error
    assert "--usage" not in out.error and "--clock" not in out.error


@pytest.mark.graph
def test_a_restarted_monitor_publishes_the_stored_historys_rul_before_its_first_test(tmp_path):
    """Probe 11: a monitor started on a history already holding its actuator's tests said "no test
    window diagnosed yet" and published nothing on eha/rul until its next test. It now prognoses the
    stored history at start (in its worker) and says where the RUL comes from; an actuator with no
    stored test stays STALE."""
    from eha_health.prognostics.rul import prognose
    from eha_health.ros.graph import Graph
    from msg_bridge import contract as C
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    with Graph(method="deterministic", monitor_params={"history": str(db), "next_check_h": 200.0}) as g:
        seen = g.listen(C.DIAGNOSTICS, "independent_listener")

        def status():
            return [st for m in seen for st in m.status if any(kv.key == "rul_median_h" for kv in st.values)]
        g.spin_until(status, 300.0, "/diagnostics with the stored history's RUL")
        got = g.listen(C.RUL, "late_rul")    # a late subscriber gets it, latched
        g.spin_until(lambda: got, 120.0, "latched eha/rul")
        assert g.monitor.verdicts == 0
    ov = prognose(db, "eha", 200.0)["actuators"]["eha"]["overall"]
    st = status()[-1]
    kv = {k.key: k.value for k in st.values}
    assert st.level == bytes([1])          # WARN: P(fail before the check in 200 h) ~0.11 >= 0.05
    assert "P(failure before the next check in 200 h)" in st.message
    assert "no test window diagnosed yet: RUL of the stored history (latest test at 320 h)" in st.message
    assert float(kv["rul_median_h"]) == pytest.approx(ov["rul_median_h"], rel=1e-5)
    assert float(kv["rul_time_h"]) == last and "history_appended" not in kv and "test_id" not in kv
    rul = json.loads(got[-1].data)
    assert rul["source"] == "stored history" and rul["time_h"] == last and rul["test_time_h"] is None
    assert rul["next_check_h"] == 200.0     # which horizon p_fail_next is over (probe 11: not said)
    assert rul["overall"]["rul_median_h"] == ov["rul_median_h"] and count(db) == 9

    # another actuator, none of whose tests is stored: as before, nothing until its first test
    with Graph(method="deterministic", actuator_id="other", monitor_params={"history": str(db)}) as g:
        seen = g.listen(C.DIAGNOSTICS, "independent_listener")
        g.spin_until(lambda: not g.monitor._stored_due and g.monitor._stored is None, 300.0,
                     "the start's prognosis done")
        n = len(seen)
        g.spin_until(lambda: len(seen) > n, 120.0, "a status after it")
        assert g.monitor._last_rul is None
    st = seen[-1].status[0]
    assert st.level == bytes([3]) and st.message == "no test window diagnosed yet"


@pytest.mark.graph
def test_a_test_is_diagnosed_and_appended_while_the_start_prognosis_still_runs(tmp_path, monkeypatch):
    """The start's stored-history prognosis ran in the diagnosis worker, so its fleet-prior fit (~19 s
    on 1000 actuators) held up the first test's diagnosis that long. Held here in its fit: the test is
    diagnosed and appended meanwhile; its RUL, which needs that prior, follows once the fit ends."""
    import threading
    from eha_health.ros.graph import Graph
    db = young_among_a_fleet(tmp_path, monkeypatch)
    before = count(db)
    asked, released = threading.Event(), threading.Event()
    with Graph(faults=Faults(k_gm=gm_at(200.0)), method="deterministic",
               monitor_params={"history": str(db), "operating_hours": 200.0, "next_check_h": 50.0}) as g:
        mon = g.monitor
        own = mon.prognosis._priors.cancelled

        def ask():              # the start's fit waits at its first batch until the test lets it go on
            asked.set()
            released.wait(900)
            return own()
        mon.prognosis._priors.cancelled = ask
        try:
            g.spin_until(asked.is_set, 300.0, "the start prognosis in its fleet-prior fit")
            g.spin_until(lambda: g.command.start_test()[0], 300.0, "a test started")
            g.spin_until(lambda: count(db) == before + 1, 900.0, "the test appended while the start's fit is held")
            assert not mon._stored.done() and mon.verdicts == 0
        finally:
            released.set()
        g.spin_until(lambda: mon.verdicts >= 1, 900.0, "the test's verdict")
    prog = mon.results[-1]["prognosis"]
    assert prog.appended and prog.prognosis is not None and prog.error is None and prog.rul_time_h == 200.0


def test_the_stored_prognosis_of_an_actuator_without_tests_is_none(tmp_path):
    db = tmp_path / "h.sqlite"
    last = seed_history(db)
    out = PrognosisStep(db, "eha").stored()
    assert out.prognosis is not None and out.rul_time_h == last and not out.appended and out.error is None
    assert PrognosisStep(db, "other").stored() is None
    assert PrognosisStep(tmp_path / "new.sqlite", "eha").stored() is None and not (tmp_path / "new.sqlite").exists()
    stopped = PrognosisStep(db, "eha")
    stopped.stop()
    out = stopped.stored()
    assert out.prognosis is None and out.error.startswith("prognosis skipped") and count(db) == 9


def test_the_start_prognosis_is_cut_short_by_a_stop_as_a_tests_is(tmp_path, monkeypatch):
    """The stored history's RUL at the monitor's start fits the fleet prior when a young actuator
    takes it; a stop (the node's shutdown) from another thread ends the fit at its next batch."""
    db = young_among_a_fleet(tmp_path, monkeypatch)
    before = count(db)
    step = PrognosisStep(db, "eha", next_check_h=50.0)
    out = stopped_in_the_prior_fit(step, step.stored)
    assert out.prognosis is None and "fleet prior stopped after 0 of" in out.error and count(db) == before
