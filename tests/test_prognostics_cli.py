"""The history / prognose / thresholds / bench rul commands, run in-process on real files (SQLite, CSV, MCAP),
with real diagnoses; bad input is one line, exit code 2, and the store unchanged."""
import csv
import json
import sqlite3

import numpy as np
import pytest

from eha_health import Faults, load, simulate
from eha_health.cli import main
from eha_health.prognostics.records import HealthRecord
from eha_health.prognostics.store import HistoryStore
from eha_health.prognostics.thresholds import threshold_values


def rows_of(db):
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT * FROM tests ORDER BY id").fetchall(), con.execute(
            "SELECT * FROM maintenance").fetchall()
    finally:
        con.close()


def write_csv(path, rows, header=("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl")):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    return path


def fleet_rows(n_act=4, n_tests=12, seed=0):
    """Linear wear of gm after 100 h, each actuator its own rate; noise 0.003 with that stated std."""
    rng = np.random.default_rng(seed)
    rows = []
    for a in range(n_act):
        rate = 8e-4 * np.exp(0.2 * rng.standard_normal())
        for i in range(n_tests):
            t = 40.0 * i
            k = max(0.0, rate * max(t - 100.0, 0.0) + rng.normal(0, 0.003))
            rows.append([f"A{a}", t, round(k, 5), 0.0, 0.0, 0.003, 0.002, 0.002])
    return rows


@pytest.fixture
def db(tmp_path):
    path = tmp_path / "h.sqlite"
    assert main(["history", "import", str(write_csv(tmp_path / "h.csv", fleet_rows())), "--history", str(path)]) == 0
    return path


def run(capsys, argv):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_import_list_repair_prognose(db, tmp_path, capsys):
    code, out, _ = run(capsys, ["history", "list", "--history", str(db), "--json"])
    obj = json.loads(out)
    assert code == 0 and len(obj["tests"]) == 48 and obj["maintenance"] == []
    # importing the same file again adds nothing
    code, out, _ = run(capsys, ["history", "import", str(tmp_path / "h.csv"), "--history", str(db)])
    assert code == 0 and "imported 0 new" in out and len(rows_of(db)[0]) == 48

    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--json", "--next-check-h", "100"])
    obj = json.loads(out)["actuators"]
    assert code == 0 and set(obj) == {"A0", "A1", "A2", "A3"}
    for a in obj.values():
        gm = a["faults"]["gm"]
        assert gm["rul_p05_h"] <= gm["rul_median_h"] <= gm["rul_p95_h"]
        assert gm["threshold"] == pytest.approx(threshold_values()["gm"], abs=1e-4)
        assert a["overall"]["dominant_fault"] == "gm" and 0 <= a["overall"]["p_fail_next"] <= 1
        # no wear in fsj/bkl: null RUL with a reason
        assert a["faults"]["fsj"]["rul_median_h"] is None and a["faults"]["fsj"]["reason"]
        assert "no degradation in the history (no repair recorded)" in a["faults"]["fsj"]["reason"]

    # a gm repair at the last test restarts its trend: too few tests since then for a RUL
    code, out, _ = run(capsys, ["history", "repair", "--history", str(db), "--actuator", "A1", "--fault", "gm",
                                "--time-h", "440"])
    assert code == 0 and len(rows_of(db)[1]) == 1
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--actuator", "A1", "--json"])
    a1 = json.loads(out)["actuators"]["A1"]
    assert a1["faults"]["gm"]["rul_median_h"] is None and "since the last repair" in a1["faults"]["gm"]["reason"]

    png = tmp_path / "p.png"
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--actuator", "A0", "--plot", str(png)])
    assert code == 0 and "dominant fault: gm" in out and png.read_bytes()[:4] == b"\x89PNG"
    # without --actuator the plot is of the first actuator, and the output says which
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--plot", str(png)])
    assert code == 0 and "(actuator A0, the first of " in out
    # prognose straight from a HISTORY.csv gives the same answer as from its imported store
    code, out_csv, _ = run(capsys, ["prognose", "--history", str(tmp_path / "h.csv"), "--actuator", "A0", "--json"])
    code, out_db, _ = run(capsys, ["prognose", "--history", str(db), "--actuator", "A0", "--json"])
    assert json.loads(out_csv) == json.loads(out_db)


