"""prognose: the JSON object of issue 16, its rules (few tests, repairs, fleet prior), bad input,
the plot, physics thresholds, settings and metrics."""
import csv
import json
import math
import re

import numpy as np
import pytest

from eha_health.prognostics import metrics as M
from eha_health.prognostics.config import PrognosticsError, load_settings
from eha_health.prognostics.degradation import degradation_segment, rise_onset
from eha_health.prognostics.rul import plot_prognosis, prognose
from eha_health.prognostics.records import HealthRecord
from eha_health.prognostics.store import HistoryStore
from eha_health.prognostics.thresholds import METRICS, failure_thresholds

THR = {"gm": 0.8, "fsj": 0.9, "bkl": 0.85}     # explicit thresholds: these tests need no simulation
F_KEYS = {"model", "rul_median_h", "rul_p05_h", "rul_p95_h", "p_fail_next", "threshold", "n_tests"}


def write_history(path, n_act=5, n_tests=14, seed=0, rate_gm=0.001, noise=0.004, extra=None):
    rng = np.random.default_rng(seed)
    rows = []
    for a in range(n_act):
        rate = rate_gm * math.exp(0.2 * rng.standard_normal())
        for i in range(n_tests):
            t = 50.0 * i
            rows.append({"actuator_id": f"A{a}", "time_h": t,
                         "k_gm": min(1.5, max(0.0, rate * max(t - 60, 0) + rng.normal(0, noise))),
                         "k_fsj": 0.0, "k_bkl": 0.0005 * i, "std_gm": noise, "std_fsj": 0.001, "std_bkl": 0.001,
                         "usage": 2.0 * t})
    rows += extra or []
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    return rows


