"""A history as CSV files (HISTORY.csv + MAINTENANCE.csv): `history export` writes what `history
import --maintenance` and `prognose --history HISTORY.csv --maintenance` read back -- the same
prognosis, repairs and replacements included; bad files are one line, exit 2, the store unchanged."""
import csv
import json
import sqlite3

import numpy as np
import pytest

from eha_health.cli import main
from eha_health.prognostics.config import PrognosticsError
from eha_health.prognostics.history_csv import read_history_csv, read_maintenance_csv
from eha_health.prognostics.records import HealthRecord, batch_usage_notes
from eha_health.prognostics.store import HistoryStore


def run(capsys, argv):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def write(path, header, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    return path


def table(db):
    con = sqlite3.connect(db)
    try:
        return (con.execute("SELECT actuator_id, time_h, k_gm, k_fsj, k_bkl, std_gm, std_fsj, std_bkl, usage, "
                            "usage_unit, sim_time_s FROM tests ORDER BY actuator_id, time_h").fetchall(),
                con.execute("SELECT actuator_id, time_h, fault, action, note FROM maintenance "
                            "ORDER BY actuator_id, time_h, fault").fetchall())
    finally:
        con.close()


@pytest.fixture
def store(tmp_path):
    """A: gm wears, fsj wears, is repaired at 400 h and wears again. B: a unit replaced at 360 h
    (its usage restarts from zero), whose gm then wears; its std are not stated (estimated when
    read). C: flat. Errors 0.004; a fixed seed. A's usage is in flight hours, B's in cycles; A's
    tests carry a window stamp (a monitor's), the others none."""
    rng = np.random.default_rng(5)
    recs = []
    for i in range(16):
        t = 40.0 * i
        gm = 6e-4 * max(t - 80.0, 0.0) + rng.normal(0, 0.004)
        fsj = 9e-4 * (t if t < 400 else t - 400) + rng.normal(0, 0.004)
        recs.append(HealthRecord("A", t, (max(gm, 0.0), max(fsj, 0.0), abs(rng.normal(0, 0.004))),
                                 (0.004, 0.004, 0.004), usage=0.8 * t, usage_unit="FH", sim_time_s=3600.0 * t + 0.125))
        gb = (5e-4 * t if t < 360 else 8e-4 * (t - 360)) + rng.normal(0, 0.004)
        recs.append(HealthRecord("B", t, (max(gb, 0.0), abs(rng.normal(0, 0.004)), 0.0), (None, None, None),
                                 usage=0.9 * (t if t < 360 else t - 360) + 10.0, usage_unit="cycles"))
        recs.append(HealthRecord("C", t, (abs(rng.normal(0, 0.004)), 0.0, 0.0), (0.004, 0.004, 0.004)))
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        # the new unit's first test comes before its replacement is recorded (as at a check)
        st.add_tests([r for r in recs if r.time_h < 360])
        st.add_tests([r for r in recs if r.time_h >= 360])
        st.record_repair("A", "fsj", 400.0, note="new seal, bench 3")
        st.record_repair("B", "all", 360.0, action="replace")
    return db


def prognose_json(capsys, *argv):
    code, out, err = run(capsys, ["prognose", "--json", "--next-check-h", "50", *argv])
    assert code == 0, err
    return json.loads(out)


def test_an_export_imports_to_the_same_prognosis(store, tmp_path, capsys):
    h, m = tmp_path / "out" / "HISTORY.csv", tmp_path / "out" / "HISTORY_maintenance.csv"
    h.parent.mkdir()
    code, out, err = run(capsys, ["history", "export", str(h), "--history", str(store)])
    assert code == 0, err
    assert "48 test(s)" in out and "2 maintenance action(s)" in out and str(m) in out
    assert len(read_history_csv(h)) == 48 and len(read_maintenance_csv(m)) == 2
    want = prognose_json(capsys, "--history", str(store))

    # read from the files, and imported into a new store: the same object to the last digit
    assert prognose_json(capsys, "--history", str(h), "--maintenance", str(m)) == want
    db2 = tmp_path / "copy.sqlite"
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(db2)])
    assert code == 0, err
    assert "imported 48 new test(s)" in out and "2 maintenance action(s)" in out
    assert err == ""            # B's usage falls at its recorded replacement: nothing to note
    # every stored column the file holds, usage_unit and sim_time_s too (lost until 2026-11-30)
    assert table(db2) == table(store)
    assert {(r[0], r[9], r[10] is None) for r in table(db2)[0]} == {("A", "FH", False), ("B", "cycles", True),
                                                                     ("C", None, True)}
    assert prognose_json(capsys, "--history", str(db2)) == want

    # again: nothing added, nothing changed
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(db2)])
    assert code == 0 and "imported 0 new test(s)" in out and "0 maintenance action(s)" in out
    assert table(db2) == table(store)

    # without its maintenance the history reads otherwise: A's fsj runs across its repair, and B's
    # usage falls with no replacement to explain it; both are said
    code, out, err = run(capsys, ["prognose", "--json", "--history", str(h)])
    assert code == 0 and json.loads(out) != want
    assert err.count("note: ") == 2, err
    assert "usage falls for actuator B: 10 at time_h=360 after" in err and "MAINTENANCE.csv" in err
    assert f"{m} beside it is not read" in err


