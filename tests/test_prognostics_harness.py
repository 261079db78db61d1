"""Validation harness: the simulated fleet, cached real diagnoses, and one tiny end-to-end bench."""
import json
import math

import numpy as np
import pytest

from eha_health.prognostics.config import load_settings
from eha_health.bench.rul import (FINE_DT_H, MARK_BEGIN, MARK_END, bench_rul, diagnose_test, format_result, law_cells,
                                  make_fleet, reference_rul, write_markdown)

THR = {"gm": 0.8, "fsj": 0.9, "bkl": 0.85}


def test_fleet_is_seeded_and_its_eol_is_the_first_crossing():
    b = load_settings(overrides={"bench": {"n_units": 8}}).bench
    f1, f2 = make_fleet(b, THR), make_fleet(b, THR)
    for u, v in zip(f1, f2):
        np.testing.assert_array_equal(u.test_h, v.test_h)
        np.testing.assert_array_equal(u.true_k, v.true_k)
    # unit i does not depend on the fleet size
    small = make_fleet(load_settings(overrides={"bench": {"n_units": 3}}).bench, THR)
    np.testing.assert_array_equal(small[2].true_k, f1[2].true_k)
    other = make_fleet(load_settings(overrides={"bench": {"n_units": 8, "seed": 7}}).bench, THR)
    assert not np.array_equal(other[0].true_k, f1[0].true_k)
    laws = set()
    for u in f1:
        assert u.test_h[-1] < u.eol_h and np.all(np.diff(u.test_h) > 0)
        for p in u.paths:
            laws.add(p.law)
            assert np.all(np.diff(p.k) >= 0)                       # wear is monotone
            assert np.all(p.k[p.t_h < p.onset_h - FINE_DT_H] == 0)  # healthy before onset
        first = min(p.t_h[np.argmax(p.k >= THR[p.fault])] for p in u.paths if np.any(p.k >= THR[p.fault]))
        assert abs(first - u.eol_h) <= FINE_DT_H
        assert np.all(u.true_k < 1.5)
    assert laws == {"linear", "exponential", "power", "two_phase"}


def test_gamma_process_mean_follows_the_law():
    b = load_settings(overrides={"bench": {"n_units": 30, "second_fault_probability": 0.0}}).bench
    fleet = make_fleet(b, THR)
    # at the mean-path life L the process is at its threshold on average (Var = nu thr)
    ratios = []
    for u in fleet:
        p = u.paths[0]
        ratios.append(np.interp(p.onset_h + p.life_h, p.t_h, p.k) / THR[p.fault])
    se = np.sqrt(b.volatility[1] / 0.8) / np.sqrt(len(ratios))
    assert abs(np.mean(ratios) - 1.0) < 4 * se


def test_reference_predictor_learns_a_known_law_and_follows_the_unit_level():
    """The bench's reference predictor, told the law, finds a low-volatility unit's RUL from half its
    history; it continues from the level the unit is at, so the same history ending higher gives a
    shorter RUL; told every law of the fleet it still finds a linear unit."""
    b = load_settings(overrides={"bench": {"n_units": 1, "volatility": [1e-5, 1e-5],
                                           "second_fault_probability": 0.0}}).bench
    u = make_fleet(b, THR)[0]                      # unit 0: linear
    p = u.paths[0]
    u.diag_k, u.diag_std = u.true_k.copy(), np.full(u.true_k.shape, 0.002)
    k = int(np.searchsorted(u.test_h, p.onset_h + 0.5 * p.life_h))
    true_rul = u.eol_h - u.test_h[k]
    known = reference_rul(u, k, THR, [(p.law, p.shape, p.knee)], [p.volatility], b.life_median_h)
    assert abs(known / true_rul - 1) < 0.05
    every = [c for law in b.laws for c in law_cells(law)]
    assert abs(reference_rul(u, k, THR, every, [1e-5, 1e-3], b.life_median_h) / true_rul - 1) < 0.2
    fi = ["gm", "fsj", "bkl"].index(p.fault)
    u.diag_k[k, fi] += 0.05                        # the last test higher: less of the way left
    higher = reference_rul(u, k, THR, [(p.law, p.shape, p.knee)], [p.volatility], b.life_median_h)
    slope = THR[p.fault] / p.life_h
    assert higher < known - 0.5 * 0.05 / slope


def test_diagnoses_are_real_and_cached(tmp_path):
    k = np.array([0.3, 0.0, 0.2])
    d1 = diagnose_test(k, 123, "deterministic", tmp_path)
    assert d1["cached"] is False
    assert np.allclose(d1["k"], k, atol=0.02) and all(s > 0 for s in d1["std"])
    files = list(tmp_path.rglob("*.json"))
    assert len(files) == 1 and json.loads(files[0].read_text())["inputs"]["noise_seed"] == 123
    d2 = diagnose_test(k, 123, "deterministic", tmp_path)
    assert d2["cached"] is True and d2["k"] == d1["k"]
    d3 = diagnose_test(k, 124, "deterministic", tmp_path)      # another noise seed: a new diagnosis
    assert d3["cached"] is False and d3["k"] != d1["k"]