@pytest.mark.parametrize("rows, why", [
    ([["A0", 10, 0.1, 0, 0, 0.01, 0.01, 0.01], ["A0", 5, 0.1, 0, 0, 0.01, 0.01, 0.01]], "out of order"),
    ([["A0", 10, 0.1, 0, 0, 0.01, 0.01, 0.01], ["A0", 10, 0.2, 0, 0, 0.01, 0.01, 0.01]], "duplicate row"),
    ([["A0", 10, 0.1, 0, 0, "nan", 0.01, 0.01]], "std_gm"),
    ([["A0", 10, 0.1, 0, 0, -0.01, 0.01, 0.01]], "negative"),
    ([["A0", 10, 1.7, 0, 0, 0.01, 0.01, 0.01]], r"outside \[0, 1.5\]"),
    ([], "empty"),
    ([["A0", 10, "0.0_5", 0, 0, 0.01, 0.01, 0.01]], r"k_gm '0.0_5' is not a number"),   # float() took it as 0.005
])
def test_bad_import_is_one_line_and_leaves_the_store(db, tmp_path, capsys, rows, why):
    before = rows_of(db)
    bad = write_csv(tmp_path / "bad.csv", [["A9", 0, 0, 0, 0, 0.01, 0.01, 0.01]] + [
        [r[0], r[1] + 1000 if r[0] == "A0" else r[1], *r[2:]] for r in rows] if rows else [])
    code, out, err = run(capsys, ["history", "import", str(bad), "--history", str(db)])
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1
    import re
    assert re.search(why, err), err
    assert rows_of(db) == before


def test_a_duplicate_row_of_an_import_says_what_to_do(db, tmp_path, capsys):
    """A row at a time its actuator has a test at -- in the history, or in a row of the file before
    it -- was refused without a word of what to do (history add's refusal says it): the line now
    names the row and says to correct its time_h or remove it, and that a row repeating another's
    test (the same values) is the same test twice."""
    before = rows_of(db)
    row = ["A0", 1000, 0.1, 0, 0, 0.01, 0.01, 0.01]
    fix = "each test of an actuator has its own operating time: "
    stored = ("the history); the history holds another test there (the same one, with the same K, would add "
              f"nothing); {fix}correct this row's time_h, or remove the row")
    for name, rows, extra, said in (
            ("two", [row, [*row[:2], 0.2, *row[3:]]], [], "{f} line 3: duplicate row: actuator A0 already has a "
             "test at time_h=1000 ({f} line 2); " + fix + "correct the time_h of one of the two rows, or remove one"),
            ("same", [row, row], [], "{f} line 3: duplicate row: actuator A0 already has a test at time_h=1000 "
             "({f} line 2); it repeats the test of {f} line 2 (the same values): remove one of the two rows"),
            ("stored", [["A0", 440, 0.3, 0, 0, 0.01, 0.01, 0.01]], [],
             "{f} line 2: duplicate row: actuator A0 already has a test at time_h=440 (" + stored),
            ("backfill", [["A0", 30, 0.1, 0, 0, 0.01, 0.01, 0.01], ["A0", 40, 0.3, 0, 0, 0.01, 0.01, 0.01]],
             ["--backfill"], "{f} line 3: duplicate row: actuator A0 already has a test at time_h=40 (" + stored)):
        f = write_csv(tmp_path / f"{name}.csv", rows)
        code, out, err = run(capsys, ["history", "import", str(f), "--history", str(db), *extra])
        assert code == 2 and out == "", (out, err)
        (line,) = err.splitlines()
        assert line == "eha-health history import: error: " + said.format(f=f.name), line
        assert rows_of(db) == before


def test_bad_commands_exit_2(db, tmp_path, capsys):
    before = rows_of(db)
    cases = [
        (["history", "list", "--history", str(tmp_path / "none.sqlite")], "no such history"),
        (["history", "list", "--history", str(db), "--actuator", "ZZ"], "unknown actuator"),
        (["history", "repair", "--history", str(db), "--actuator", "A0", "--fault", "gm", "--time-h", "1e6"],
         "in the future"),
        (["history", "repair", "--history", str(db), "--actuator", "ZZ", "--fault", "all", "--time-h", "1"],
         "unknown actuator"),
        (["prognose", "--history", str(db), "--actuator", "ZZ"], "unknown actuator"),
        (["prognose", "--history", str(db), "--next-check-h", "-5"], "--next-check-h"),
        (["prognose", "--history", str(write_csv(tmp_path / "empty.csv", []))], "empty"),
        (["history", "add", str(tmp_path / "missing.csv"), "--actuator", "A0", "--time-h", "1",
          "--history", str(db)], "no such recording"),
        (["prognose", "--history", str(tmp_path)], "a directory, not a history"),
        (["history", "import", str(tmp_path / "d.csv"), "--history", str(db)], "a directory, not a HISTORY.csv"),
        (["prognose", "--history", str(write_csv(tmp_path / "twice.csv", [["A0", 0, 0.1, 0.2, 0.0, 0.1]],
                                                 ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "k_gm")))],
         "column(s) k_gm appear more than once in the header"),
        (["prognose", "--history", str(write_csv(tmp_path / "short.csv", [["A0", 0, 0.1, 0, 0, 0.01, 0.01, 0.01],
                                                                          ["A0", 10, 0.1]]))],
         "short.csv line 3: 3 value(s) for 8 columns: no k_fsj, k_bkl"),
    ]
    (tmp_path / "d.csv").mkdir()
    for argv, why in cases:
        code, out, err = run(capsys, argv)
        assert code == 2 and why in err and len(err.strip().splitlines()) == 1, (argv, err)
    # a usage that falls within a file is read, and said (a replaced unit, or a typing error)
    down = write_csv(tmp_path / "down.csv", [["A0", 0, 0.1, 0, 0, 9.0], ["A0", 10, 0.1, 0, 0, 4.0]],
                     ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "usage"))
    code, out, err = run(capsys, ["prognose", "--history", str(down)])
    assert code == 0 and err.startswith("note: usage falls for actuator A0: 4 at time_h=10 after 9 at time_h=0; kept")
    assert rows_of(db) == before
    assert not (tmp_path / "none.sqlite").exists()