def one_actuator_csv(tmp_path, rows):
    """A HISTORY.csv at tmp_path/h.csv of rows (actuator, time_h, 3 K, 3 std)."""
    h = tmp_path / "h.csv"
    with open(h, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl"])
        w.writerows(rows)
    return h


def test_json_object_of_the_issue(tmp_path):
    h = tmp_path / "h.csv"
    write_history(h)
    obj = prognose(h, thresholds=THR, next_check_h=100.0)
    assert set(obj) == {"actuators"}
    assert json.loads(json.dumps(obj)) == obj           # plain JSON: no NaN, no numpy types
    a = obj["actuators"]["A0"]
    assert set(a) == {"faults", "overall"} and set(a["faults"]) == {"gm", "fsj", "bkl"}
    for f in list(a["faults"].values()) + [a["overall"]]:
        assert F_KEYS <= set(f)
        if f["rul_median_h"] is None:
            assert f["reason"]
    gm = a["faults"]["gm"]
    assert gm["rul_p05_h"] <= gm["rul_median_h"] <= gm["rul_p95_h"]
    assert gm["threshold"] == THR["gm"] and gm["n_tests"] == 14
    assert 0.0 <= gm["p_fail_next"] <= 1.0
    assert gm["rul_median_usage"] == pytest.approx(2.0 * gm["rul_median_h"], rel=1e-3)
    # fsj never moves: no RUL, and the reason says so; overall is the gm RUL and names it
    assert a["faults"]["fsj"]["rul_median_h"] is None and "no degradation" in a["faults"]["fsj"]["reason"]
    assert a["overall"]["dominant_fault"] == "gm"
    assert a["overall"]["rul_median_h"] == gm["rul_median_h"]


def test_rul_follows_the_trend_and_p_fail_grows_with_the_interval(tmp_path):
    h = tmp_path / "h.csv"
    write_history(h, n_act=1, n_tests=12, noise=0.002)
    short = prognose(h, thresholds=THR, next_check_h=10.0)["actuators"]["A0"]["faults"]["gm"]
    long = prognose(h, thresholds=THR, next_check_h=500.0)["actuators"]["A0"]["faults"]["gm"]
    expected = (THR["gm"] / 0.001 + 60.0) - 550.0      # the linear law reaches 0.8 at 860 h
    assert short["rul_p05_h"] <= expected * 1.1 and short["rul_p95_h"] >= expected * 0.9
    assert short["p_fail_next"] <= long["p_fail_next"]
    assert short["rul_median_h"] == long["rul_median_h"]


def test_same_seed_same_result_and_independent_of_other_actuators(tmp_path):
    h1, h2 = tmp_path / "a.csv", tmp_path / "b.csv"
    rows = write_history(h1, n_act=2)
    write_history(h2, n_act=2, extra=[{**rows[0], "actuator_id": "Z", "k_gm": 0.0}])
    o1 = prognose(h1, thresholds=THR)
    assert prognose(h1, thresholds=THR) == o1
    # a new actuator without a trend changes nobody's result (no fleet prior in play: >= 6 points each)
    assert prognose(h2, thresholds=THR)["actuators"]["A1"] == o1["actuators"]["A1"]


def test_few_tests_and_repair_restart_the_trend(tmp_path):
    db = tmp_path / "h.sqlite"
    with HistoryStore(db) as st:
        recs = [HealthRecord("R", 50.0 * i, (min(0.002 * 50 * i, 1.5), 0.0, 0.0), (0.002, 0.001, 0.001))
                for i in range(8)]
        st.add_tests(recs)
        st.add_tests([HealthRecord("R", 400.0, (0.0, 0.0, 0.0), (0.002, 0.001, 0.001))])
        st.record_repair("R", "gm", 400.0)
        st.add_tests([HealthRecord("R", 450.0, (0.02, 0.0, 0.0), (0.002, 0.001, 0.001))])
    gm = prognose(db, thresholds=THR)["actuators"]["R"]["faults"]["gm"]
    assert gm["rul_median_h"] is None and gm["n_tests"] == 2
    assert "2 test(s) since the last repair" in gm["reason"] and "fewer than 3" in gm["reason"]
    # before the repair the same actuator had a RUL
    with HistoryStore(tmp_path / "before.sqlite") as st:
        st.add_tests(recs)
    assert prognose(tmp_path / "before.sqlite", thresholds=THR)["actuators"]["R"]["faults"]["gm"]["rul_median_h"] > 0


def test_a_rise_that_shows_at_one_test_gets_a_rul_from_the_onset_candidates(tmp_path):
    # flat for 8 tests, then one test clearly above the noise: the onset anchor is the test before it
    t = 50.0 * np.arange(9)
    k = np.r_[np.full(8, 0.01), 0.06]
    h = one_actuator_csv(tmp_path, (["A", ti, ki, 0.0, 0.0, 0.003, 0.001, 0.001] for ti, ki in zip(t, k)))
    gm = prognose(h, thresholds=THR)["actuators"]["A"]["faults"]["gm"]
    assert gm["n_points"] == 2 and gm["onset_posterior"]        # every post-repair point is fitted
    assert gm["rul_p05_h"] > 0
    assert gm["rul_p95_h"] is None and "beyond the prediction horizon" in gm["reason"]   # one test of rise: wide
    # ... and it may be a failed diagnosis: said, and half the samples are the flat history's (no
    # failure ahead); the rise alone (nothing judged off the trend) has a RUL of its own
    assert gm["last_test_off_trend"] and 0.0 < gm["p_fail_next"] < 0.5
    alone = load_settings(overrides={"prognosis": {"outlier_sigma": 0.0}})
    gm0 = prognose(h, thresholds=THR, settings=alone)["actuators"]["A"]["faults"]["gm"]
    assert gm0["n_points"] == 2 and gm0["rul_median_h"] > 0 and gm0["rul_p05_h"] < gm0["rul_median_h"]
    one = load_settings(overrides={"prognosis": {"onset_candidates": 1}})
    gm1 = prognose(h, thresholds=THR, settings=one)["actuators"]["A"]["faults"]["gm"]
    assert gm1["rul_median_h"] is None and "only 2 points since then" in gm1["reason"]


def test_fleet_prior_for_an_actuator_with_few_points(tmp_path):
    h = tmp_path / "h.csv"
    rows = write_history(h, n_act=6, n_tests=14, seed=4)
    young = [{**r, "actuator_id": "Y"} for r in rows[:4]]          # onset at 60 h, 3 points since
    write_history(h, n_act=6, n_tests=14, seed=4, extra=young)
    y = prognose(h, thresholds=THR)["actuators"]["Y"]["faults"]["gm"]
    assert y["fleet_prior"] is True and y["rul_median_h"] is not None
    old = prognose(h, thresholds=THR)["actuators"]["A1"]["faults"]["gm"]
    assert old["fleet_prior"] is False
    s = load_settings(overrides={"fleet": {"min_members": 100}})
    y2 = prognose(h, thresholds=THR, settings=s)["actuators"]["Y"]["faults"]["gm"]
    assert y2["fleet_prior"] is False
    # the prior narrows the interval of the young actuator (without it, 3 points since onset may
    # leave the 95 % quantile beyond the prediction horizon: null, an unbounded interval)
    def width(f):
        assert f["rul_p05_h"] is not None
        if f["rul_p95_h"] is None:
            assert "beyond the prediction horizon" in f["reason"]
            return math.inf
        return f["rul_p95_h"] - f["rul_p05_h"]
    assert width(y) < width(y2)


def test_bad_input_one_line(tmp_path):
    h = tmp_path / "h.csv"
    write_history(h, n_act=1)
    cases = [
        (lambda: prognose(h, actuator="nope", thresholds=THR), "unknown actuator 'nope'"),
        (lambda: prognose(h, next_check_h=-1, thresholds=THR), "next-check"),
        (lambda: prognose(tmp_path / "missing.sqlite", thresholds=THR), "no such history"),
    ]
    empty = tmp_path / "empty.sqlite"
    HistoryStore(empty).close()
    cases.append((lambda: prognose(empty, thresholds=THR), "empty"))
    for call, message in cases:
        with pytest.raises(PrognosticsError, match=message) as e:
            call()
        assert "\n" not in str(e.value)


def test_plot_writes_a_png(tmp_path):
    h = tmp_path / "h.csv"
    write_history(h, n_act=2)
    png = tmp_path / "p.png"
    obj = plot_prognosis(h, png, "A1", settings=load_settings(overrides={"requirements": []}))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert obj["actuators"]["A1"]["faults"]["gm"]["threshold"] == 1.0   # no requirement: K = 1


def test_thresholds_from_the_physics():
    from eha_health import FDISequence, Faults, simulate
    s = load_settings()
    th = failure_thresholds(s)
    seq = FDISequence()
    for f, t in th.items():
        if t.requirement is None:
            assert t.k == s.thresholds.default
            continue
        assert 0 < t.k < s.thresholds.search_max
        fn = METRICS[t.metric][1]
        above = fn(simulate(faults=Faults(**{f"k_{f}": t.k + 2 * s.thresholds.tolerance})), seq)
        below = fn(simulate(faults=Faults(**{f"k_{f}": t.k - 2 * s.thresholds.tolerance})), seq)
        assert below <= t.limit < above, (f, below, t.limit, above)
    none = failure_thresholds(load_settings(overrides={"requirements": []}))
    assert {f: t.k for f, t in none.items()} == {"gm": 1.0, "fsj": 1.0, "bkl": 1.0}


def test_settings_errors_name_the_problem(tmp_path):
    with pytest.raises(PrognosticsError, match="prognosis.samples"):
        load_settings(overrides={"prognosis": {"samples": "many"}})
    with pytest.raises(PrognosticsError, match="unknown setting"):
        load_settings(overrides={"prognosis": {"sample": 10}})
    with pytest.raises(PrognosticsError, match="unknown metric"):
        load_settings(overrides={"requirements": [{"name": "x", "metric": "speed", "limit": 1.0}]})
    p = load_settings().prognosis
    assert p.warn_p_fail <= p.error_p_fail and p.next_check_h > 0


@pytest.mark.parametrize("over, why", [
    # an independent probe (2026-11-29) found each accepted: a hang, a silent skip, a traceback or
    # figures changed without a word
    ({"thresholds": {"tolerance": 0.0}}, "thresholds.tolerance must be within"),
    ({"thresholds": {"tolerance": 5.0}}, "thresholds.tolerance must be within"),
    ({"thresholds": {"scan_points": 0}}, "thresholds.scan_points must be within"),
    ({"models": {"criterion": "bogus"}}, "models.criterion must be evidence or aicc"),
    ({"models": {"aic_delta_max": -1.0}}, "models.aic_delta_max must be > 0"),
    ({"models": {"names": ["wiener", "wiener"]}}, "without a model named twice"),
    ({"models": {"exponential_rate": []}}, "models.exponential_rate must be a non-empty list"),
    ({"models": {"power_exponent": [0.5, -1.0]}}, "models.power_exponent must be"),
    ({"models": {"diffusion": [0.0]}}, "models.diffusion must be"),
    ({"models": {"scatter": [float("nan")]}}, "models.scatter must be"),
    ({"models": {"wiener_exponent": ["x"]}}, "models.wiener_exponent must be"),
    # a blow-up within the data (c <= 1 span) would make g infinite at a test
    ({"models": {"hyperbolic_blowup": [1.0]}}, "models.hyperbolic_blowup must be"),
    ({"models": {"wiener_hyperbolic_blowup": [2.0, 0.5]}}, "models.wiener_hyperbolic_blowup must be"),
    ({"models": {"names": ["wiener", "gamma"]}}, "models.names: choose from"),
    ({"prognosis": {"horizon_factor": 0.0}}, "prognosis.horizon_factor must be > 0"),
    ({"prognosis": {"min_std": 0.0}}, "prognosis.min_std must be > 0"),
    ({"prognosis": {"seed": -1}}, "prognosis.seed must be >= 0"),
    ({"prognosis": {"samples": 100_000_000}}, "prognosis.samples must be within"),
    ({"prognosis": {"onset_sigma": -1.0}}, "prognosis.onset_sigma must be > 0"),
    ({"history": {"default_std": -0.1}}, "history.default_std must be > 0"),
    ({"fleet": {"min_members": 0}}, "fleet.min_members must be >= 1"),
    ({"bench": {"n_units": -1}}, "bench.n_units must be >= 1"),
    # a fault's own model set is checked as models: is, under its own name
    ({"fault_models": {"fsj": {"names": ["gamma"]}}}, "fault_models.fsj.names: choose from"),
    ({"fault_models": {"fsj": {"names": []}}}, "fault_models.fsj.names is empty"),
    ({"models": {"names": [["wiener"]]}}, "models.names: choose from"),
    ({"prognosis": {"samples": 1}}, "prognosis.samples must be within [100, 100000], got 1"),
    ({"prognosis": {"next_check_h": 0.0}}, "prognosis.next_check_h must be > 0 h, got 0.0"),
    ({"prognosis": {"min_tests": -1}}, "prognosis.min_tests must be >= 3 (a trend needs three points), got -1"),
    ({"fault_models": {"bkl": {"diffusion": [0.0]}}}, "fault_models.bkl.diffusion must be"),
    ({"fault_models": {"gm": {"shape": 2}}}, "fault_models.gm: unknown setting(s) ['shape']"),
    ({"fault_models": {"k_fsj": {"names": ["linear"]}}}, "fault_models: unknown fault(s) ['k_fsj']; faults: gm, fsj, bkl"),
    ({"fault_models": {"fsj": ["wiener"]}}, "fault_models.fsj: expected a mapping"),
    ({"fault_models": ["fsj"]}, "fault_models: expected a mapping of fault"),
])
def test_settings_out_of_range_are_refused_by_name(over, why):
    with pytest.raises(PrognosticsError, match=re.escape(why)):
        load_settings(overrides=over)


@pytest.mark.parametrize("text, why", [("- a\n- b\n", "got list"), ("3\n", "got int"), ("just text\n", "got str")])
def test_a_settings_file_that_is_not_a_mapping_is_one_line(tmp_path, text, why):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    with pytest.raises(PrognosticsError, match=f"{re.escape(str(p))}: settings must be a mapping.*{why}"):
        load_settings(p)
    p.write_bytes(b"prognosis:\n  seed: \xff\xfe\n")
    with pytest.raises(PrognosticsError, match=f"{re.escape(str(p))}: cannot read settings"):
        load_settings(p)


def test_loosening_a_requirement_never_lowers_its_threshold():
    """A probe found 1.36 mm of sine error giving K_BKL 1.486 and 1.40 mm the default 1.0: a
    requirement now lowers the threshold below the default (K = 1), never raises it above."""
    req = next(r for r in load_settings().requirements if r.metric == "sine_peak_error")
    ks = []
    for scale in (1.0, 1.3, 2.2, 2.5, 9.0):
        s = load_settings(overrides={"requirements": [{"name": req.name, "metric": req.metric,
                                                      "limit": req.limit * scale}]})
        ks.append(failure_thresholds(s))
    for f in ("gm", "bkl"):
        seq = [t[f].k for t in ks]
        assert seq == sorted(seq) and seq[-1] == 1.0, (f, seq)
        assert all(t[f].k <= 1.0 for t in ks)
    tight = load_settings(overrides={"requirements": [{"name": "r", "metric": req.metric, "limit": 1e-5}]})
    with pytest.raises(PrognosticsError, match="healthy reference EHA already breaks requirement"):
        failure_thresholds(tight)


def test_metrics_by_their_definitions():
    eol = 1000.0
    t = np.array([200.0, 400.0, 600.0, 800.0])
    truth = eol - t
    perfect = truth.copy()
    assert M.alpha_lambda(t, perfect, eol, 0.2, 0.5) is True
    late = truth * 1.5
    assert M.alpha_lambda(t, late, eol, 0.2, 0.5) is False
    # lambda 0.5: t_lambda = 600 h, the prediction then in force is the one at 600 h
    mixed = np.array([truth[0] * 2, truth[1] * 2, truth[2], truth[3] * 3])
    assert M.alpha_lambda(t, mixed, eol, 0.2, 0.5) is True
    assert M.prognostic_horizon(t, perfect, eol, 0.2) == eol - 200.0
    assert M.prognostic_horizon(t, mixed, eol, 0.2) == eol - 600.0
    assert M.prognostic_horizon(t, mixed, eol, 0.2, stay=True) == 0.0
    np.testing.assert_allclose(M.relative_accuracy(perfect, truth), 1.0)
    assert M.cumulative_relative_accuracy(late, truth) == pytest.approx(0.5)
    assert M.convergence(t, perfect, eol) == pytest.approx(0.0)
    assert M.convergence(t, late, eol) > 0
    assert M.coverage(truth - 1, truth + 1, truth) == 1.0
    assert np.all(M.nasa_score(perfect, truth, eol) == 0)
    s_late, s_early = M.nasa_score(truth + 50, truth, eol), M.nasa_score(truth - 50, truth, eol)
    assert np.all(s_late > s_early)
    assert M.naive_rul(np.arange(5.0), 0.1 * np.arange(5.0), 1.0, 5) == pytest.approx(6.0)
    assert M.naive_rul(np.arange(5.0), np.zeros(5), 1.0, 5) == math.inf


def _one_actuator(path, k_of_t, noise, seed, n=16):
    rng = np.random.default_rng(seed)
    t = 50.0 * np.arange(n)
    y = np.clip(k_of_t(t) + rng.normal(0, noise, n), 0, 1.5)
    rows = [{"actuator_id": "A", "time_h": ti, "k_gm": yi, "k_fsj": 0.0, "k_bkl": 0.0, "std_gm": noise,
             "std_fsj": 0.001, "std_bkl": 0.001} for ti, yi in zip(t, y)]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)


