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
from eha_health.prognostics.records import HealthRecord
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
        return (con.execute("SELECT actuator_id, time_h, k_gm, k_fsj, k_bkl, std_gm, std_fsj, std_bkl, usage "
                            "FROM tests ORDER BY actuator_id, time_h").fetchall(),
                con.execute("SELECT actuator_id, time_h, fault, action, note FROM maintenance "
                            "ORDER BY actuator_id, time_h, fault").fetchall())
    finally:
        con.close()


@pytest.fixture
def store(tmp_path):
    """A: gm wears, fsj wears, is repaired at 400 h and wears again. B: a unit replaced at 360 h
    (its usage restarts from zero), whose gm then wears; its std are not stated (estimated when
    read). C: flat. Errors 0.004; a fixed seed."""
    rng = np.random.default_rng(5)
    recs = []
    for i in range(16):
        t = 40.0 * i
        gm = 6e-4 * max(t - 80.0, 0.0) + rng.normal(0, 0.004)
        fsj = 9e-4 * (t if t < 400 else t - 400) + rng.normal(0, 0.004)
        recs.append(HealthRecord("A", t, (max(gm, 0.0), max(fsj, 0.0), abs(rng.normal(0, 0.004))),
                                 (0.004, 0.004, 0.004), usage=0.8 * t))
        gb = (5e-4 * t if t < 360 else 8e-4 * (t - 360)) + rng.normal(0, 0.004)
        recs.append(HealthRecord("B", t, (max(gb, 0.0), abs(rng.normal(0, 0.004)), 0.0), (None, None, None),
                                 usage=0.9 * (t if t < 360 else t - 360) + 10.0))
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
    assert len(read_history_csv(h, read_maintenance_csv(m))) == 48
    want = prognose_json(capsys, "--history", str(store))

    # read from the files, and imported into a new store: the same object to the last digit
    assert prognose_json(capsys, "--history", str(h), "--maintenance", str(m)) == want
    db2 = tmp_path / "copy.sqlite"
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(db2)])
    assert code == 0, err
    assert "imported 48 new test(s)" in out and "2 maintenance action(s)" in out
    assert err == ""            # B's usage falls at its recorded replacement: nothing to note
    assert table(db2) == table(store)
    assert prognose_json(capsys, "--history", str(db2)) == want

    # again: nothing added, nothing changed
    code, out, err = run(capsys, ["history", "import", str(h), "--maintenance", str(m), "--history", str(db2)])
    assert code == 0 and "imported 0 new test(s)" in out and "0 maintenance action(s)" in out
    assert table(db2) == table(store)

    # without its maintenance the history reads otherwise: A's fsj runs across its repair
    code, out, err = run(capsys, ["prognose", "--json", "--history", str(h)])
    assert code == 2 and "usage falls" in err and "MAINTENANCE.csv" in err     # B's replacement is missing
    assert len(err.strip().splitlines()) == 1


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


def test_a_usage_count_may_fall_in_a_history_csv_only_at_a_replacement(tmp_path):
    h = write(tmp_path / "h.csv", ("actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "usage"),
              [["U", 0, 0, 0, 0, 100], ["U", 10, 0, 0, 0, 108], ["U", 20, 0, 0, 0, 3], ["U", 30, 0, 0, 0, 11]])
    with pytest.raises(PrognosticsError, match="usage falls"):
        read_history_csv(h)
    # a replacement after the fall, or one of another actuator, does not explain it
    for rows in ([["U", 30, "all", "replace"]], [["V", 15, "all", "replace"]], [["U", 15, "all", "repair"]]):
        m = write(tmp_path / "m.csv", ("actuator_id", "time_h", "fault", "action"), rows)
        with pytest.raises(PrognosticsError, match="usage falls"):
            read_history_csv(h, read_maintenance_csv(m))
    for t in (15, 20):          # after the higher count, at or before the lower
        m = write(tmp_path / "m.csv", ("actuator_id", "time_h", "fault", "action"), [["U", t, "gm", "replace"]])
        assert [r.usage for r in read_history_csv(h, read_maintenance_csv(m))] == [100, 108, 3, 11]


GOOD = [["A", 0, 0.01, 0, 0], ["A", 50, 0.05, 0, 0], ["A", 100, 0.09, 0, 0]]


@pytest.mark.parametrize("header, rows, why", [
    (("actuator_id", "time_h"), [["A", 50]], "missing column(s) fault"),
    (("actuator_id", "time_h", "fault"), [["A", 50, "xyz"]], "unknown fault 'xyz'"),
    (("actuator_id", "time_h", "fault", "action"), [["A", 50, "gm", "swap"]], "unknown maintenance action 'swap'"),
    (("actuator_id", "time_h", "fault"), [["A", "fifty", "gm"]], "time_h 'fifty' is not a number"),
    (("actuator_id", "time_h", "fault"), [["A", -5, "gm"]], "finite number of hours >= 0"),
    (("actuator_id", "time_h", "fault"), [["A", "nan", "gm"]], "finite number of hours >= 0"),
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