def test_an_export_of_one_actuator_and_an_explicit_maintenance_file(store, tmp_path, capsys):
    h, m = tmp_path / "a.csv", tmp_path / "a_repairs.csv"
    code, out, err = run(capsys, ["history", "export", str(h), "--maintenance", str(m), "--actuator", "A",
                                  "--history", str(store)])
    assert code == 0, err
    with open(m, newline="") as f:
        assert list(csv.DictReader(f)) == [{"actuator_id": "A", "time_h": "400.0", "fault": "fsj",
                                            "action": "repair", "note": "new seal, bench 3"}]
    got = prognose_json(capsys, "--history", str(h), "--maintenance", str(m))
    assert got == prognose_json(capsys, "--history", str(store), "--actuator", "A")


def test_imported_maintenance_older_than_a_stored_one_is_said_once(store, tmp_path, capsys):
    """A back-filled maintenance file whose actions lie before a maintenance already stored for the
    same fault is kept in the log; the trend restarts at the stored one, and one note says so (as
    `history repair` does for one action). Actions of a fault with no later one say nothing."""
    h = write(tmp_path / "h.csv", ["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"], [["D", 0.0, 0.0, 0.0, 0.0]])
    m = write(tmp_path / "m.csv", ["actuator_id", "time_h", "fault", "action"],
              [["A", 100.0, "fsj", "repair"], ["A", 200.0, "all", "repair"], ["A", 500.0, "fsj", "repair"],
               ["B", 300.0, "gm", "repair"], ["C", 100.0, "bkl", "repair"]])
    before = prognose_json(capsys, "--history", str(store), "--actuator", "A")["actuators"]["A"]["faults"]
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(store)])
    assert code == 0 and "5 maintenance action(s)" in out, err
    assert err.count("note: ") == 1, err
    assert "3 maintenance action(s) are older than a maintenance already recorded" in err
    assert "A fsj at 100 h (restarts at fsj 400 h)" in err and "A all at 200 h (restarts at fsj 400 h)" in err
    assert "B gm at 300 h (restarts at gm 360 h)" in err
    assert "A fsj at 500" not in err and "C bkl" not in err
    assert len(table(store)[1]) == 2 + 5                  # every action is kept in the log
    after = prognose_json(capsys, "--history", str(store), "--actuator", "A")["actuators"]["A"]["faults"]
    assert after["gm"] != before["gm"] and after["fsj"] != before["fsj"]   # 200 h all, 500 h fsj restart them

    # imported again: nothing new, nothing said
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(store)])
    assert code == 0 and "0 maintenance action(s)" in out and err == ""


def test_a_usage_count_that_falls_in_a_history_csv_is_kept_and_said_unless_a_replacement_explains_it(tmp_path, capsys):
    """As in the store: a replaced unit's count restarts, and its first tests may come before the
    replacement is known. Until 2026-11-29 a fall within one file was refused, so a store holding one
    (kept with a note, or with the replacement recorded after the fall) exported a file its own
    import refused (an independent probe)."""
    h = write(tmp_path / "h.csv", ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "usage"),
              [["U", 0, 0, 0, 0, 100], ["U", 10, 0, 0, 0, 108], ["U", 20, 0, 0, 0, 3], ["U", 30, 0, 0, 0, 11]])
    assert [r.usage for r in read_history_csv(h)] == [100, 108, 3, 11]
    said = "usage falls for actuator U: 3 at time_h=20 after 108 at time_h=10; kept"
    # a replacement after the fall, or one of another actuator, or a repair, does not explain it
    for rows in ([], [["U", 30, "all", "replace"]], [["V", 15, "all", "replace"]], [["U", 15, "all", "repair"]]):
        m = write(tmp_path / "m.csv", ("actuator_id", "time_h", "fault", "action"), rows)
        notes = batch_usage_notes(read_history_csv(h), read_maintenance_csv(m))
        assert len(notes) == 1 and notes[0].startswith(said), rows
    for t in (15, 20):          # after the higher count, at or before the lower
        m = write(tmp_path / "m.csv", ("actuator_id", "time_h", "fault", "action"), [["U", t, "gm", "replace"]])
        assert batch_usage_notes(read_history_csv(h), read_maintenance_csv(m)) == []
    # the store: imported, kept, said once; exported and imported again, the same rows, nothing said
    db = tmp_path / "h.sqlite"
    code, out, err = run(capsys, ["history", "import", str(h), "--history", str(db)])
    assert code == 0 and "imported 4 new test(s)" in out and err.count("usage falls") == 1 and said in err
    out_csv = tmp_path / "out.csv"
    assert run(capsys, ["history", "export", str(out_csv), "--history", str(db)])[0] == 0
    db2 = tmp_path / "copy.sqlite"
    code, out, err = run(capsys, ["history", "import", str(out_csv), "--maintenance",
                                  str(tmp_path / "out_maintenance.csv"), "--history", str(db2)])
    assert code == 0 and table(db2) == table(db) and err.count("usage falls") == 1
    code, out, err = run(capsys, ["history", "import", str(out_csv), "--history", str(db2)])   # held: nothing new
    assert code == 0 and "imported 0 new test(s)" in out and "usage falls" not in err