def test_onset_weighed_by_the_evidence(tmp_path):
    """Onset candidates from the first test to the anchor: a rise that starts late puts the weight on
    the anchor; a convex rise from the first test (flat within noise at first, so the anchor is later)
    puts weight on the earlier onset, and the interval holds the true RUL (the anchor alone missed seed 2:
    262-277 h for a true 250 h)."""
    h = tmp_path / "h.csv"
    _one_actuator(h, lambda t: 0.02 + 0.001 * np.maximum(t - 400.0, 0.0), 0.004, 0)
    obj, det = prognose(h, thresholds=THR, details=True)
    d, f = det["A"]["gm"], obj["actuators"]["A"]["faults"]["gm"]
    assert len(d.candidate_onsets_h) == 4 and d.candidate_onsets_h[0] == 0.0
    assert d.candidate_onsets_h[-1] == f["onset_h"] == 400.0 and d.onset_weights[-1] > 0.9
    assert list(f["onset_posterior"]) == ["0", "150", "250", "400"] and f["onset_posterior"]["400"] > 0.9
    assert json.loads(json.dumps(obj)) == obj
    assert f["rul_p05_h"] <= 1196.0 - 750.0 <= f["rul_p95_h"]
    for seed in range(3):
        _one_actuator(h, lambda t: 0.02 + 0.796 * np.expm1(2.5 * t / 1000.0) / np.expm1(2.5), 0.004, seed)
        obj, det = prognose(h, thresholds=THR, details=True)
        d, f = det["A"]["gm"], obj["actuators"]["A"]["faults"]["gm"]
        assert f["onset_h"] > 0.0 and d.candidate_onsets_h[0] == 0.0 and d.onset_weights[0] > 0.1
        assert f["rul_p05_h"] <= 250.0 <= f["rul_p95_h"], (seed, f)
    # the anchor alone (seed 2) missed with the library of finite shapes: 254-269 h, the candidates
    # 219-290 h. The hyperbolic time scale (section 3) widens convex intervals enough to hold it
    # either way (175-266 h alone, 177-268 h with the candidates), so the contrast is drawn without it
    finite = {"models": {"wiener_hyperbolic_blowup": []}}
    f = prognose(h, thresholds=THR, settings=load_settings(overrides=finite))["actuators"]["A"]["faults"]["gm"]
    assert f["rul_p05_h"] <= 250.0 <= f["rul_p95_h"]
    one = load_settings(overrides={**finite, "prognosis": {"onset_candidates": 1}})
    f = prognose(h, thresholds=THR, settings=one)["actuators"]["A"]["faults"]["gm"]
    assert not f["rul_p05_h"] <= 250.0 <= f["rul_p95_h"]