def test_history_add_csv_and_mcap(tmp_path, capsys):
    """Two real diagnoses: a CSV run and a monitor-style MCAP log carrying its operating time."""
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    p = load("reference").with_effect_names(["sensor_noise"])
    db = tmp_path / "h.sqlite"
    r1 = simulate(kind="reference", faults=Faults(k_gm=0.3), params=p, seed=1)
    r1.to_csv(tmp_path / "r1.csv")
    common = ["--history", str(db), "--method", "deterministic", "--quiet"]
    code, out, _ = run(capsys, ["history", "add", str(tmp_path / "r1.csv"), "--actuator", "X", "--time-h", "100",
                                "--usage", "250", *common])
    assert code == 0 and out.startswith("added: X at 100 h")
    # the same recording again: nothing added, no diagnosis needed; for another actuator: an error
    code, out, _ = run(capsys, ["history", "add", str(tmp_path / "r1.csv"), "--actuator", "X", "--time-h", "200",
                                *common])
    assert code == 0 and "already in" in out
    # with --json the answer is the append's object (it was a plain line: not JSON)
    code, out, _ = run(capsys, ["history", "add", str(tmp_path / "r1.csv"), "--actuator", "X", "--time-h", "200",
                                "--json", *common])
    res = json.loads(out)
    assert code == 0 and res["added"] is False and res["diagnosis"] is None and res["time_h"] == 100.0
    assert res["actuator_id"] == "X" and "already in" in res["reason"] and res["history"] == str(db)
    # another recording at a stored time: refused before its diagnosis, with what to do
    r0 = simulate(kind="reference", faults=Faults(k_gm=0.2), params=p, seed=9)
    r0.to_csv(tmp_path / "r0.csv")
    code, _, err = run(capsys, ["history", "add", str(tmp_path / "r0.csv"), "--actuator", "X", "--time-h", "100",
                                "--backfill", *common])
    assert code == 2 and "duplicate row: actuator X already has a test at time_h=100" in err, err
    assert "give this one its --time-h" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, ["history", "add", str(tmp_path / "r1.csv"), "--actuator", "Y", "--time-h", "200",
                                *common])
    assert code == 2 and "already in the history for actuator X" in err

    r2 = simulate(kind="reference", faults=Faults(k_gm=0.35), params=p, seed=2)
    bag = tmp_path / "r2.mcap"
    with BagWriter(bag) as w:
        write_run(w, r2, test_id=3, start_ns=7_000_000_000)
        w.add_metadata("history/test_3", {"time_h": "160.5", "usage": "400", "sim_time_s": "7.0"})
    # an operating time before the stored one is refused before the diagnosis (no progress line of
    # one: the error is all of stderr), and nothing is written
    before = rows_of(db)
    code, _, err = run(capsys, ["history", "add", str(bag), "--actuator", "X", "--time-h", "50",
                                *[a for a in common if a != "--quiet"]])
    assert code == 2 and "out of order" in err and len(err.strip().splitlines()) == 1, err
    assert rows_of(db) == before
    code, out, err = run(capsys, ["history", "add", str(bag), "--actuator", "X", "--json", *common])
    res = json.loads(out)
    assert code == 0 and res["added"] and res["time_h"] == 160.5 and res["usage"] == 400.0
    assert "usage falls" not in err
    code, out, _ = run(capsys, ["history", "list", "--history", str(db), "--json"])
    tests = json.loads(out)["tests"]
    assert [t["time_h"] for t in tests] == [100.0, 160.5] and tests[1]["sim_time_s"] == 7.0
    assert tests[0]["k_gm"] == pytest.approx(0.3, abs=0.02) and tests[1]["k_gm"] == pytest.approx(0.35, abs=0.02)
    assert tests[0]["std_gm"] > 0 and tests[0]["method"] == "deterministic" and tests[0]["wall_time_utc"]
    # a usage below the stored one: kept (a replaced unit's first test), and said
    r3 = simulate(kind="reference", faults=Faults(k_gm=0.05), params=p, seed=3)
    r3.to_csv(tmp_path / "r3.csv")
    code, out, err = run(capsys, ["history", "add", str(tmp_path / "r3.csv"), "--actuator", "X", "--time-h", "200",
                                  "--usage", "30", *common])
    assert code == 0 and out.startswith("added: X at 200 h")
    assert "note: usage falls for actuator X: 30 at time_h=200 after 400 at time_h=160.5" in err
    # the run refused at 50 h goes in with --backfill; the RULs given at the three later tests did not see it
    code, out, err = run(capsys, ["history", "add", str(tmp_path / "r3.csv"), "--actuator", "X", "--time-h", "50",
                                  "--backfill", *common])
    assert code == 0 and "already in" in out and "back-filled" not in err     # r3 is held (at 200 h): nothing added
    r4 = simulate(kind="reference", faults=Faults(k_gm=0.25), params=p, seed=4)
    r4.to_csv(tmp_path / "r4.csv")
    code, out, err = run(capsys, ["history", "add", str(tmp_path / "r4.csv"), "--actuator", "X", "--time-h", "50",
                                  "--backfill", *common])
    assert code == 0 and out.startswith("added: X at 50 h")
    assert "back-filled: actuator X: 1 test(s) at 50 h go in before 3 later stored test(s) (100-200 h)" in err



