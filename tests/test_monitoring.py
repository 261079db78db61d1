"""The monitor's logic without ROS: window queue and readiness, assembly, health policy and verdict."""
import numpy as np
import pytest

from eha_health import simulate
from eha_health.identification.diagnose import diagnose
from eha_health.io.bagrun import read_run
from eha_health.monitoring.health import HealthPolicy, results_summary
from eha_health.monitoring.windows import CHANNELS, WindowTracker

NS = 1_000_000_000


@pytest.fixture(scope="module")
def run():
    return simulate()


def _feed(tr: WindowTracker, r, t0_ns: int, part: slice = slice(None), skip: str | None = None):
    stamps = t0_ns + np.round(r.t * NS).astype(np.int64)
    for c in CHANNELS:
        if c == skip:
            continue
        for ns, v in zip(stamps[part], getattr(r, c)[part]):
            tr.put(c, int(ns), float(v))
    return stamps


def test_window_is_ready_once_every_channel_reaches_its_end_and_assembles(run):
    tr = WindowTracker()
    stamps = _feed(tr, run, 5 * NS, slice(0, -10))
    w = tr.mark(int(stamps[0]), "start", 7, now=0.0, timeout_s=2.0)
    tr.mark(int(stamps[-1]), "end", 7, now=0.0, timeout_s=2.0)
    assert tr.ready(now=0.1, timeout_s=2.0) == [] and tr.waiting     # the last samples are still to come
    _feed(tr, run, 5 * NS, slice(-10, None))
    assert [x.id for x in tr.ready(now=0.2, timeout_s=2.0)] == [7] and not tr.waiting
    r = tr.assemble(w)
    np.testing.assert_array_equal(r.position, run.position)
    assert r.t[0] == 0.0 and r.meta["test_id"] == 7


def test_a_window_whose_samples_stop_is_taken_at_its_deadline_and_refused_by_name(run):
    tr = WindowTracker()
    stamps = _feed(tr, run, 0, skip="current")                 # the current channel never arrives
    w = tr.mark(int(stamps[0]), "start", 3, now=10.0, timeout_s=2.0)
    tr.mark(int(stamps[-1]), "end", 3, now=10.0, timeout_s=2.0)
    assert tr.ready(now=11.0, timeout_s=2.0) == []
    assert tr.ready(now=12.5, timeout_s=2.0) == []             # progress seen at 11.0 moved the deadline to 13.0
    assert [x.id for x in tr.ready(now=13.1, timeout_s=2.0)] == [3]
    with pytest.raises(ValueError, match="current: no samples in the test window"):
        tr.assemble(w)


def test_windows_are_taken_in_order_and_forgotten(run):
    tr = WindowTracker()
    stamps = _feed(tr, run, 0)
    for tid in (1, 2):
        tr.mark(int(stamps[0]), "start", tid, 0.0, 1.0)
    tr.mark(int(stamps[-1]), "end", 2, 0.0, 1.0)
    tr.mark(int(stamps[-1]), "end", 1, 0.0, 1.0)
    assert [w.id for w in tr.ready(0.0, 1.0)] == [2, 1]
    tr.forget(1)
    assert set(tr.windows) == {2}


def test_a_long_run_holds_only_the_samples_an_open_window_can_need(run):
    """Soak (issue 18): after each reported window the buffers keep no samples of it, only those of
    a later test that arrived before its marks; an open window's samples stay until it is reported."""
    tr, period = WindowTracker(), 4 * NS
    for tid in range(1, 21):
        stamps = _feed(tr, run, tid * period)
        tr.mark(int(stamps[0]), "start", tid, 0.0, 1.0)
        tr.mark(int(stamps[-1]), "end", tid, 0.0, 1.0)
        early = _feed(tr, run, (tid + 1) * period, slice(0, 5))    # the next test's first samples, marks not yet here
        (w,) = tr.ready(0.0, 1.0)
        r = tr.assemble(w)
        tr.forget(tid)
        assert {c: len(b) for c, b in tr.buffers.items()} == {c: 5 for c in CHANNELS}
        assert all(b[0][0] == early[0] for b in tr.buffers.values())
        for c in CHANNELS:                                          # the next feed repeats them: start clean
            tr.buffers[c].clear()
    np.testing.assert_array_equal(r.position, run.position)
    stamps = _feed(tr, run, 0)
    tr.mark(int(stamps[0]), "start", 1, 0.0, 1.0)                   # open, no end yet
    tr.mark(int(stamps[0]), "start", 2, 0.0, 1.0)
    tr.mark(int(stamps[-1]), "end", 2, 0.0, 1.0)
    tr.forget(2)
    assert all(len(b) == len(stamps) for b in tr.buffers.values())


def test_health_policy_levels_follow_the_largest_coefficient():
    p = HealthPolicy(warn_level=0.3, error_level=0.7)
    assert p.level((0.1, 0.2, 0.29))[0] == "OK"
    level, why = p.level((0.1, 0.45, 0.2))
    assert level == "WARN" and why.startswith("K_FSJ = 0.450")
    level, why = p.level((0.71, 0.45, 0.2))
    assert level == "ERROR" and "K_GM" in why and "near the fault limit" in why
    v = p.refused(4, "pressure: gap of 2.000 ms")
    assert v.level == "ERROR" and v.values == {"test_id": 4, "error": "pressure: gap of 2.000 ms"}


def test_verdict_of_a_real_diagnosis_carries_the_status_values():
    r = read_run("bags/combined.mcap").response          # gm 0.4, fsj 0.6, bkl 0.4
    d = diagnose(r, method="deterministic")
    v = HealthPolicy().verdict(1, 2 * NS, d)
    assert v.level == "WARN" and "K_FSJ" in v.message
    for n in ("k_gm", "k_fsj", "k_bkl"):
        assert v.values[n] == getattr(d.faults, n) and v.values[n + "_std"] == d.std[n]
    assert v.values["window_start_s"] == 2.0 and v.values["method"] == "deterministic"
    assert v.values["guard"] == "none"      # no guard outside the fast method
    line = results_summary([{"test_id": 1, "diagnosis": d.as_dict(), "truth": {"k_gm": 0.4, "k_fsj": 0.6, "k_bkl": 0.4}}])
    assert line.startswith("test 1: K_GM=") and "(truth 0.600)" in line
