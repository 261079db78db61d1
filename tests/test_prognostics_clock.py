"""The usage clock: wear fitted against the tests' usage, the RUL in usage and in hours."""
import json
import subprocess
import sys

import numpy as np
import pytest

from eha_health.prognostics.clock import on_usage_clock, usage_variance
from eha_health.prognostics.config import PrognosticsError, load_settings
from eha_health.prognostics.rul import prognose
from eha_health.prognostics.records import HealthRecord, history_from_records

THR = {"gm": 1.0, "fsj": 1.0, "bkl": 1.0}
USAGE = load_settings(overrides={"prognosis": {"clock": "usage"}})


def history(units, repairs=()):
    """units: {id: (time_h, usage, k_gm)}; K_FSJ and K_BKL healthy."""
    recs = [HealthRecord(a, float(t), (float(k), 0.01, 0.01), (0.005, 0.005, 0.005),
                         usage=None if not np.isfinite(u) else float(u))
            for a, (ts, us, ks) in units.items() for t, u, k in zip(ts, us, ks)]
    return history_from_records(recs, list(repairs), 0.002)


def seasonal(seed, n=16, interval=50.0):
    """Usage in 200-h seasons of lognormal rate; K_GM linear in usage, 0.4-0.7 at the last test."""
    rng = np.random.default_rng(seed)
    per_h = np.repeat(np.exp(rng.normal(0.0, 0.7, 40)), 200)
    use = np.concatenate([[0.0], np.cumsum(per_h)])
    t = np.arange(n) * interval
    u = use[t.astype(int)]
    slope = rng.uniform(0.4, 0.7) / u[-1]
    return t, u, slope * u + rng.normal(0, 0.005, n), slope


def test_the_usage_clock_merges_maps_and_refuses():
    t = np.array([0.0, 50, 100, 150, 200, 250])
    u = np.array([0.0, 40, 40, 90, 130, 170])           # no flying between the checks at 50 and 100 h
    k = np.array([0.0, 0.1, 0.12, 0.2, 0.3, 0.4])
    h, clocks, _ = on_usage_clock(history({"A": (t, u, k)}, [("A", 120.0, "gm", "repair")]))
    a, c = h.actuators["A"], clocks["A"]
    assert a.time_h.tolist() == [0.0, 40.0, 90.0, 130.0, 170.0]          # the clock is the usage
    assert a.k[1, 0] == pytest.approx(0.11) and a.std[1, 0] == pytest.approx(0.005 / np.sqrt(2))
    assert a.repairs == [(90.0, "gm", "repair")]                         # at the first test after it
    assert c.to_hours(90.0) == 150.0 and c.rate == pytest.approx(np.polyfit(t, u, 1)[0])
    # a replaced unit counts its usage from its own zero: the old unit's tests are not on its clock
    t2, u2 = np.r_[t, 300, 350, 400], np.r_[u, 10, 50, 95]
    h2, *_ = on_usage_clock(history({"A": (t2, u2, np.r_[k, 0.0, 0.05, 0.1])}))
    assert h2.actuators["A"].time_h.tolist() == [10.0, 50.0, 95.0]
    with pytest.raises(PrognosticsError, match=r"actuator B: .* time_h=100 has none"):
        on_usage_clock(history({"B": (t, np.where(t == 100, np.nan, u), k)}))
    with pytest.raises(PrognosticsError, match="actuator C: the usage clock needs a usage that grows"):
        on_usage_clock(history({"C": (t, np.full(6, np.nan), k)}))
    # not asked for: left out, not refused (it informs no fleet prior on the usage clock)
    h3, _, refused = on_usage_clock(history({"A": (t, u, k), "C": (t, np.full(6, np.nan), k)}), required={"A"})
    assert set(h3.actuators) == {"A"} and "actuator C: the usage clock needs" in refused["C"]
    # a fleet report: the actuator without a usage gets no RUL and says why; the others theirs
    fleet = prognose(history({"A": (t, u, k), "C": (t, np.full(6, np.nan), k)}), settings=USAGE, thresholds=THR)
    c = fleet["actuators"]["C"]
    assert c["overall"]["rul_median_h"] is None and "the usage clock needs" in c["faults"]["gm"]["reason"]
    assert fleet["actuators"]["A"]["faults"]["gm"]["rul_median_h"] is not None
    with pytest.raises(PrognosticsError, match="actuator C: the usage clock needs"):      # asked for: refused
        prognose(history({"A": (t, u, k), "C": (t, np.full(6, np.nan), k)}), "C", settings=USAGE, thresholds=THR)


def test_usage_variance_is_the_long_run_one():
    """Even usage has none; usage in seasons shows its variance over blocks a season long, and a
    fleet pooled sees it where one unit's history does not."""
    t = np.arange(0.0, 1000.0, 50.0)
    assert usage_variance([(t, 2.0 * t, 2.0)]) == pytest.approx(0.0, abs=1e-12)
    units = []
    for seed in range(40):
        tt, u, *_ = seasonal(seed)
        units.append((tt, u, float(np.polyfit(tt, u, 1)[0])))
    pooled = usage_variance(units)
    own = np.median([usage_variance([x]) for x in units])
    assert own < 0.5 * pooled and 60.0 < pooled < 400.0          # the process: about 206 usage^2 / h