def test_each_test_of_a_bag_is_a_recording_of_its_own(tmp_path, capsys):
    """A monitor log of N tests holds N recordings: before, the file's hash stood for all of them,
    and the second test of a bag was 'already in' the history once the first was."""
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    p = load("reference").with_effect_names(["sensor_noise"])
    bag, db = tmp_path / "two.mcap", tmp_path / "h.sqlite"
    with BagWriter(bag) as w:
        for tid, (k, t0) in enumerate([(0.3, 1), (0.36, 9)], start=1):
            write_run(w, simulate(kind="reference", faults=Faults(k_gm=k), params=p, seed=tid), test_id=tid,
                      start_ns=t0 * 1_000_000_000)
    common = ["--history", str(db), "--actuator", "X", "--quiet"]
    for tid, t in ((1, "10"), (2, "20")):
        code, out, _ = run(capsys, ["history", "add", str(bag), "--test", str(tid), "--time-h", t, *common])
        assert code == 0 and out.startswith(f"added: X at {t} h"), out
    for extra in (["--test", "2"], ["--test", "1"], []):       # no --test: the first window
        code, out, _ = run(capsys, ["history", "add", str(bag), *extra, "--time-h", "30", *common])
        assert code == 0 and "already in" in out, out
    code, out, _ = run(capsys, ["history", "list", "--history", str(db), "--json"])
    tests = json.loads(out)["tests"]
    assert [t["time_h"] for t in tests] == [10.0, 20.0]
    assert [t["k_gm"] for t in tests] == [pytest.approx(0.3, abs=0.02), pytest.approx(0.36, abs=0.02)]


def test_a_window_the_monitor_dropped_at_its_stop_is_not_added(tmp_path, capsys):
    """A window the monitor recorded as cut off by its stop (metadata dropped/test_<id>) with both its
    marks in the log was diagnosed and appended as a whole test; now it is passed over, saying why."""
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    from bagmarks import WithoutEnd
    p = load("reference").with_effect_names(["sensor_noise"])
    reason = "the monitor stopped while it waited for its last samples"
    bag, one, db = tmp_path / "two.mcap", tmp_path / "one.mcap", tmp_path / "h.sqlite"
    with BagWriter(bag) as w:
        for tid, (k, t0) in enumerate([(0.3, 1), (0.36, 9)], start=1):
            write_run(w, simulate(kind="reference", faults=Faults(k_gm=k), params=p, seed=tid), test_id=tid,
                      start_ns=t0 * 1_000_000_000)
        w.add_metadata("dropped/test_1", {"reason": reason})
    with BagWriter(one) as w:
        write_run(w, simulate(kind="reference", faults=Faults(k_gm=0.2), params=p, seed=5), test_id=4)
        w.add_metadata("dropped/test_4", {"reason": reason})
    # the monitor's usual case: the stop came before the end mark; its log's only window has none
    # (read_run took a bag without a complete window whole until 2026-12-07: this one was diagnosed as
    # a test; read_run refuses it now, the dropped record says why first)
    no_end = tmp_path / "no_end.mcap"
    why_no_end = "the monitor stopped while its samples were still arriving (no end mark)"
    with BagWriter(no_end) as w:
        write_run(WithoutEnd(w), simulate(kind="reference", faults=Faults(k_gm=0.2), params=p, seed=6), test_id=2)
        w.add_metadata("dropped/test_2", {"reason": why_no_end})
    common = ["--history", str(db), "--actuator", "X", "--time-h", "10", "--quiet"]
    for argv, name, why in (([str(bag), "--test", "1"], f"{bag} test 1", reason),
                            ([str(one)], f"{one}: nothing to add", reason),
                            ([str(no_end)], f"{no_end}: nothing to add", why_no_end)):
        code, out, err = run(capsys, ["history", "add", *argv, *common])
        assert code == 2 and out == "" and not db.exists(), (out, err)
        line, = err.splitlines()
        assert line.startswith(f"eha-health history add: error: {name}") and "cut off by the monitor's stop" in line, line
        assert why in line, line
    # without --test: the first window not cut off
    code, out, err = run(capsys, ["history", "add", str(bag), *common])
    assert code == 0 and out.startswith("added: X at 10 h"), (out, err)
    assert f"note: {bag} test 1: skipped, cut off by the monitor's stop ({reason}; metadata dropped/test_1)" in err
    assert "diagnosing test 2" in err
    (t,) = json.loads(run(capsys, ["history", "list", "--history", str(db), "--json"])[1])["tests"]
    assert t["k_gm"] == pytest.approx(0.36, abs=0.02)