GOOD = [["A", 0, 0.01, 0, 0], ["A", 50, 0.05, 0, 0], ["A", 100, 0.09, 0, 0]]


@pytest.mark.parametrize("header, rows, why", [
    (("actuator_id", "time_h"), [["A", 50]], "missing column(s) fault"),
    (("actuator_id", "time_h", "fault"), [["A", 50, "xyz"]], "unknown fault 'xyz'"),
    (("actuator_id", "time_h", "fault", "action"), [["A", 50, "gm", "swap"]], "unknown maintenance action 'swap'"),
    (("actuator_id", "time_h", "fault"), [["A", "fifty", "gm"]], "time_h 'fifty' is not a number"),
    (("actuator_id", "time_h", "fault"), [["A", -5, "gm"]], "must be a number of hours in [0, 1e+09]"),
    (("actuator_id", "time_h", "fault"), [["A", "nan", "gm"]], "must be a number of hours in [0, 1e+09]"),
    (("actuator_id", "time_h", "fault"), [["A", 50, "gm"], ["A", 50, "k_gm"]], "duplicate maintenance"),
    (("actuator_id", "time_h", "fault"), [["A", 150, "gm"]], "in the future"),
    (("actuator_id", "time_h", "fault"), [["Z", 50, "gm"]], "unknown actuator 'Z'"),
    (("actuator_id", "time_h", "fault"), [["", 50, "gm"]], "empty actuator id"),
])
def test_a_bad_maintenance_file_is_one_line_and_nothing_is_imported(tmp_path, capsys, header, rows, why):
    h = write(tmp_path / "h.csv", ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"), GOOD)
    m = write(tmp_path / "m.csv", header, rows)
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([HealthRecord("B", 0.0, (0, 0, 0), (0.01,) * 3)])
    before = table(db)
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(db)])
    assert code == 2 and why in err and len(err.strip().splitlines()) == 1, err
    assert table(db) == before          # the tests of the good HISTORY.csv did not go in either
    code, out, err = run(capsys, ["prognose", "--history", str(h), "--maintenance", str(m)])
    assert code == 2 and why in err and len(err.strip().splitlines()) == 1, err


def test_a_maintenance_file_that_disagrees_with_the_store_is_refused(store, tmp_path, capsys):
    h, m = tmp_path / "x.csv", tmp_path / "x_maintenance.csv"
    assert main(["history", "export", str(h), "--history", str(store)]) == 0
    write(m, ("actuator_id", "time_h", "fault", "action"), [["A", 400, "fsj", "replace"],  # stored: repair
                                                                   ["B", 360, "all", "replace"]])
    before = table(store)
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(store)])
    assert code == 2 and "duplicate maintenance: A fsj already recorded at time_h=400 (repair)" in err
    assert table(store) == before


def test_bad_exports_exit_2_and_leave_files_as_they_were(store, tmp_path, capsys):
    kept = write(tmp_path / "kept.csv", ("x",), [["1"]]).read_bytes()
    cases = [
        (["history", "export", str(tmp_path / "h.txt")], "ending in .csv"),
        (["history", "export", str(tmp_path / "no" / "h.csv")], "no such directory"),
        (["history", "export", str(tmp_path)], "ending in .csv"),
        (["history", "export", str(tmp_path / "h.csv"), "--maintenance", str(tmp_path / "h.csv")], "two files"),
        (["history", "export", str(tmp_path / "h.csv"), "--actuator", "nobody"], "unknown actuator 'nobody'"),
        (["history", "export", str(tmp_path / "h.csv"), "--history", str(tmp_path / "none.sqlite")], "no such history"),
        (["prognose", "--maintenance", str(tmp_path / "kept.csv")], "goes with a HISTORY.csv"),
    ]
    for argv, why in cases:
        if "--history" not in argv:
            argv = argv + ["--history", str(store)]
        code, out, err = run(capsys, argv)
        assert code == 2 and why in err and len(err.strip().splitlines()) == 1, (argv, err)
    assert (tmp_path / "kept.csv").read_bytes() == kept
    assert not (tmp_path / "h.csv").exists() and not (tmp_path / "h_maintenance.csv").exists()


