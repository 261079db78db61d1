"""kill -9 of the monitor mid-window, three processes over DDS (issue 18, item 1).

Plant, command and monitor run as OS processes (as ``eha-health launch`` runs them) in a domain
of their own. The monitor is SIGKILLed while the second test's samples stream in: its MCAP log
reads up to the kill and holds the first window complete with its diagnosis; a restarted
monitor (new log) asks for and diagnoses the next test. Waits are on the log's content with
generous deadlines, never on sleeps. Both monitors append to one SQLite health history
(``history`` parameter): it holds every diagnosed test exactly once, and not the killed one.
"""
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eha_health.io.bagrun import complete_windows, recorded_results, resolve_topics, window_marks
from eha_health.io.mcaplog import BagError, read_bag
from eha_health.physics.faults import Faults
from eha_health.prognostics.store import list_tests
from msg_bridge import convert as cv
from eha_health.ros.launch import _ros_args
from waiting import wait_until

#: the monitor is killed and restarted on purpose; the plant or the command node must not exit
MONITOR_MAY_EXIT = ("monitor",)

pytestmark = pytest.mark.graph

ROOT = Path(__file__).resolve().parents[1]
TRUTH = Faults(0.4, 0.6, 0.4)


def _node(name: str, params: dict, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", f"eha_health.ros.{name}", *_ros_args(params)], env=env)


def _stop_all(procs: dict) -> None:
    """SIGINT what still runs, then SIGKILL what has not stopped within 30 s."""
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs.values():
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _log_state(path: Path) -> tuple[int, int]:
    """(diagnoses, command messages) readable in the live log so far."""
    try:
        bag = read_bag(path, topics=["/eha/command"], raw=True)
    except BagError:
        return 0, 0
    n = sum(1 for k in bag.metadata if k.startswith("diagnosis/test_"))
    return n, len(bag.messages.get("/eha/command", []))


def test_monitor_killed_mid_window_keeps_its_complete_windows_and_a_restart_diagnoses_the_next(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
               ROS_DOMAIN_ID=str(1 + (int(os.environ.get("ROS_DOMAIN_ID", "0")) + 90) % 200))
    first, second, history = tmp_path / "first.mcap", tmp_path / "second.mcap", tmp_path / "history.sqlite"
    procs = {
        "plant": _node("plant", {"k_gm": TRUTH.k_gm, "k_fsj": TRUTH.k_fsj, "k_bkl": TRUTH.k_bkl}, env),
        "command": _node("command", {"rate": 0.0}, env),
        "monitor": _node("monitor", {"request_tests": 3, "log_path": str(first), "plant_node": "/eha_plant",
                                     "history": str(history)}, env),
    }
    try:
        wait_until(lambda: _log_state(first)[0] >= 1, 600, "first verdict in the log", procs, MONITOR_MAY_EXIT)
        n_cmd = _log_state(first)[1]
        # the second test is streaming in: kill the monitor with a third of its window received
        wait_until(lambda: _log_state(first)[1] >= n_cmd + 1500, 600, "second test streaming", procs, MONITOR_MAY_EXIT)
        procs["monitor"].send_signal(signal.SIGKILL)
        assert procs["monitor"].wait(timeout=60) == -signal.SIGKILL

        bag = read_bag(first)
        results = recorded_results(first)
        assert [r["test_id"] for r in results] == [1]
        est = np.array([results[0]["diagnosis"][k] for k in ("k_gm", "k_fsj", "k_bkl")])
        assert np.abs(est - np.array(TRUTH.as_tuple())).max() <= 0.01
        assert len(bag.messages["/eha/command"]) >= n_cmd + 1500   # read up to the kill, inside test 2
        # every window whose end mark made it into the log is there whole (test 2 too if its end
        # came before the kill); a window cut by the kill is not complete
        wins = complete_windows(window_marks(bag, resolve_topics(bag.types, first).get("eha/test_window")))
        assert 1 in wins
        stamps = np.array([cv.stamp_ns(m.header.stamp) for m in bag.messages["/eha/command"]])
        for tid, w in wins.items():
            assert ((stamps >= w["start"]) & (stamps <= w["end"])).sum() == 3500, tid

        # a restarted monitor asks for the next test and diagnoses it
        procs["monitor"] = _node("monitor", {"request_tests": 1, "exit_after": 1, "log_path": str(second),
                                             "plant_node": "/eha_plant", "history": str(history)}, env)
        wait_until(lambda: procs["monitor"].poll() is not None, 600, "restarted monitor's verdict", procs,
                   MONITOR_MAY_EXIT)
        assert procs["monitor"].returncode == 0
    finally:
        _stop_all(procs)
    after = recorded_results(second)
    assert len(after) == 1 and after[0]["test_id"] >= 2
    est = np.array([after[0]["diagnosis"][k] for k in ("k_gm", "k_fsj", "k_bkl")])
    assert np.abs(est - np.array(TRUTH.as_tuple())).max() <= 0.01

    # the history: the two diagnosed tests, each once, with the estimates their logs hold
    rows = list_tests(history)
    assert len(rows) == 2, rows
    assert len({r["time_h"] for r in rows}) == 2 and len({r["source_hash"] for r in rows}) == 2
    logged = [results[0]["diagnosis"], after[0]["diagnosis"]]
    for row, d in zip(sorted(rows, key=lambda r: r["time_h"]), logged):
        assert [row[k] for k in ("k_gm", "k_fsj", "k_bkl")] == [d[k] for k in ("k_gm", "k_fsj", "k_bkl")]


def test_ctrl_c_during_a_long_prognosis_stops_it_and_keeps_the_diagnosis_in_log_and_history(tmp_path):
    """SIGINT to the monitor process while its prognosis fits the fleet prior of a 600-actuator
    history (a young actuator takes it: ~10 s of fitting). The node stops the fit, writes the
    finished diagnosis into its log and exits 0; the history holds the test once. Until
    2026-11-29 the shutdown waited for the whole fit and the diagnosis never reached the log
    (the worker's result was dropped)."""
    import csv
    from eha_health.bench.rul import synthetic_history_csv
    from eha_health.prognostics.store import HistoryStore
    history, log, err = tmp_path / "history.sqlite", tmp_path / "mon.mcap", tmp_path / "monitor.err"
    young = tmp_path / "young.csv"
    # gm flat for three tests: the stored history's RUL, given at start, needs no fleet prior; the fourth
    # test, the monitor's (0.06), starts a young trend that takes it
    with open(young, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl"])
        for i in range(3):
            w.writerow(["eha", 40.0 * i, 0.0, 0.0, 0.0, 0.004, 0.002, 0.002])
    with HistoryStore(history) as st:
        st.import_csv(synthetic_history_csv(tmp_path / "fleet.csv", 600, n_tests=12, seed=2))
        st.import_csv(young)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
               ROS_DOMAIN_ID=str(1 + (int(os.environ.get("ROS_DOMAIN_ID", "0")) + 95) % 200))
    with open(err, "w") as errf:
        procs = {
            "plant": _node("plant", {"k_gm": 0.06}, env),
            "command": _node("command", {"rate": 0.0}, env),
            "monitor": subprocess.Popen([sys.executable, "-m", "eha_health.ros.monitor", *_ros_args(
                {"request_tests": 1, "log_path": str(log), "history": str(history), "actuator_id": "eha",
                 "operating_hours": 120.0, "method": "deterministic"})], env=env, stderr=errf),
        }
        try:
            # the test is appended: the worker has gone on to the prognosis (the fleet prior)
            wait_until(lambda: len(list_tests(history, "eha")) == 4, 600, "the monitor's test in the history",
                       procs, MONITOR_MAY_EXIT)
            procs["monitor"].send_signal(signal.SIGINT)
            assert procs["monitor"].wait(timeout=600) == 0
        finally:
            _stop_all(procs)
    text = err.read_text()
    assert "the monitor is stopping" in text, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    results = recorded_results(log)
    assert [r["test_id"] for r in results] == [1]
    assert results[0]["diagnosis"]["k_gm"] == pytest.approx(0.06, abs=0.01)
    rows = list_tests(history, "eha")
    assert len(rows) == 4 and rows[-1]["time_h"] == 120.0 and rows[-1]["k_gm"] == results[0]["diagnosis"]["k_gm"]
    # the status it could no longer publish (Ctrl-C shut the context down) is in the log
    said = [st.message for m in read_bag(log, topics=["/diagnostics"]).messages.get("/diagnostics", []) for st in m.status]
    assert any("the monitor is stopping" in x for x in said), said