def test_a_monitor_log_says_which_history_its_test_went_to(tmp_path, capsys):
    """The history a monitor log's history/test_<id> names: this one, where the monitor's live row
    is, adds nothing and says so before any diagnosis (it used to diagnose, then drop the row);
    another one takes the test too, and says so (it used to say nothing)."""
    from eha_health import diagnose
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    from eha_health.monitoring.prognosis import PrognosisStep
    p = load("reference").with_effect_names(["sensor_noise"])
    r = simulate(kind="reference", faults=Faults(k_gm=0.3), params=p, seed=1)
    db, other, fresh = tmp_path / "h.sqlite", tmp_path / "merged.sqlite", tmp_path / "fresh.sqlite"

    def monitor_log(bag, history):
        with BagWriter(bag) as w:
            w.add_metadata("eha_health", {"actuator_id": "X"})
            write_run(w, r, test_id=1, start_ns=7_000_000_000)
            w.add_metadata("history/test_1", {"actuator_id": "X", "time_h": "100.0", "sim_time_s": "7.0",
                                              "history": str(history.absolute())})
        return bag
    log = monitor_log(tmp_path / "mon.mcap", db)
    # the monitor's own append: its row hashed by the channels and the window stamp
    step = PrognosisStep(db, "X")
    assert step.after_diagnosis(diagnose(r, method="deterministic"), 100.0, sim_time_s=7.0, response=r).appended
    before = rows_of(db)
    common = ["--actuator", "X", "--method", "deterministic", "--quiet"]
    code, out, err = run(capsys, ["history", "add", str(log), "--history", str(db), *common])
    assert code == 0 and err == "" and rows_of(db) == before
    assert out == (f"{log} test 1 is already in {db} (actuator X, time_h 100, window stamp 7 s: metadata "
                   f"history/test_1, appended by the monitor): nothing added\n")      # no diagnosis printed
    code, out, err = run(capsys, ["history", "add", str(log), "--history", str(db), "--json", *common])
    res = json.loads(out)
    assert code == 0 and res["added"] is False and res["time_h"] == 100.0 and "appended by the monitor" in res["reason"]
    # into another history (a merge): added, and said
    code, out, err = run(capsys, ["history", "add", str(log), "--history", str(other), *common])
    assert code == 0 and out.startswith("added: X at 100 h"), (out, err)
    assert err == (f"note: {log} test 1: the monitor appended it to {db.absolute()} (metadata history/test_1), "
                   f"not to {other}; added to {other} as well\n")
    # the log names this history, which lacks the test (a row removed, the file replaced): added, and said
    code, out, err = run(capsys, ["history", "add", str(monitor_log(tmp_path / "f.mcap", fresh)),
                                  "--history", str(fresh), *common])
    assert code == 0 and out.startswith("added: X at 100 h"), (out, err)
    assert "says the monitor appended it to" in err and "which held no test of actuator X at time_h 100" in err
    assert [len(rows_of(h)[0]) for h in (db, other, fresh)] == [1, 1, 1]


def test_thresholds_command(capsys):
    code, out, _ = run(capsys, ["thresholds", "--json"])
    obj = json.loads(out)
    assert code == 0 and set(obj) == {"gm", "fsj", "bkl"}
    assert {f: v["k"] for f, v in obj.items()} == threshold_values()
    code, out, _ = run(capsys, ["thresholds"])
    assert code == 0 and "K_GM" in out and "breaks" in out