def test_wear_in_usage_is_predicted_in_usage_and_in_hours():
    """K linear in usage that comes in seasons: the usage RUL is the truth within 10 % and its
    interval holds it; the hours are those of the usage to come at the unit's rate, with the
    seasons' spread. Even usage: the usage clock gives the time clock's hours."""
    units = {f"U{i}": seasonal(i) for i in range(12)}
    out = prognose(history({a: v[:3] for a, v in units.items()}), settings=USAGE, thresholds=THR)["actuators"]
    for a, (t, u, k, slope) in units.items():
        g = out[a]["faults"]["gm"]
        true_usage = 1.0 / slope - u[-1]
        assert g["rul_p05_usage"] <= true_usage <= g["rul_p95_usage"], (a, g)
        assert g["rul_median_usage"] == pytest.approx(true_usage, rel=0.1)
        assert g["rul_p05_h"] < g["rul_median_h"] < g["rul_p95_h"] and out[a]["overall"]["clock"] == "usage"
    t = np.arange(16) * 50.0
    even = {"E": (t, 2.0 * t, 0.0004 * t + np.random.default_rng(1).normal(0, 0.005, 16))}
    on_usage = prognose(history(even), settings=USAGE, thresholds=THR)["actuators"]["E"]["faults"]["gm"]
    on_time = prognose(history(even), thresholds=THR)["actuators"]["E"]["faults"]["gm"]
    assert on_usage["rul_median_h"] == pytest.approx(on_time["rul_median_h"], rel=0.03)
    assert on_usage["rul_median_usage"] == pytest.approx(on_time["rul_median_usage"], rel=0.03)
    assert on_usage["onset_h"] == on_time["onset_h"]                   # past times back in hours


def test_prognose_clock_usage_from_the_command_line(tmp_path):
    t, u, k, _ = seasonal(3)
    p = tmp_path / "h.csv"
    p.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl,usage\n"
                 + "".join(f"A,{a},{b},0.01,0.01,{c}\n" for a, b, c in zip(t, k, u)))
    run = [sys.executable, "-m", "eha_health.cli", "prognose", "--history", str(p), "--json"]
    r = subprocess.run(run + ["--clock", "usage"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["actuators"]["A"]["overall"]["clock"] == "usage"
    q = tmp_path / "nousage.csv"
    q.write_text("actuator_id,time_h,k_gm,k_fsj,k_bkl\n" + "".join(f"B,{a},{b},0,0\n" for a, b in zip(t, k)))
    r = subprocess.run(run[:5] + [str(q), "--clock", "usage"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "actuator B: the usage clock needs a usage" in r.stderr


def test_a_repair_on_the_ground_is_not_merged_away():
    """A repair between two checks with no usage between them: the two tests share a usage but not
    a trend. Merged (as tests at one usage are), K 0.7 and 0.02 read 0.36 and the trend restarted at
    the mixture; now the later test's clock lies just past the earlier's and the trend restarts at it."""
    t = np.arange(14) * 50.0
    u = 2.0 * t
    u[8:] -= 100.0                                    # no flying between 350 h and 400 h
    k = np.where(np.arange(14) < 8, 0.001 * u, 0.0005 * (u - u[7]) + 0.02)
    h = history({"A": (t, u, k)}, [("A", 375.0, "gm", "repair")])
    a = on_usage_clock(h)[0].actuators["A"]
    assert a.k[7, 0] == pytest.approx(0.7) and a.k[8, 0] == pytest.approx(0.02) and a.time_h[8] > a.time_h[7]
    g = prognose(h, settings=USAGE, thresholds=THR)["actuators"]["A"]["faults"]["gm"]
    assert g["n_tests"] == 6
    assert g["rul_median_usage"] == pytest.approx((1.0 - 0.02) / 0.0005 - (u[-1] - u[7]), rel=0.05)


def test_after_a_replacement_both_clocks_say_the_same_reason_and_count():
    """gm wears, then the unit is replaced (all) at 510 h and its faults stay flat: on the usage
    clock the reason said "no repair recorded" and the overall n_tests counted 6 tests where the
    time clock counted all 16 (an independent probe, 2026-11-29). Both say the current trend now."""
    recs = [HealthRecord("D", 50.0 * i, (0.02 + 0.0006 * 50 * i, 0.02, 0.02), (0.005,) * 3, usage=0.8 * 50 * i)
            for i in range(1, 11)]
    recs += [HealthRecord("D", 50.0 * i, (0.02, 0.021, 0.02), (0.005,) * 3, usage=0.8 * (50 * i - 520))
             for i in range(11, 17)]
    hist = history_from_records(recs, [("D", 510.0, "all", "replace")], 0.002)
    for clock in ("time", "usage"):
        s = load_settings(overrides={"prognosis": {"clock": clock}})
        d = prognose(hist, settings=s)["actuators"]["D"]
        gm = d["faults"]["gm"]
        assert gm["n_tests"] == 6 and d["overall"]["n_tests"] == 6, clock
        assert gm["reason"].startswith("no degradation since the last repair"), (clock, gm["reason"])
