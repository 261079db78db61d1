"""Bad recordings: `diagnose` exits 2 with one clear line; the live monitor reports ERROR
with the reason, keeps running, diagnoses the next good window and loses nothing."""
import os

import numpy as np
import pytest

from eha_health import cli
from eha_health.io.bagrun import write_run
from eha_health.io.mcaplog import BagWriter, read_bag
from eha_health.physics.faults import Faults
from eha_health.physics.model import simulate
from eha_health.ros.replay import replay
from msg_bridge import contract as C
from msg_bridge import convert as cv

NS = 1_000_000_000
TRUTH = Faults(0.0, 0.6, 0.0)


@pytest.fixture(scope="module")
def run():
    return simulate(faults=TRUTH)


def write_window(w, r, tid, start_ns, log_ns, damage=None, skip_topic=None, marks=("start", "end")):
    """One window to the contract, messages logged in the order written (so a
    damaged stamp order survives a replay), with the test-window ``marks`` given;
    returns the next free log time."""
    stamps = start_ns + np.round(r.t * NS).astype(np.int64)
    pressure, current = r.pressure.copy(), r.current.copy()
    keep = np.ones(len(stamps), bool)
    js_stamps = stamps.copy()
    if damage == "nan":
        pressure[1700] = np.nan
    elif damage == "drop":
        keep[2200:2205] = False
    elif damage == "dup":
        js_stamps[901] = js_stamps[900]
    elif damage == "order":
        js_stamps[[1500, 1501]] = js_stamps[[1501, 1500]]
    n = 1500 if damage == "short" else len(stamps)
    t = log_ns

    def put(topic, msg):
        nonlocal t
        if topic is not skip_topic:
            w.write("/" + topic.name, topic.type, msg, t)
        t += 1000
    if "start" in marks:
        put(C.TEST_WINDOW, cv.window_msg(int(stamps[0]), "start", tid))
    for i in range(n):
        s = int(stamps[i])
        put(C.COMMAND, cv.command_msg(s, r.command[i], "eha"))
        put(C.JOINT_STATE, cv.joint_state_msg(int(js_stamps[i]), r.position[i], r.velocity[i], "eha"))
        put(C.PRESSURE, cv.pressure_msg(s, pressure[i], "eha"))
        if keep[i]:
            put(C.CURRENT, cv.current_msg(s, current[i], "eha"))
    if "end" in marks:
        put(C.TEST_WINDOW, cv.window_msg(int(stamps[n - 1]), "end", tid))
    return t


def _second_chunk(path):
    """Byte range of the second Chunk record (opcode 0x06) of an MCAP file."""
    import struct
    data, pos, seen = path.read_bytes(), 8, 0
    while pos + 9 <= len(data):
        op, n = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            seen += 1
            if seen == 2:
                return pos, pos + 9 + n
        pos += 9 + n
    raise AssertionError("fewer than 2 chunks")


CASES = {"nan": "pressure: 1 NaN/inf sample", "drop": "current: 5 sample(s) missing",
         "dup": "duplicate stamp", "order": "stamps out of order", "short": "window too short"}