def test_bench_rul_time_prognose(capsys):
    code, out, _ = run(capsys, ["bench", "rul", "--time-prognose", "6", "--json"])
    obj = json.loads(out)
    assert code == 0 and obj["actuators"] == 6 and obj["series"] == 18 and obj["wall_time_s"] > 0
    assert obj["monitor_step_refitted"] == 1 and obj["monitor_step_s"] > 0 and obj["fleet_prior_fit_s"] > 0
    code, _, err = run(capsys, ["bench", "rul", "--units", "1"])
    assert code == 2 and "--units" in err


def test_prognose_table_says_what_the_history_checks_did(tmp_path, capsys):
    t = np.arange(24) * 50.0
    gm = np.where(t >= 600, 0.001 * (t - 600) + 0.02, 0.001 * t)     # repaired at 600 h, not recorded
    bkl = 0.0004 * t
    bkl[10] += 0.2                                                     # a failed diagnosis
    bkl[-1] += 0.2                                                     # and the latest test off the trend
    h = write_csv(tmp_path / "h.csv", [["A", ti, g, 0.0, b, 0.005, 0.001, 0.005] for ti, g, b in zip(t, gm, bkl)])
    code, out, err = run(capsys, ["prognose", "--history", str(h)])
    assert code == 0, err
    assert "K fell at 600 h and stayed down" in out and "history repair" in out
    assert "set aside as failed diagnoses (far off their neighbours): tests at 500 h" in out
    assert "the last test is off the trend" in out


