"""The graph under faults (issue 18, items 2 and 3): a plant killed mid-test, lost messages.

Real rclpy nodes on a real executor; the killed plant is a real OS process (SIGKILL) talking
DDS to the command and monitor nodes of this process. Waits are on conditions with generous
deadlines (a busy machine), never on sleeps.
"""
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eha_health.io.window import MAX_FILL_FRACTION
from eha_health.physics.faults import Faults
from eha_health.ros.graph import Graph

pytestmark = pytest.mark.graph

ROOT = Path(__file__).resolve().parents[1]
TRUTH = Faults(0.4, 0.6, 0.4)
TOL = 0.01


def _plant_process(faults: Faults) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]))
    return subprocess.Popen([sys.executable, "-m", "eha_health.ros.plant", "--ros-args",
                             "-p", f"k_gm:={faults.k_gm!r}", "-p", f"k_fsj:={faults.k_fsj!r}",
                             "-p", f"k_bkl:={faults.k_bkl!r}"], env=env)


def _matched(g: Graph) -> bool:
    """The plant process's answers reach the monitor and its commands leave the command node."""
    return (g.command.pub_cmd.get_subscription_count() >= 2 and g.command._echo.get_publisher_count() >= 1
            and all(s.get_publisher_count() >= 1 for s in g.monitor._subs))


def test_a_plant_killed_mid_test_gives_an_incomplete_warn_and_a_returning_plant_is_diagnosed():
    with Graph(plant=False, log_path="") as g:
        proc = _plant_process(TRUTH)
        try:
            g.spin_until(lambda: _matched(g), 120.0, "plant process matched")
            ok, why = g.command.start_test()
            assert ok, why
            # mid-test: a third of the window answered, then SIGKILL (no clean shutdown)
            g.spin_until(lambda: g.monitor.received["eha/joint_state"] >= 1200, 120.0, "plant answering")
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=60)
            g.spin_until(lambda: len(g.monitor.results) >= 1, 180.0, "monitor verdict on the cut window")
            cut = g.monitor.results[0]
            assert cut["diagnosis"] is None
            assert cut["level"] == "WARN", cut["message"]
            assert "incomplete" in cut["message"] and "stop" in cut["message"], cut["message"]
            assert g.monitor._status.level == "WARN" and "incomplete" in g.monitor._status.values

            # DDS forgets the killed plant's endpoints only when its lease runs out; until then they
            # still count as matched, and a test started then would go to nobody
            g.spin_until(lambda: g.monitor._subs[1].get_publisher_count() == 0, 180.0, "killed plant forgotten")
            proc = _plant_process(TRUTH)          # a plant returns
            g.spin_until(lambda: _matched(g) and g.command._test is None, 120.0, "new plant matched")
            ok, why = g.command.start_test()
            assert ok, why
            g.spin_until(lambda: len(g.monitor.results) >= 2, 180.0, "verdict after the plant returned")
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
    nxt = g.monitor.results[1]
    assert nxt["diagnosis"] is not None, nxt["message"]
    est = np.array(nxt["diagnosis"].faults.as_tuple())
    assert np.abs(est - np.array(TRUTH.as_tuple())).max() <= TOL, est


@pytest.fixture(scope="module")
def lossless():
    with Graph(faults=TRUTH, log_path="") as g:
        r = g.run_test()
    assert r["diagnosis"] is not None, r["message"]
    return np.array(r["diagnosis"].faults.as_tuple())


def _lossy_run(loss: float, max_fill: int):
    with Graph(faults=TRUTH, log_path="", loss=loss, loss_seed=7, best_effort=True, max_fill=max_fill) as g:
        r = g.run_test()
        dropped = dict(g.relay.dropped)
    return r, dropped


def test_one_percent_loss_over_best_effort_is_filled_and_stays_within_0_01_of_lossless(lossless):
    r, dropped = _lossy_run(0.01, max_fill=10)
    assert sum(dropped.values()) > 50                       # ~1 % of 3 x 3500 samples really went
    assert r["diagnosis"] is not None, r["message"]
    filled = r["response"].meta["filled"]
    assert sum(filled.values()) >= sum(dropped.values())   # each lost message is at least one filled sample
    assert f"{sum(filled.values())} lost sample(s) filled" in r["message"], r["message"]
    est = np.array(r["diagnosis"].faults.as_tuple())
    assert np.abs(est - lossless).max() <= 0.01, (est, lossless)


def test_five_percent_loss_is_filled_up_to_the_limit_or_refused_naming_the_gap(lossless):
    r, dropped = _lossy_run(0.05, max_fill=10)
    assert sum(dropped.values()) > 300
    if r["diagnosis"] is None:      # a run of lost samples longer than the limit
        assert r["level"] == "ERROR" and "gap fill limit" in r["message"], r["message"]
    else:
        assert "lost sample(s) filled" in r["message"]
        assert max(r["response"].meta["filled"].values()) <= MAX_FILL_FRACTION * len(r["response"])


def test_without_gap_fill_a_lossy_window_is_refused_naming_the_gap():
    r, dropped = _lossy_run(0.01, max_fill=0)
    assert sum(dropped.values()) > 0
    assert r["diagnosis"] is None and r["level"] == "ERROR"
    assert "sample(s) missing, first at t=" in r["message"], r["message"]