@pytest.mark.parametrize("header, rows, match", [
    # "Usage" was not a column of ours: the usage was dropped, a falling count unseen
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "Usage"), [["A", 0, 0, 0, 0, 5]],
     r"column\(s\) Usage: names are case-sensitive"),
    # float() reads Arabic-Indic and full-width digits
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"), [["A", "\u0661\u0660", 0, 0, 0]],
     r"line 2: time_h '\u0661\u0660' is not a number"),
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"), [["A", "\uff12\uff10", 0, 0, 0]],
     r"line 2: time_h '\uff12\uff10' is not a number"),
    # times near the float limit overflowed the prognosis (a traceback)
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"), [["A", 1e290, 0, 0, 0]],
     r"line 2: time_h must be a number of hours in \[0, 1e\+09\], got 1e\+290"),
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "usage"), [["A", 1, 0, 0, 0, 1e300]],
     r"line 2: usage must be a number in \[0, 1e\+12\]"),
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "sim_time_s"), [["A", 1, 0, 0, 0, "nan"]],
     r"line 2: sim_time_s must be a time stamp \[s\] >= 0, got nan"),
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "sim_time_s"), [["A", 1, 0, 0, 0, "-2"]],
     r"line 2: sim_time_s must be a time stamp \[s\] >= 0, got -2.0"),
    (("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "Usage_unit"), [["A", 1, 0, 0, 0, "FH"]],
     r"column\(s\) Usage_unit: names are case-sensitive"),
])
def test_what_a_history_csv_would_misread_is_refused(tmp_path, capsys, header, rows, match):
    """Cases of an independent probe (2026-11-29), each read silently or with a traceback before."""
    h = write(tmp_path / "h.csv", header, rows)
    with pytest.raises(PrognosticsError, match=match):
        read_history_csv(h)
    db = tmp_path / "h.sqlite"
    code, _, err = run(capsys, ["history", "import", str(h), "--history", str(db)])
    assert code == 2 and len(err.strip().splitlines()) == 1 and not db.exists()


def test_a_maintenance_column_in_other_case_is_refused(tmp_path):
    m = write(tmp_path / "m.csv", ("actuator_id", "time_h", "fault", "Action"), [["A", 5, "all", "replace"]])
    with pytest.raises(PrognosticsError, match=r"column\(s\) Action: names are case-sensitive"):
        read_maintenance_csv(m)


def test_errors_not_stated_are_estimated_within_each_trend(tmp_path):
    """5 tests before and 5 after a repair, errors of 0.005 not stated: the second differences
    that spanned the repair's fall read 0.0204 (an independent probe, 2026-11-29)."""
    rng = np.random.default_rng(11)
    t = 50.0 * np.arange(10)
    gm = np.where(t < 250, 0.3 + 0.001 * t, 0.02 + 0.001 * (t - 250)) + rng.normal(0, 0.005, 10)
    h = write(tmp_path / "h.csv", ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"),
              [["A", ti, round(float(g), 5), 0, 0] for ti, g in zip(t, gm)])
    m = write(tmp_path / "m.csv", ("actuator_id", "time_h", "fault"), [["A", 240, "gm"]])
    from eha_health.prognostics.scatter import noise_estimate
    from eha_health.prognostics.store import as_history
    k = np.round(gm, 5)
    std = as_history(h, maintenance=m).actuators["A"].std[:, 0]
    assert np.all(std == std[0]) and 0.0025 <= std[0] <= 0.01, std[0]
    assert std[0] == noise_estimate(k, [5]) != noise_estimate(k)     # no difference spans the repair
    assert as_history(h).actuators["A"].std[0, 0] == noise_estimate(k)  # without it: one trend


def test_a_row_the_store_refuses_is_named_by_its_line_as_the_files_own_checks_name_it(tmp_path, capsys):
    """The store's checks said "FILE row N" (the N-th record), the file's "line N" for the same row
    (an independent probe, 2026-11-29); with a blank line the two numbers differed by two."""
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        st.add_tests([HealthRecord("A", 10.0, (0.1, 0, 0), (0.01,) * 3)])
    h = tmp_path / "h.csv"
    h.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\nB,0,0.1,0,0\n\nA,5,0.1,0,0\n")
    code, _, err = run(capsys, ["history", "import", str(h), "--history", str(db)])
    assert code == 2 and "h.csv line 4: times out of order: actuator A test at time_h=5" in err, err