def test_bench_end_to_end_tiny(tmp_path):
    """One short-lived unit, every test diagnosed for real, scored, plotted; a rerun is all cached."""
    s = load_settings(overrides={"bench": {"n_units": 1, "life_median_h": 330.0, "life_spread": 0.0,
                                           "healthy_fraction": [0.05, 0.06], "second_fault_probability": 0.0,
                                           "test_interval_h": 40.0}})
    lines = []
    r = bench_rul(s, cache_dir=tmp_path / "cache", plot=tmp_path / "b.png", progress=lines.append)
    assert r["points"] >= 3 and r["diagnoses"]["cached"] == 0
    assert any(line.startswith("diagnosis 1/") for line in lines)
    assert [line.split(",")[0] for line in lines if line.startswith("predictions:")] == [
        "predictions: fault gm (1/3)", "predictions: fault fsj (2/3)", "predictions: fault bkl (3/3)"]
    assert lines[-1].startswith("reference predictors")      # the figures are the caller's to print
    assert (tmp_path / "b.png").read_bytes()[:4] == b"\x89PNG"
    m = r["model"]
    assert 0.0 <= m["coverage90"] <= 1.0 and set(r["targets"]) and "ratios_model_to_naive" in r
    f = m["p_fail_next"]                     # the unit's last test is within a check of its end
    assert f["points"] == r["points"] and f["events"] >= 1 and sum(c["n"] for c in f["reliability"]) == f["points"]
    r2 = bench_rul(s, cache_dir=tmp_path / "cache", plot=None, progress=None)
    assert r2["diagnoses"]["cached"] == r2["diagnoses"]["diagnoses"]
    assert r2["model"] == r["model"] and r2["naive"] == r["naive"]
    assert set(r["oracle"]) == {"alpha_lambda", "law_and_shape_known", "law_known", "fleet_laws_known",
                                "generic_shapes"}
    # the figures go between the markers of a document, the rest of it kept
    doc = tmp_path / "doc.md"
    doc.write_text(f"# title\n{MARK_BEGIN}\nold figures\n{MARK_END}\ntail\n")
    write_markdown(r, doc, "eha-health bench rul --units 1")
    text = doc.read_text()
    assert text.startswith("# title\n") and text.endswith(f"{MARK_END}\ntail\n") and "old figures" not in text
    assert "`eha-health bench rul --units 1`" in text and format_result(r) in text


def test_p_fail_next_is_scored_as_a_warning():
    """Brier score and skill, reliability and the WARN / ERROR counts of p_fail_next, by their
    definitions (Brier 1950): the event is a failure before the next check."""
    from eha_health.bench.rul import UnitScore, failure_warning
    from eha_health.prognostics.metrics import brier, reliability
    assert brier([0.0, 1.0, 0.0], [0, 1, 0]) == (0.0, 1.0)                  # certain and right
    assert brier([1 / 3] * 3, [0, 1, 0])[1] == pytest.approx(0.0)           # the climatology: no skill
    assert brier([0.5, 0.5], [1, 1])[1] != brier([0.5, 0.5], [1, 1])[1]     # one outcome only: NaN
    cells = reliability(np.array([0.01, 0.02, 0.1, 0.9, 1.0]), np.array([0, 0, 1, 1, 0]))
    assert [c["n"] for c in cells] == [2, 1, 0, 2] and cells[3]["observed"] == 0.5
    assert cells[0]["mean_p"] == pytest.approx(0.015) and cells[2]["mean_p"] is None

    r_true = np.array([500.0, 300.0, 100.0, 40.0])       # checks every 60 h: the last point fails
    sc = UnitScore("U", 1000.0, np.arange(4.0), r_true, r_true, r_true, r_true, np.full(4, 0.5), r_true,
                   np.zeros(4, bool), np.ones(4, bool), np.array([0.0, 0.1, 0.3, 0.9]))
    f = failure_warning([sc], 60.0, 0.05, 0.2)
    assert (f["events"], f["points"]) == (1, 4)
    assert f["warn"] == {"p": 0.05, "events_raised": 1, "false": 1, "far_points": 2}   # 300 h away: false
    assert f["error"] == {"p": 0.2, "events_raised": 1, "false": 0, "far_points": 2}   # 100 h: not 2 checks
    assert f["brier"] == pytest.approx((0.01 + 0.09 + 0.01) / 4)


def test_bench_figures_carry_their_sampling_intervals():
    """24 units make a share uncertain by +-20 %: alpha-lambda gets a Wilson interval, the coverage
    one from resampling whole units (a unit's predictions are not independent points)."""
    from eha_health.bench.rul import UnitScore, _unit_bootstrap_ci, _wilson
    lo, hi = _wilson(13, 24)
    z, p, n = 1.959964, 13 / 24, 24        # Wilson (1927) by its formula
    c, h = (p + z * z / (2 * n)) / (1 + z * z / n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    assert (lo, hi) == pytest.approx((c - h, c + h), abs=1e-6)

    def unit(i, covered):
        r = np.full(20, 100.0)
        return UnitScore(f"U{i}", 1000.0, np.arange(20.0), r, r * (0.5 if covered else 2.0), r, r * 3.0,
                         np.full(20, 0.5), r, np.zeros(20, bool), np.ones(20, bool))
    units = [unit(i, i % 2 == 0) for i in range(24)]      # half the units covered at every point
    ci = _unit_bootstrap_ci(units)
    assert ci[0] < 0.5 < ci[1] and ci[1] - ci[0] > 0.3    # 480 independent points would give +-0.045
    assert _unit_bootstrap_ci(units) == ci                 # seeded