def test_a_fault_already_beyond_its_threshold_beside_a_degrading_one(tmp_path):
    # K_FSJ came in at 1.0, above its threshold, and stays there; K_GM degrades. prognose raised
    # ValueError (the RUL-0 fault had 1 sample, the other 2000) until 2026-11-28
    t = 50.0 * np.arange(12)
    h = one_actuator_csv(tmp_path, (["A", ti, 0.0008 * ti, 1.0, 0.0, 0.003, 0.003, 0.001] for ti in t))
    a = prognose(h, thresholds=THR)["actuators"]["A"]
    assert a["faults"]["fsj"]["rul_median_h"] == 0.0 and "at or beyond the threshold" in a["faults"]["fsj"]["reason"]
    assert a["faults"]["gm"]["rul_median_h"] > 0
    assert a["overall"]["rul_median_h"] == 0.0 and a["overall"]["dominant_fault"] == "fsj"
    assert a["overall"]["p_fail_next"] == 1.0


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_nothing_fixes_a_time_scale(tmp_path, scale):
    """A rig whose life is an hour and an aircraft whose life is a thousand hours are the same
    problem in other units: every time and RUL scales, every probability stays (the RULs were
    rounded to 0.1 h before, so an accelerated test's 0.35 h read 0.3 or 0.4)."""
    rows = write_history(tmp_path / "base.csv", n_act=4)
    with open(tmp_path / "scaled.csv", "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows({**r, "time_h": r["time_h"] * scale} for r in rows)
    base = prognose(tmp_path / "base.csv", thresholds=THR, next_check_h=100.0)["actuators"]
    scaled = prognose(tmp_path / "scaled.csv", thresholds=THR, next_check_h=100.0 * scale)["actuators"]
    compared = 0
    for a, obj in base.items():
        for f in ("gm", "fsj", "bkl", "overall"):
            b = obj["faults"][f] if f != "overall" else obj["overall"]
            s = scaled[a]["faults"][f] if f != "overall" else scaled[a]["overall"]
            assert (b["rul_median_h"] is None) == (s["rul_median_h"] is None)
            assert s["p_fail_next"] == b["p_fail_next"] and s.get("n_points") == b.get("n_points")
            for k in ("rul_p05_h", "rul_median_h", "rul_p95_h", "onset_h"):
                if b.get(k) is not None:
                    assert s[k] / scale == pytest.approx(b[k], rel=1e-3), (a, f, k)
                    compared += 1
    assert compared >= 4 * 7              # gm (with its onset) and overall of every actuator, at least


def test_table_hours_keep_their_precision_at_any_scale():
    from eha_health.prognostics.rul import format_hours
    assert [format_hours(v) for v in (None, 0.03456, 3.456, 99.95, 1234.5)] == ["-", "0.0346", "3.46", "100", "1234"]


def test_an_exact_history_states_zero_errors(tmp_path):
    """A synthetic history may state std 0 (an exact K). The models take at least
    prognosis.min_std: a zero variance made the likelihood singular (no model weights, no median)."""
    h = tmp_path / "exact.csv"
    rows = [{"actuator_id": "X", "time_h": 50.0 * i, "k_gm": 0.001 * 50.0 * i, "k_fsj": 0.0, "k_bkl": 0.0,
             "std_gm": 0.0, "std_fsj": 0.0, "std_bkl": 0.0} for i in range(12)]
    with open(h, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    gm = prognose(h, thresholds=THR)["actuators"]["X"]["faults"]["gm"]
    true = THR["gm"] / 0.001 - 550.0
    assert gm["model_weights"] and gm["rul_median_h"] == pytest.approx(true, rel=0.01)
    assert gm["rul_p05_h"] <= true <= gm["rul_p95_h"] and gm["std_last"] == 0.0     # reported as stated
    fsj = prognose(h, thresholds=THR)["actuators"]["X"]["faults"]["fsj"]
    assert "K 0.0000 +- 0.0000 " in fsj["reason"]                                  # as stated, not the floor


def test_a_next_check_beyond_the_prediction_horizon_gives_a_lower_bound(tmp_path):
    """Samples beyond the horizon (20 data spans) may fail before a check further out or after it:
    P(fail before the next check) is then only bounded below. Before, they counted as 'after' and
    a rig history spanning 0.06 h, asked about a check in 50 h, read p_fail_next 0.005 for a fault
    whose linear trend crosses in about 3.6 h."""
    h = tmp_path / "rig.csv"
    rows = [{"actuator_id": "R", "time_h": 0.004 * i, "k_gm": 0.0, "k_fsj": 0.001 * i, "k_bkl": 0.0,
             "std_gm": 1e-4, "std_fsj": 1e-4, "std_bkl": 1e-4} for i in range(15)]
    with open(h, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    far = prognose(h, thresholds=THR, next_check_h=50.0)["actuators"]["R"]["faults"]["fsj"]
    assert far["rul_median_h"] is None and far["p_fail_next"] is None
    assert 0.0 <= far["p_fail_next_min"] < 1.0 and "beyond the prediction horizon" in far["reason"]
    near = prognose(h, thresholds=THR, next_check_h=0.01)["actuators"]["R"]["faults"]["fsj"]
    assert near["p_fail_next"] is not None and "p_fail_next_min" not in near
    # the table says it is a bound
    from eha_health.cli.prognostics import format_prognosis
    obj = prognose(h, thresholds=THR, next_check_h=50.0)
    assert f">= {far['p_fail_next_min']:.3f}" in format_prognosis(obj, 50.0)


def test_a_trend_already_past_its_threshold_says_so(tmp_path):
    h = tmp_path / "past.csv"
    rows = [{"actuator_id": "P", "time_h": 50.0 * i, "k_gm": min(1.5, 0.0016 * 50.0 * i), "k_fsj": 0.01,
             "k_bkl": 0.02} for i in range(12)]
    with open(h, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    gm = prognose(h, thresholds=THR)["actuators"]["P"]["faults"]["gm"]
    assert gm["rul_median_h"] == 0.0 and gm["p_fail_next"] == 1.0
    assert gm["reason"] == f"K {rows[-1]['k_gm']:.3f} at or beyond the threshold {THR['gm']:.3f}: RUL 0"


def test_overall_is_never_less_pessimistic_than_a_fault_on_the_fleet_prior(tmp_path):
    # Young actuators whose faults sit on the fleet prior carry importance weights. Pairing the
    # faults' samples sample by sample (weight = product of the weights) re-weighted one fault
    # by the other's prior: the overall came out later than a single fault's RUL, which
    # first-to-threshold cannot be (here: p05 598 h against bkl's 584 h, P(fail) 0.41 against 0.49).
    rng = np.random.default_rng(12)
    rows = []
    for a in range(8):        # gm and bkl wear alike; the diagnoses scatter 3x their stated error
        rg, rb = 0.001 * math.exp(0.1 * rng.standard_normal()), 0.00106 * math.exp(0.1 * rng.standard_normal())
        for i in range(14):
            t = 50.0 * i
            rows.append({"actuator_id": f"A{a}", "time_h": t,
                         "k_gm": max(0.0, rg * max(t - 60, 0) + rng.normal(0, 0.015)), "k_fsj": 0.0,
                         "k_bkl": max(0.0, rb * max(t - 60, 0) + rng.normal(0, 0.015)),
                         "std_gm": 0.005, "std_fsj": 0.001, "std_bkl": 0.005})
    rows += [{**r, "actuator_id": f"Y{j}"} for j in range(4) for r in rows[14 * j:14 * j + 4]]
    h = tmp_path / "h.csv"
    with open(h, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    obj = prognose(h, thresholds=THR, next_check_h=100.0)["actuators"]
    checked = 0
    for j in range(4):
        a = obj[f"Y{j}"]
        faults = [a["faults"][f] for f in ("gm", "bkl")]
        assert any(f["fleet_prior"] for f in faults)
        o = a["overall"]
        assert o["fleet_prior"] is True                      # built from faults on the prior: said
        for f in faults:
            for q in ("rul_p05_h", "rul_median_h"):
                assert o[q] is not None and o[q] <= f[q], (j, q, o[q], f[q])
            assert o["p_fail_next"] >= f["p_fail_next"], (j, o["p_fail_next"], f["p_fail_next"])
            checked += 1
    assert checked == 8


def test_understated_errors_do_not_make_a_flat_fault_wear(tmp_path):
    # 40 actuators that do not wear, their diagnoses scattering 4x the stated error: judged by the
    # stated error alone, a low first test and a few high ones made an onset, and 8 of 40 were
    # given a RUL, 5 of them P(failure before the next check) >= 5 % (a false WARN). The tests
    # before the rise show the scatter; the onset is judged by it.
    rng = np.random.default_rng(5)
    rows = []
    for u in range(40):
        for i in range(20):
            rows.append({"actuator_id": f"F{u}", "time_h": 50.0 * i, "k_gm": max(0.0, 0.05 + rng.normal(0, 0.02)),
                         "k_fsj": 0.0, "k_bkl": 0.0, "std_gm": 0.005, "std_fsj": 0.005, "std_bkl": 0.005})
    h = tmp_path / "flat.csv"
    with open(h, "w", newline="") as f:
        w = csv.DictWriter(f, rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    gm = [a["faults"]["gm"] for a in prognose(h, thresholds=THR)["actuators"].values()]
    given = [g for g in gm if g["rul_p05_h"] is not None]
    assert len(given) <= 2, [g["onset_h"] for g in given]
    assert not any(g["p_fail_next"] >= 0.05 for g in given)
    assert sum("no degradation" in (g.get("reason") or "") for g in gm) >= 38


def test_an_actuator_on_the_fleet_prior_is_not_its_own_member(tmp_path):
    # Y has 4 points since onset: a member of the fleet prior at min_points 4 and a receiver
    # (below use_below_points 6). Its own life must not weigh its own samples twice: its
    # prior is the others', the same as when it is too young to be a member (min_points 5).
    h = tmp_path / "h.csv"
    rows = write_history(h, n_act=6, n_tests=14, seed=4)
    young = [{**r, "actuator_id": "Y"} for r in rows[:5]]          # 5 tests, 4 points since the anchor
    write_history(h, n_act=6, n_tests=14, seed=4, extra=young)
    got = {}
    for mp in (4, 5):
        s = load_settings(overrides={"fleet": {"min_points": mp}})
        obj, det = prognose(h, thresholds=THR, settings=s, details=True)
        y = obj["actuators"]["Y"]["faults"]["gm"]
        assert y["fleet_prior"] is True and y["n_points"] == 4
        got[mp] = (y["rul_p05_h"], y["rul_median_h"], y["rul_p95_h"], y["p_fail_next"])
    assert got[4] == got[5]


def test_overall_p_fail_is_exact_where_every_fault_fails_within_its_horizon():
    # the first-to-threshold distribution carries an atom at infinity only where some mass lies
    # beyond the horizon; with none, P(failure before a check past the horizon) is known (1 here),
    # not a lower bound
    from eha_health.prognostics.rul import FaultPrediction, overall, summary
    rng = np.random.default_rng(0)
    preds = {f: FaultPrediction(rng.lognormal(3.0, 0.3, 2000), None) for f in ("gm", "fsj", "bkl")}
    for p in preds.values():
        p.horizon_h = 40.0
    o = summary(overall(preds, 10), 100.0, None)
    assert o["p_fail_next"] == 1.0 and "p_fail_next_min" not in o
    preds["bkl"].samples[:200] = np.inf          # 10 % of bkl beyond its horizon: the others still fail first
    o = summary(overall(preds, 10), 100.0, None)
    assert o["p_fail_next"] == 1.0 and o["rul_p95_h"] is not None


def test_one_actuator_reads_as_in_the_whole_fleet(tmp_path):
    # prognose --actuator fits the fleet only when that actuator takes the fleet prior; either
    # way its answer is the one the whole-fleet run gives it
    h = tmp_path / "h.csv"
    rows = write_history(h, n_act=6, n_tests=14, seed=4)
    young = [{**r, "actuator_id": "Y"} for r in rows[:5]]
    write_history(h, n_act=6, n_tests=14, seed=4, extra=young)
    whole = prognose(h, thresholds=THR)["actuators"]
    assert whole["Y"]["faults"]["gm"]["fleet_prior"] is True and whole["A2"]["faults"]["gm"]["fleet_prior"] is False
    for a in ("Y", "A2"):
        assert prognose(h, a, thresholds=THR)["actuators"][a] == whole[a]


def test_the_fleet_prior_holds_what_its_members_do_not_know():
    # members' lives are estimates: a young fleet's are uncertain (and can all be biased the same
    # way). The prior matches the mixture of the members' lognormals, so their own spread widens it.
    from eha_health.prognostics.rul import fleet_prior
    lives = [1000.0, 1100.0, 900.0, 1050.0]
    sure = fleet_prior({f"u{i}": (v, 0.0) for i, v in enumerate(lives)}, 3)
    unsure = fleet_prior({f"u{i}": (v, 0.5) for i, v in enumerate(lives)}, 3)
    assert unsure.mu_log == pytest.approx(sure.mu_log)
    assert unsure.sd_log == pytest.approx(math.sqrt(sure.sd_log ** 2 + 0.25))
    assert sure.sd_log == pytest.approx(np.std(np.log(lives), ddof=1))
    assert fleet_prior({"a": (1000.0, 0.2), "b": (1200.0, 0.2), "c": (800.0, 0.2)}, 3).excluding("a") is None
    one = fleet_prior({"a": (1000.0, 0.2), "b": (float("nan"), 0.1), "c": (-5.0, 0.1)}, 1)
    assert one.members == 1 and one.sd_log == pytest.approx(0.2) and one.lives == (("a", 1000.0, 0.2),)


def test_the_fleet_prior_says_nothing_of_lives_shorter_than_its_members_had_to_last():
    """Members qualify with fleet.min_points points since onset: with tests 300 h apart, only units
    that lasted 900 h did, 35 of 40 waited, and the prior (lives 1400-1800 h) moved a young unit's
    short lives 2x late (an independent probe, 2026-12-07: 14 of 65 failed before their 5 %
    quantile). In the share of the wearing fleet still waiting to qualify, a life shorter than the
    members' entry age keeps the weight of the unit's own data, and the prior shares out the rest;
    with none waiting (every wearing unit a member) the prior weighs every life as before."""
    from eha_health.prognostics.degradation import Series
    from eha_health.prognostics.rul import FaultPrediction, apply_fleet_prior, fleet_prior
    s = load_settings()
    rng = np.random.default_rng(0)
    own = rng.lognormal(math.log(400.0), 0.5, 4000)         # RUL [h] from tau_now = 600 h
    members = {f"M{i}": (L, 0.05, 900.0) for i, L in enumerate((1400.0, 1500.0, 1600.0, 1800.0))}
    short = (600.0 + own < 900.0).mean()                     # the unit's own P(failing before 900 h)

    def applied(lives, actuator=None):
        p = FaultPrediction(own.copy(), None, n_points=3, series=Series(np.array([0.0, 300.0, 600.0]),
                                                                      np.zeros(3), np.ones(3), 600.0))
        apply_fleet_prior(p, fleet_prior(lives, 3), s, actuator)
        assert p.fleet_prior, p.reason
        return p
    nan3 = (math.nan,) * 3
    waiting = {f"W{i}": nan3 for i in range(4)}
    prior = fleet_prior({**members, **waiting, "Y": nan3}, 3)
    assert prior.entry_h == 900.0 and prior.members == 4 and prior.unseen == pytest.approx(5 / 9)
    assert prior.excluding("Y").unseen == pytest.approx(0.5)     # the unit itself is not the fleet
    half = applied({**members, **waiting, "Y": nan3}, "Y")
    assert half.p_fail(300.0) == pytest.approx(0.5 * short, rel=0.02)
    assert half.quantiles()[1] > 1.5 * np.median(own)           # beyond 900 h the prior weighs still
    # 36 of 40 waiting: nearly the unit's own share of short lives
    most = applied({**members, **{f"W{i}": nan3 for i in range(36)}})
    assert most.p_fail(300.0) == pytest.approx(0.9 * short, rel=0.02)
    # every wearing unit a member: the prior weighs the short lives too (none are left)
    assert applied(members).p_fail(300.0) < 0.01 * short


def test_a_rise_no_single_test_shows_is_seen_by_the_tests_together(tmp_path):
    # errors of 0.03: flat at 0.03 for 6 tests, then 5 tests up 0.09-0.11. No test clears the
    # first by 3 sd (0.127), so the per-test rule finds no onset; the 5 together are a rise of
    # some 7 sd. Before: "no degradation" and no RUL.
    rng = np.random.default_rng(2)
    t = 60.0 * np.arange(11)
    k = np.r_[0.03 + rng.normal(0, 0.01, 6), 0.03 + np.linspace(0.07, 0.11, 5)]
    assert degradation_segment(t, k, np.full(11, 0.03), 3.0, 0.01) is None
    j = rise_onset(t, k, np.full(11, 0.03), 16.0)
    assert j is not None and 2 <= j <= 5        # a ramp fitted to the rise starts a little before it
    h = one_actuator_csv(tmp_path, (["A", ti, ki, 0.0, 0.0, 0.03, 0.001, 0.001] for ti, ki in zip(t, k)))
    gm = prognose(h, thresholds=THR)["actuators"]["A"]["faults"]["gm"]
    assert gm["rul_p05_h"] is not None and gm["rul_p05_h"] > 0, gm
    assert gm["onset_h"] <= 300 and max(map(float, gm["onset_posterior"])) <= 300   # the rise begins after 300 h
    off = load_settings(overrides={"prognosis": {"onset_chi2": 0.0}})
    gm0 = prognose(h, thresholds=THR, settings=off)["actuators"]["A"]["faults"]["gm"]
    assert gm0["rul_median_h"] is None and "no degradation" in gm0["reason"]
    with pytest.raises(PrognosticsError, match="onset_chi2"):
        load_settings(overrides={"prognosis": {"onset_chi2": -1.0}})


def test_the_pooled_rise_rule_makes_no_onset_on_flat_data_of_right_errors():
    # the pooled rule's false alarms: flat histories of 4-40 tests with the errors stated right,
    # 3000 of them; at the default chi^2 gain of 16 none clears it (docs; 2 allowed)
    rng = np.random.default_rng(8)
    s = load_settings()
    hits = 0
    for n in rng.integers(4, 41, 3000):
        t = np.cumsum(rng.uniform(20.0, 80.0, n))
        sd = rng.uniform(0.002, 0.03)
        k = 0.05 + rng.normal(0.0, sd, n)
        hits += rise_onset(t, k, np.full(n, sd), s.prognosis.onset_chi2) is not None
    assert hits <= 2
    # one test within the history, however high, is no pooled rise (a failed diagnosis): the
    # gain is the smallest with any one test before the last left out
    for i in range(1, 7):
        assert rise_onset(np.arange(8.0), np.where(np.arange(8) == i, 1.0, 0.0), np.full(8, 0.01), 16.0) is None
    assert rise_onset(np.arange(8.0), np.r_[np.zeros(5), 0.05, 0.06, 0.07], np.full(8, 0.01), 16.0) in (3, 4)


def test_the_fleet_prior_reaches_beyond_a_young_units_horizon(tmp_path):
    # six members wear K_FSJ linearly over ~1000 h; Y wears at the same rate and has 5 tests over
    # 20 h. Its own data reach 20 spans (400 h): cut there, the prior had only the samples before
    # it -- the RUL ended at 400 h against a truth near 960 h, or the prior was refused as
    # "conflicting" (found by an independent probe).
    rng = np.random.default_rng(0)
    rows = []
    for m in range(6):
        life = 1000 * np.exp(rng.normal(0, 0.15))
        rows += [["M%d" % m, t, 0.02, 0.02 + 0.915 * t / life + 0.005 * rng.standard_normal(), 0.02, 0.005, 0.005, 0.005]
                 for t in np.arange(0, 601, 50.0)]
    rows += [["Y", t, 0.02, 0.02 + 0.915 * t / 1000 + 0.0005 * rng.standard_normal(), 0.02, 0.0005, 0.0005, 0.0005]
             for t in np.linspace(0, 20, 5)]
    h = one_actuator_csv(tmp_path, rows)
    thr = {"gm": 0.8, "fsj": 0.915, "bkl": 0.85}
    y = prognose(h, "Y", thresholds=thr)["actuators"]["Y"]
    f = y["faults"]["fsj"]
    assert f["fleet_prior"] is True and f["n_points"] < 6
    assert f["rul_p05_h"] <= 958 <= f["rul_p95_h"] and 800 < f["rul_median_h"] < 1100, f
    assert f["p_fail_next"] == 0.0 and "p_fail_next_min" not in f      # the horizon reaches the prior's lives
    assert y["overall"]["rul_median_h"] == f["rul_median_h"]


def test_a_straight_rise_just_begun_is_found_where_it_began(tmp_path):
    # K_FSJ flat at 0.02 (errors 0.005) for 14 tests every 10 h, then a straight rise of
    # 0.0011 /h from 135 h; the history ends at 210 h. The onset anchor is the first test above
    # the noise (140 h); the even grid's candidates were 0, 50, 90 and 140 h, and from 90 h a
    # convex shape took the kink: median 218 h against a true 712 h, P(failure in 50 h) 0.2
    # (an ERROR) -- an independent probe's unit. The test before the anchor is a candidate now.
    rng = np.random.default_rng(3)
    t = 10.0 * np.arange(22)
    k = 0.02 + 0.0011 * np.maximum(t - 135.0, 0.0) + rng.normal(0.0, 0.005, len(t))
    h = one_actuator_csv(tmp_path, (["Y", ti, 0.02, ki, 0.02, 0.005, 0.005, 0.005] for ti, ki in zip(t, k)))
    thr = {"gm": 0.8, "fsj": 0.915, "bkl": 0.85}
    f = prognose(h, thresholds=thr)["actuators"]["Y"]["faults"]["fsj"]
    true_rul = (0.915 - 0.02) / 0.0011 + 135.0 - 210.0
    post = {float(a): w for a, w in f["onset_posterior"].items()}
    assert sum(w for a, w in post.items() if a >= 120.0) > 0.5, post
    assert 0.6 * true_rul <= f["rul_median_h"] <= 1.3 * true_rul, (f["rul_median_h"], true_rul)
    assert f["p_fail_next"] < 0.2


def test_a_rise_only_the_last_test_shows_must_clear_the_outlier_level():
    # one test 3 sd up is about 1 flat series in 700 at every look: read as wear, it gave RULs of
    # hours (an independent probe: 16 tests at 0.02 +- 0.005, a low first test, the last 0.0306:
    # p05 3 h, P(failure in 50 h) 0.32 -- an ERROR on a fault at 4 % of its threshold)
    k = np.array([0.00718, 0.02537, 0.02364, 0.01622, 0.01306, 0.0130, 0.02367, 0.01987, 0.02034, 0.01897,
                  0.01848, 0.01911, 0.01507, 0.01293, 0.01236, 0.03058])
    t, sd = 10.0 * np.arange(16), np.full(16, 0.005)
    assert degradation_segment(t, k, sd, 3.0, 0.01) == 14                     # the last test alone
    assert degradation_segment(t, k, sd, 3.0, 0.01, sigma_last=5.0) is None
    gm = prognose(_history_of("FLAT", t, k, sd), thresholds=THR)["actuators"]["FLAT"]["faults"]["gm"]
    assert gm["rul_median_h"] is None and "no degradation" in gm["reason"]
    # flat series of right errors: onsets shown by the last test alone are gone, and a jump that
    # clears 5 sd is still wear at once (test_a_rise_that_shows_at_one_test_...)
    rng = np.random.default_rng(4)
    hits = {None: 0, 5.0: 0}
    for n in rng.integers(5, 41, 3000):
        y = 0.05 + rng.normal(0.0, 0.005, n)
        for last in hits:
            hits[last] += degradation_segment(np.arange(n) * 50.0, y, np.full(n, 0.005), 3.0, 0.01, last) is not None
    assert hits[None] >= 2 and hits[5.0] <= 1, hits


def _history_of(actuator, t, k, sd):
    from eha_health.prognostics.records import history_from_records
    return history_from_records([HealthRecord(actuator, float(ti), (float(ki), 0.0, 0.0), (float(si), 0.001, 0.001))
                                  for ti, ki, si in zip(t, k, sd)], [], 0.002)


def test_linear_wear_with_a_wide_rate_walk_has_a_finite_p95():
    """Twelve tests of linear gm wear (0.0008 K/h from 100 h, error 0.003): the Wiener model's
    rate walk is as wide as the rate over its span. A walk free to turn the rate negative turned a
    fifth of its paths down for good, and the p95 read "beyond the horizon" for wear that plainly
    goes on; reflected at 0 (a wear rate does not turn negative: rul.rate_walk_passage), the
    interval is finite and holds the line's own crossing."""
    rng = np.random.default_rng(0)
    t = 40.0 * np.arange(12)
    k = np.maximum(8e-4 * np.maximum(t - 100.0, 0.0) + rng.normal(0, 0.003, t.size), 0.0)
    gm = prognose(_history_of("A", t, k, np.full(t.size, 0.003)), next_check_h=100.0)["actuators"]["A"]["faults"]["gm"]
    assert gm["model"] is not None and gm["rul_p95_h"] is not None, gm
    true = (gm["threshold"] - 8e-4 * (t[-1] - 100.0)) / 8e-4
    assert gm["rul_p05_h"] < true < gm["rul_p95_h"], (gm, true)


def test_young_wear_raises_no_false_warn():
    """Twenty units whose K_FSJ starts a gamma wear (mean 0.915 K in 700 h, Var = 0.002 mean) at
    250 h, tested every 10 h (error 0.005) until 60-150 h after: P(failure within 50 h) stays
    below the 5 % WARN level for at least 19 of them (their mean paths are 550 h or more from the
    threshold). The rate walk folded into a diffusion at the mean passage put mass on passages
    within hours: 7 of these 20 read P >= 5 % (tools/prognose_processes.py young: 11 of 40)."""
    warns = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        start, rate = 250.0, 0.915 / 700.0
        t = 10.0 * np.arange(int((start + rng.uniform(60, 150)) / 10) + 1)
        inc = np.where(t[1:] > start, rng.gamma(rate * 10 / 0.002, 0.002, t.size - 1), 0.0)
        k = np.maximum(np.concatenate([[0.0], np.cumsum(inc)]) + rng.normal(0, 0.005, t.size), 0.0)
        recs = [HealthRecord("Y", float(a), (0.02, float(b), 0.02), (0.005,) * 3) for a, b in zip(t, k)]
        from eha_health.prognostics.records import history_from_records
        fsj = prognose(history_from_records(recs, [], 0.002), next_check_h=50.0)["actuators"]["Y"]["faults"]["fsj"]
        assert fsj["rul_median_h"] is not None and fsj["rul_median_h"] > 150.0, (seed, fsj)
        warns.append(fsj["p_fail_next"] >= 0.05)
    assert sum(warns) <= 1, warns


def test_the_pooled_rise_is_the_same_in_blocks(monkeypatch):
    """rise_onset fits every onset candidate in blocks of rows (memory); one block gives the same."""
    from eha_health.prognostics import degradation
    rng = np.random.default_rng(4)
    for n, at in ((700, 400), (600, 590), (300, 30)):
        t = np.sort(rng.uniform(0, 5000, n))
        k = np.where(np.arange(n) > at, 1e-5 * (t - t[at]), 0.0) + rng.normal(0, 0.01, n)
        std = np.full(n, 0.01)
        blocks = [rise_onset(t, k, std, c) for c in (0.0, 16.0, 1e9)]
        monkeypatch.setattr(degradation, "_ROWS", 10 ** 6)
        assert [rise_onset(t, k, std, c) for c in (0.0, 16.0, 1e9)] == blocks
        monkeypatch.setattr(degradation, "_ROWS", 256)
        assert blocks[2] is None and blocks[0] is not None


LONG = """
import resource, sys
import numpy as np
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
from eha_health.prognostics.records import HealthRecord, history_from_records
from eha_health.prognostics.rul import prognose
n = 6000
rng = np.random.default_rng(1)
t = np.arange(n) * 2.4
k = np.clip(np.where(t > 0.5 * t[-1], 0.5 * (t - 0.5 * t[-1]) / t[-1], 0) + rng.normal(0, 0.01, (3, n)), 0, 1.5).T
recs = [HealthRecord("A", float(ti), tuple(ki), (0.01,) * 3) for ti, ki in zip(t, k)]
out = prognose(history_from_records(recs, [], 0.002), next_check_h=24.0)
gm = out["actuators"]["A"]["faults"]["gm"]
print(gm["rul_median_h"], gm["threshold"], t[-1])
"""


def test_a_history_of_thousands_of_tests_fits_in_bounded_memory():
    """Ten checks a day for 20 months, no repair: 6000 tests. The pooled rise's [J, n] sums took
    about 3 GB at this length (5.6 GB at 8000); in blocks the whole prognosis runs under a 2 GB
    address-space limit."""
    import subprocess
    import sys
    p = subprocess.run([sys.executable, "-c", LONG], capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    median, thr, end = map(float, p.stdout.split())
    true_rul = end / 2 + thr * 2 * end - end            # K = 0.5 (t - T/2) / T from half-way on
    assert median == pytest.approx(true_rul, rel=0.1)


def test_the_hyperbolic_path_model_can_be_chosen_and_plotted_past_its_blow_up(tmp_path):
    """`hyperbolic` in models.names (not in the default set: section 3) on Paris-law wear: it is
    weighed with the others, its RUL ends before its blow-up, and the plot's trend, infinite past the
    blow-up, is drawn up to it (the trend band is NaN beyond, not inf)."""
    from eha_health.prognostics.rul import trend_band
    h = tmp_path / "h.csv"
    _one_actuator(h, lambda t: 0.02 + 0.05 * (1 / (1 - t / 1000.0) - 1), 0.004, 0)    # blows up at 1000 h
    s = load_settings(overrides={"models": {"names": ["linear", "exponential", "power", "hyperbolic", "wiener"]}})
    obj, det = prognose(h, thresholds=THR, settings=s, details=True)
    d, f = det["A"]["gm"], obj["actuators"]["A"]["faults"]["gm"]
    assert d.model_weights["hyperbolic"] > 0.05, d.model_weights
    assert 0 < f["rul_median_h"] < 1000.0 - 750.0
    tau = np.linspace(0.0, 3000.0, 301)
    mean, lo, hi = trend_band(d, tau)
    assert np.all(np.isfinite(mean[:40])) and not np.any(np.isinf(mean)) and not np.any(np.isinf(hi))
    assert f["model"] == "hyperbolic" and np.isnan(mean[-1])       # the trend drawn is the blow-up's
    png = tmp_path / "p.png"
    plot_prognosis(h, png, "A", settings=s)
    assert png.stat().st_size > 10_000


def test_prognose_on_threads_equals_the_serial_result(tmp_path, monkeypatch):
    """The faults' predictions run on threads in parts of the fleet (rul._predict_faults): the
    same object and the same samples and weights, to the last bit, as one thread gives."""
    import os
    from eha_health.bench.rul import synthetic_history_csv
    from eha_health.prognostics import rul
    path = synthetic_history_csv(tmp_path / "h.csv", 2 * rul.PARALLEL_MIN + 3, n_tests=12, seed=5)
    out = {}
    for cpus in (1, 2):
        monkeypatch.setattr(os, "cpu_count", lambda: cpus)
        out[cpus] = prognose(path, details=True)
    assert json.dumps(out[1][0], sort_keys=True) == json.dumps(out[2][0], sort_keys=True)
    for a, d in out[1][1].items():
        for f, p in d.items():
            if f == "history":
                continue
            q = out[2][1][a][f]
            for x, y in ((p.samples, q.samples), (p.weights, q.weights)):
                assert (x is None and y is None) or np.array_equal(x, y, equal_nan=True), (a, f)


def test_a_pick_at_some_entries_is_the_pick_of_all():
    """rul._pick_at (a model's samples search their cells only) against rul._pick of every
    entry: ties, weights of zero, a last cumulative weight forced to 1, and NaN (the fallback)."""
    from eha_health.prognostics.rul import _pick, _pick_at
    rng = np.random.default_rng(0)
    for trial in range(300):
        s, k, m = int(rng.integers(1, 9)), int(rng.integers(1, 50)), int(rng.integers(1, 200))
        w = rng.choice([0.0, 0.5, 1.0, rng.random()], (s, k)) if trial % 2 else rng.random((s, k))
        cum = np.cumsum(w / np.maximum(w.sum(1, keepdims=True), 1e-300), 1)
        cum[:, -1] = 1.0
        if trial % 7 == 0:
            cum[rng.integers(s), rng.integers(k)] = np.nan
        u = rng.random(m) if trial % 3 else rng.choice(cum.ravel()[np.isfinite(cum.ravel())], m)
        rows, cols = np.nonzero(rng.random((s, m)) < 0.3)
        assert np.array_equal(_pick_at(cum, u, rows, cols), _pick(cum, u)[rows, cols])