@pytest.fixture(scope="module")
def bags(tmp_path_factory, run):
    d = tmp_path_factory.mktemp("bad")
    out = {}
    for damage in CASES:
        with BagWriter(d / f"{damage}.mcap") as w:
            write_window(w, run, 1, 0, 0, damage)
        out[damage] = d / f"{damage}.mcap"
    with BagWriter(d / "no_pressure.mcap") as w:
        write_window(w, run, 1, 0, 0, skip_topic=C.PRESSURE)
    out["no_pressure"] = d / "no_pressure.mcap"
    with BagWriter(d / "good.mcap") as w:
        write_run(w, run, truth={"k_gm": 0.0, "k_fsj": 0.6, "k_bkl": 0.0})
    out["good"] = d / "good.mcap"
    data = out["good"].read_bytes()
    (d / "truncated.mcap").write_bytes(data[: int(len(data) * 0.6)])
    out["truncated"] = d / "truncated.mcap"
    corrupt = bytearray(data)
    a, b = _second_chunk(out["good"])
    corrupt[(a + b) // 2: (a + b) // 2 + 64] = os.urandom(64)   # inside compressed data
    (d / "corrupt.mcap").write_bytes(bytes(corrupt))
    out["corrupt"] = d / "corrupt.mcap"
    (d / "noise.mcap").write_bytes(os.urandom(5000))
    out["noise"] = d / "noise.mcap"
    return out


@pytest.mark.parametrize("name, phrase", list(CASES.items()) + [
    ("truncated", "cut off"), ("corrupt", "damaged"),
    ("noise", "not an MCAP file"), ("absent", "no such file")])
def test_diagnose_refuses_a_bad_bag_in_one_line(bags, tmp_path, capsys, name, phrase):
    path = bags.get(name, tmp_path / "absent.mcap")
    rc = cli.main(["diagnose", str(path), "--json"])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert phrase in err and str(path) in err, err


def test_diagnose_takes_a_bag_without_a_channels_topic_as_a_csv_without_its_column(bags, capsys):
    """No eha/pressure topic: the channels it has are diagnosed (as a CSV without the pressure column
    is), and the diagnosis says pressure was not recorded (refused whole until 2026-11-27)."""
    import json
    assert cli.main(["diagnose", str(bags["no_pressure"]), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert "pressure" not in out["rms"] and {"position", "velocity", "current"} <= set(out["rms"])
    assert any("pressure" in w and "not recorded" in w for w in out["warnings"]), out["warnings"]


def test_diagnose_reads_a_good_bag_with_its_truth(bags, capsys):
    import json
    assert cli.main(["diagnose", str(bags["good"]), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["truth"] == {"k_gm": 0.0, "k_fsj": 0.6, "k_bkl": 0.0}
    assert abs(out["k_fsj"] - 0.6) <= 0.01 and out["k_gm"] <= 0.01 and out["k_bkl"] <= 0.01


def test_a_bag_whose_window_marks_complete_no_window_is_refused_not_read_whole(run, tmp_path, capsys):
    """Window marks without a complete window (a recording stopped mid-test, or started in one) were
    read as a bag without marks, whole, with the note 'no test-window marks': a part of a test was
    diagnosed and added as a test. Every reader refuses it now, naming the marks; a bag without
    any mark is still read whole, and says so."""
    import json
    stopped, between, db = tmp_path / "stopped.mcap", tmp_path / "between.mcap", tmp_path / "h.sqlite"
    with BagWriter(stopped) as w:        # every sample of test 1, then the recording stopped
        write_window(w, run, 1, 0, 0, marks=("start",))
    with BagWriter(between) as w:        # started in test 1, stopped in test 2
        t = write_window(w, run, 1, 0, 0, marks=("end",))
        write_window(w, run, 2, 10 * NS, t, marks=("start",))
    for path, said in ((stopped, "test(s) 1 (start only)"), (between, "test(s) 1 (end only), 2 (start only)")):
        for argv in (["diagnose", str(path), "--json"], ["discrepancy", str(path)],
                     ["history", "add", str(path), "--history", str(db), "--actuator", "A", "--time-h", "5"]):
            assert cli.main(argv) == 2, argv
            cap = capsys.readouterr()
            (line,) = cap.err.splitlines()
            assert cap.out == "" and f"{path}: no complete test window: the marks on /eha/test_window are of " \
                f"{said}, none with both its start and end mark" in line, line
    assert not db.exists()
    whole = tmp_path / "whole.mcap"
    with BagWriter(whole) as w:
        write_window(w, run, 1, 0, 0, marks=())
    assert cli.main(["diagnose", str(whole), "--json"]) == 0
    cap = capsys.readouterr()
    assert f"note: {whole}: no test-window marks; using the whole record" in cap.err
    assert abs(json.loads(cap.out)["k_fsj"] - 0.6) <= 0.01


@pytest.mark.graph
def test_monitor_reports_each_bad_window_and_diagnoses_the_next_good_one(run, tmp_path):
    src = tmp_path / "mixed.mcap"
    damages = list(CASES) + [None]
    with BagWriter(src) as w:
        log_ns = 0
        for tid, damage in enumerate(damages, start=1):
            log_ns = write_window(w, run, tid, (tid - 1) * 5 * NS, log_ns, damage)
    mon_log = tmp_path / "monitor.mcap"
    out = replay(src, rate=0.0, log_path=mon_log)
    res = out["results"]
    assert [r["test_id"] for r in res] == list(range(1, len(damages) + 1))
    for r, damage in zip(res[:-1], damages[:-1]):
        assert r["level"] == "ERROR" and r["diagnosis"] is None, r
        assert CASES[damage] in r["message"], (damage, r["message"])
    good = res[-1]
    assert good["diagnosis"] is not None and abs(good["diagnosis"]["k_fsj"] - 0.6) <= 0.01
    # the ERROR statuses went out on /diagnostics, with the reason, and were logged
    diag = read_bag(mon_log, topics=["/diagnostics"]).messages["/diagnostics"]
    errors = [s.message for m in diag for s in m.status if s.level == 2]
    for damage in CASES:
        assert any(CASES[damage] in e for e in errors), damage
    # nothing lost: every replayed input message is in the monitor's log
    src_bag, mon_bag = read_bag(src), read_bag(mon_log)
    for t in C.INPUTS:
        assert len(mon_bag.messages["/" + t.name]) == len(src_bag.messages["/" + t.name]), t.name
