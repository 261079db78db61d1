"""The fleet prior kept one actuator at a time (prognostics.prior_cache) on a real SQLite history:
after a test or a repair of one actuator only it is refitted, and the prior is the one a fit of
the whole history gives, to the last bit."""
import csv

import numpy as np
import pytest

from eha_health.bench.rul import synthetic_history_csv
from eha_health.prognostics.config import load_settings
from eha_health.prognostics.prior_cache import FleetPriorCache
from eha_health.prognostics.rul import fleet_priors, prognose
from eha_health.prognostics.records import HealthRecord
from eha_health.prognostics.store import HistoryStore

N = 24


def same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for f in a:
        assert (a[f] is None) == (b[f] is None), f
        if a[f] is not None:
            assert (a[f].mu_log, a[f].sd_log, a[f].lives) == (b[f].mu_log, b[f].sd_log, b[f].lives), f


def with_usage(src, dst):
    """The synthetic history with a usage column (cycles, 1.7 per hour and unit-to-unit spread)."""
    with open(src) as f, open(dst, "w", newline="") as g:
        rows = list(csv.reader(f))
        w = csv.writer(g)
        w.writerow(rows[0] + ["usage"])
        for r in rows[1:]:
            w.writerow(r + [round(float(r[1]) * (1.2 + 0.05 * (int(r[0][1:]) % 7)), 3)])
    return dst


@pytest.mark.parametrize("clock", ["time", "usage"])
def test_one_actuators_test_or_repair_refits_only_it_and_gives_the_whole_fleets_prior(tmp_path, clock):
    s = load_settings(overrides={"prognosis": {"clock": clock}})
    csvp = synthetic_history_csv(tmp_path / "h.csv", N, n_tests=12, seed=5)
    if clock == "usage":
        csvp = with_usage(csvp, tmp_path / "hu.csv")
    db = tmp_path / "h.db"
    with HistoryStore(db, s) as st:
        st.import_csv(csvp)
    cache = FleetPriorCache(s)
    with HistoryStore(db, s) as st:
        first = cache.priors(st)
        assert cache.refitted == N
        same(first, fleet_priors(st.history(), s))
        assert all(first[f] is not None and first[f].members >= s.fleet.min_members for f in first)

        assert cache.priors(st.history()) == first and cache.refitted == 0      # nothing changed

        # one more test of one actuator: well above its trend, so its life moves
        last = st.list_tests("A0003")[-1]
        k = tuple(min(last[c] + 0.2, 1.0) for c in ("k_gm", "k_fsj", "k_bkl"))
        usage = None if clock == "time" else last["usage"] + 40 * 1.4
        st.add_tests([HealthRecord("A0003", last["time_h"] + 40.0, k, (0.003, 0.003, 0.003), usage=usage)])
        after_test = cache.priors(st)
        assert cache.refitted == 1
        same(after_test, fleet_priors(st.history(), s))
        assert any(after_test[f].lives != first[f].lives for f in first)

        # a repair of another, then its first test: its trend restarts, it leaves the members
        t0 = last["time_h"] + 10.0
        u0 = None if clock == "time" else st.list_tests("A0007")[-1]["usage"] + 10 * 1.3
        st.add_tests([HealthRecord("A0007", t0, (0.0,) * 3, (0.003,) * 3, usage=u0)])
        st.record_repair("A0007", "all", t0 - 5.0)
        after_repair = cache.priors(st)
        assert cache.refitted == 1
        same(after_repair, fleet_priors(st.history(), s))
        for f in first:
            assert "A0007" in [m[0] for m in after_test[f].lives]
            assert "A0007" not in [m[0] for m in after_repair[f].lives]

        # the repaired unit wears again: 4 more tests, a young trend that takes the fleet prior
        st.add_tests([HealthRecord("A0007", t0 + 40.0 * i, (0.02 * i,) * 3, (0.003,) * 3,
                                   usage=None if u0 is None else u0 + 40 * 1.3 * i) for i in range(1, 5)])
        young = cache.priors(st)
        assert cache.refitted == 1
        hist = st.history()
        same(young, fleet_priors(hist, s))
        # what the monitor does with it: the young unit's prognosis, the same as prognose alone
        obj = prognose(hist, "A0007", settings=s, priors=young)
        assert obj["actuators"]["A0007"]["faults"]["gm"].get("fleet_prior") is True
        assert obj == prognose(hist, "A0007", settings=s)


def test_an_actuator_that_leaves_the_history_leaves_the_prior(tmp_path):
    s = load_settings()
    csvp = synthetic_history_csv(tmp_path / "h.csv", N, n_tests=12, seed=6)
    with HistoryStore(tmp_path / "a.db", s) as st:
        st.import_csv(csvp)
        cache = FleetPriorCache(s)
        whole = cache.priors(st)
        hist = st.history()
    del hist.actuators["A0001"]
    fewer = cache.priors(hist)
    assert cache.refitted == 0
    same(fewer, fleet_priors(hist, s))
    assert all(len(fewer[f].lives) == len(whole[f].lives) - 1 for f in whole)
    assert np.isfinite([fewer[f].mu_log for f in fewer]).all()


def test_a_refit_asked_to_stop_leaves_the_cache_as_it_was_and_batches_change_nothing(tmp_path, monkeypatch):
    import os
    from eha_health.prognostics import prior_cache, rul
    monkeypatch.setattr(prior_cache, "BATCH", 5)       # 24 actuators: 5 batches
    monkeypatch.setattr(rul, "PARALLEL_MIN", 2)        # each batch's faults on threads, in parts of 2-3
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    s = load_settings()
    csvp = synthetic_history_csv(tmp_path / "h.csv", N, n_tests=12, seed=7)
    with HistoryStore(tmp_path / "a.db", s) as st:
        st.import_csv(csvp)
        hist = st.history()
    asks = []
    cache = FleetPriorCache(s, cancelled=lambda: asks.append(1) or len(asks) > 3)
    with pytest.raises(prior_cache.Cancelled, match="stopped after 15 of 24 actuators"):
        cache.priors(hist)
    assert len(asks) == 4 and cache.refitted == 0
    asks.clear()
    cache.cancelled = None
    whole = cache.priors(hist)          # the stopped refit left nothing behind: all 24 refitted
    assert cache.refitted == N
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    # in batches of 5 on threads, or all at once on one thread: the same prior to the bit
    same(whole, fleet_priors(hist, s))


def test_prognose_asks_a_cache_for_the_prior_only_when_a_fault_takes_it(tmp_path):
    s = load_settings()
    csvp = synthetic_history_csv(tmp_path / "h.csv", N, n_tests=12, seed=8)
    with HistoryStore(tmp_path / "a.db", s) as st:
        st.import_csv(csvp)
        st.add_tests([HealthRecord("A0005", 10_000.0 + 40.0 * i, (0.03 * i,) * 3, (0.003,) * 3) for i in range(4)])
        st.record_repair("A0005", "all", 9_990.0)
        hist = st.history()
    cache = FleetPriorCache(s)
    old = prognose(hist, "A0002", settings=s, priors=cache)
    assert cache.refitted == 0 and not cache._prints      # A0002 has its own 12 tests: no fleet fitted
    assert old == prognose(hist, "A0002", settings=s)
    young = prognose(hist, "A0005", settings=s, priors=cache)
    assert cache.refitted == N
    assert young["actuators"]["A0005"]["faults"]["gm"].get("fleet_prior") is True
    assert young == prognose(hist, "A0005", settings=s)