def test_a_reader_that_stops_early_gets_no_traceback(tmp_path):
    """`eha-health history list | head`: the pipe closes under a long listing. Before, Python's
    BrokenPipeError traceback went to the terminal."""
    import subprocess
    import sys
    h = tmp_path / "long.csv"
    with open(h, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"])
        w.writerows(["A", float(i), 0.0, 0.0, 0.0] for i in range(3000))   # ~300 kB of listing: beyond a pipe buffer
    db = tmp_path / "long.sqlite"
    assert main(["history", "import", str(h), "--history", str(db)]) == 0
    p = subprocess.Popen([sys.executable, "-m", "eha_health.cli", "history", "list", "--history", str(db)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = p.stdout.readline()
    p.stdout.close()                      # as `head -1` does
    err = p.stderr.read().decode()
    assert p.wait(timeout=300) == 1 and first.startswith(b"%s: 3000 test(s)" % str(db).encode())
    assert "Traceback" not in err and "BrokenPipe" not in err, err


def test_settings_file_sets_the_requirements_and_the_prognosis(db, tmp_path, capsys):
    # the parameters YAML a user writes: no requirement set, the default limit K = 0.5
    y = tmp_path / "mine.yaml"
    y.write_text("requirements: []\nthresholds: {default: 0.5}\n")
    code, out, _ = run(capsys, ["thresholds", "--settings", str(y), "--json"])
    th = json.loads(out)
    assert code == 0 and {f: (t["k"], t["requirement"]) for f, t in th.items()} == {
        "gm": (0.5, None), "fsj": (0.5, None), "bkl": (0.5, None)}
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--actuator", "A0", "--json", "--settings", str(y)])
    mine = json.loads(out)["actuators"]["A0"]
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--actuator", "A0", "--json"])
    packaged = json.loads(out)["actuators"]["A0"]
    assert mine["faults"]["gm"]["threshold"] == 0.5 and packaged["faults"]["gm"]["threshold"] != 0.5
    # a lower threshold comes sooner
    assert mine["faults"]["gm"]["rul_median_h"] < packaged["faults"]["gm"]["rul_median_h"]
    # a settings file that is missing or wrong: one line, exit 2
    bad = tmp_path / "bad.yaml"
    bad.write_text("fleet: {min_points: 4, colour: red}\n")
    for argv, why in [(["thresholds", "--settings", str(tmp_path / "none.yaml")], "no such settings file"),
                      (["prognose", "--history", str(db), "--settings", str(bad)], "colour"),
                      (["launch", "--settings", str(y)], "needs --history")]:
        code, out, err = run(capsys, argv)
        assert code == 2 and why in err and len(err.strip().splitlines()) == 1, (argv, err)


def test_a_fault_gets_its_own_model_set_from_the_settings_file(db, tmp_path, capsys):
    """fault_models: in a user's settings: gm fits only the linear path model, the other faults
    (and the other actuators' data) are untouched; a bad block is one line, exit 2."""
    y = tmp_path / "mine.yaml"
    y.write_text("fault_models:\n  gm: {names: [linear]}\n")
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--json", "--settings", str(y)])
    mine = json.loads(out)["actuators"]
    code0, out, _ = run(capsys, ["prognose", "--history", str(db), "--json"])
    shared = json.loads(out)["actuators"]
    assert code == code0 == 0 and set(mine) == set(shared)
    for a in mine:
        gm, gm0 = mine[a]["faults"]["gm"], shared[a]["faults"]["gm"]
        assert gm["model"] == "linear" and gm["model_weights"] == {"linear": 1.0}, gm
        assert gm0["model_weights"] != gm["model_weights"], gm0
        assert gm["rul_median_h"] != gm0["rul_median_h"]
        for f in ("fsj", "bkl"):
            assert mine[a]["faults"][f] == shared[a]["faults"][f]
    # a block written twice (PyYAML kept the last without a word)
    y.write_text("fault_models:\n  gm: {names: [linear]}\n  gm: {names: [wiener]}\n")
    code, out, err = run(capsys, ["prognose", "--history", str(db), "--json", "--settings", str(y)])
    assert code == 2 and "key 'gm' written twice (lines 2 and 3)" in err and len(err.strip().splitlines()) == 1, err
    y.write_text("prognosis: {min_tests: 50}\nfleet: {min_points: 4}\nprognosis: {seed: 1}\n")
    code, out, err = run(capsys, ["prognose", "--history", str(db), "--json", "--settings", str(y)])
    assert code == 2 and "key 'prognosis' written twice (lines 1 and 3)" in err, err
    y.write_text("fault_models:\n  gm: {names: [linear, weibull]}\n")
    code, out, err = run(capsys, ["prognose", "--history", str(db), "--json", "--settings", str(y)])
    assert code == 2 and "fault_models.gm.names: choose from" in err and len(err.strip().splitlines()) == 1, err


def test_an_argument_error_is_one_line_too(capsys):
    for argv, why in [(["prognose", "--next-check-h", "abc"], "invalid float value: 'abc'"),
                      (["history", "repair", "--actuator", "A", "--fault", "xx", "--time-h", "1"], "invalid choice: 'xx'"),
                      (["prognose", "--no-such-flag"], "unrecognized arguments")]:
        with pytest.raises(SystemExit) as e:
            main(argv)
        _, err = capsys.readouterr()
        assert e.value.code == 2 and why in err and len(err.strip().splitlines()) == 1, (argv, err)


def test_a_usage_that_falls_against_the_store_is_kept_with_a_note(tmp_path, capsys):
    # a replaced unit's first test may come before its replacement is recorded: a usage below the
    # stored one is kept, and said
    hdr = ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl", "usage")
    db = tmp_path / "h.sqlite"
    first = write_csv(tmp_path / "a.csv", [["A", t, 0.01, 0.0, 0.0, 0.002, 0.002, 0.002, 2.0 * t]
                                           for t in (0.0, 50.0, 100.0)], hdr)
    code, _, err = run(capsys, ["history", "import", str(first), "--history", str(db)])
    assert code == 0 and "usage falls" not in err
    later = write_csv(tmp_path / "b.csv", [["A", 150.0, 0.01, 0.0, 0.0, 0.002, 0.002, 0.002, 20.0],
                                           ["A", 200.0, 0.01, 0.0, 0.0, 0.002, 0.002, 0.002, 120.0]], hdr)
    code, _, err = run(capsys, ["history", "import", str(later), "--history", str(db)])
    assert code == 0 and len(rows_of(db)[0]) == 5
    assert err.count("usage falls") == 1 and "20 at time_h=150 after 200 at time_h=100" in err
    assert "--action replace" in err
    code, _, err = run(capsys, ["history", "import", str(later), "--history", str(db)])   # nothing new: no note
    assert code == 0 and "usage falls" not in err
    # once the replacement is recorded, the new unit's tests fall below nothing
    assert main(["history", "repair", "--actuator", "A", "--fault", "all", "--action", "replace",
                 "--time-h", "150", "--history", str(db)]) == 0
    more = write_csv(tmp_path / "c.csv", [["A", 250.0, 0.01, 0.0, 0.0, 0.002, 0.002, 0.002, 220.0]], hdr)
    code, _, err = run(capsys, ["history", "import", str(more), "--history", str(db)])
    assert code == 0 and "usage falls" not in err
    with HistoryStore(db, readonly=True) as st:
        assert st.usage_notes([HealthRecord("A", 300.0, (0.0,) * 3, (0.0,) * 3, usage=10.0)])   # below 220
        assert not st.usage_notes([HealthRecord("B", 300.0, (0.0,) * 3, (0.0,) * 3, usage=10.0)])


def test_a_misspelled_std_column_is_refused_and_a_plot_without_suffix_is_a_png(db, tmp_path, capsys):
    # std_fjs was read as no std at all (K_FSJ's errors estimated) without a word
    before = rows_of(db)
    bad = write_csv(tmp_path / "typo.csv", [["A9", 0, 0.02, 0.05, 0.01, 0.01, 0.03, 0.01]],
                    ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fjs", "std_bkl"))
    code, out, err = run(capsys, ["history", "import", str(bad), "--history", str(db)])
    assert code == 2 and "unknown column(s) std_fjs" in err and rows_of(db) == before
    own = write_csv(tmp_path / "own.csv", [["A9", 0, 0.02, 0.05, 0.01, "shift 2"]],
                    ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "comment"))
    assert run(capsys, ["history", "import", str(own), "--history", str(db)])[0] == 0   # a column of one's own
    code, out, _ = run(capsys, ["prognose", "--history", str(db), "--plot", str(tmp_path / "fig")])
    assert code == 0 and f"plot: {tmp_path / 'fig.png'}" in out
    assert (tmp_path / "fig.png").read_bytes()[:4] == b"\x89PNG"


def test_a_plot_that_cannot_be_written_is_one_line(db, tmp_path, capsys):
    (tmp_path / "d.png").mkdir()
    (tmp_path / "plots").mkdir()
    for target, why in ((tmp_path / "d.png", "is a directory"), (tmp_path / "d.png" / "x" / "f.png", "no such directory"),
                        # a directory without a suffix: it wrote plots.png beside it (probe 12)
                        (tmp_path / "plots", "is a directory; --plot takes a file name")):
        code, out, err = run(capsys, ["prognose", "--history", str(db), "--plot", str(target)])
        assert code == 2 and str(target) in err and why in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "plots.png").exists()


def test_one_actuator_on_the_usage_clock_is_answered_alone(tmp_path, capsys):
    """Asked for U1 on the usage clock, the answer held U1 and every actuator of the history that
    could not go on the clock (null RULs): an independent probe, 2026-11-29."""
    rows = [[a, 40.0 * i, round(0.001 * 40 * i, 5), 0, 0, 0.003, 0.003, 0.003] + ([30.0 * i] if a == "U1" else [""])
            for a in ("U1", "U2", "U3") for i in range(8)]
    h = write_csv(tmp_path / "h.csv", rows, ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj",
                                           "std_bkl", "usage"))
    code, out, err = run(capsys, ["prognose", "--history", str(h), "--clock", "usage", "--actuator", "U1", "--json"])
    assert code == 0, err
    assert list(json.loads(out)["actuators"]) == ["U1"]
    code, out, err = run(capsys, ["prognose", "--history", str(h), "--clock", "usage", "--json"])
    got = json.loads(out)["actuators"]
    assert list(got) == ["U1", "U2", "U3"] and got["U2"]["overall"]["rul_median_h"] is None


def test_a_back_filled_repair_says_where_the_trend_restarts(db, capsys):
    # a maintenance log entered late: a repair before one already recorded is kept, and said to
    # leave the trend where the later one restarts it (before, it read "its trend restarts there")
    common = ["--actuator", "A1", "--history", str(db)]
    code, out, err = run(capsys, ["history", "repair", "--fault", "gm", "--time-h", "300", *common])
    assert code == 0 and "(its trend restarts there)" in out and err == ""
    code, out, err = run(capsys, ["history", "repair", "--fault", "gm", "--time-h", "100", *common])
    assert code == 0 and "(kept in the log only)" in out and "gm at 300 h" in err
    code, out, err = run(capsys, ["history", "repair", "--fault", "all", "--time-h", "200", "--action", "replace", *common])
    assert code == 0 and "(the trend of fsj, bkl restarts there)" in out and "gm at 300 h" in err
    code, out, _ = run(capsys, ["history", "list", "--history", str(db), "--json"])
    assert {(m["fault"], m["time_h"]) for m in json.loads(out)["maintenance"]} >= {("gm", 300.0), ("gm", 100.0), ("all", 200.0)}


def test_a_history_csv_whose_last_line_has_no_end_of_line_is_said(tmp_path, capsys):
    """A HISTORY.csv cut inside its last value (a file still being written) reads as a shorter
    number, 0.4567 as 0.4, and cannot be told from a whole one: `prognose` and `history import` say
    that the last line has no end of line (an independent probe, 2026-12-07); a short last line is
    refused (test_what_a_history_csv_would_misread_is_refused)."""
    rows = fleet_rows(n_act=1, n_tests=8)
    whole = write_csv(tmp_path / "whole.csv", rows)
    cut = tmp_path / "cut.csv"
    cut.write_bytes(whole.read_bytes().rstrip(b"\r\n")[:-2])          # the last value loses 2 digits
    said = "has no end of line: if the file was still being written, its last value may be cut short"
    for path, noted in ((whole, False), (cut, True)):
        code, out, err = run(capsys, ["prognose", "--history", str(path), "--json"])
        assert code == 0 and json.loads(out)["actuators"], err
        assert (said in err) == noted, err
        code, out, err = run(capsys, ["history", "import", str(path), "--history", str(tmp_path / f"{path.stem}.db")])
        assert code == 0 and (said in err) == noted, err
