"""Wear by random shocks (a compound Poisson process): heavy-tailed increments widen the Wiener
model's cell posterior (degradation.increment_temper; tools/prognose_processes.py shocks)."""
import csv

import numpy as np

from eha_health.prognostics.degradation import increment_temper
from eha_health.prognostics.rul import prognose


def _prognose_fsj(path, t, k):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl"])
        for ti, ki in zip(t, k):
            w.writerow(["A", ti, 0.02, ki, 0.02, 0.005, 0.005, 0.005])
    return prognose(path)["actuators"]["A"]["faults"]["fsj"]


def test_an_early_shock_does_not_make_the_rul_sure(tmp_path):
    # a slow drift and two shocks (0.12 after 75 h, 0.03 after 420 h): the steps between them are
    # the drift alone. The Gaussian posterior read the early jump as a decelerating time scale and
    # the steps as a small sigma: p05 3745 h, twice the RUL at the mean wear rate so far (~1950 h),
    # where the next shock may well come sooner (the shocks probe: 10 % of the failures before
    # p05). Tempered (alpha 0.26): p05 1304 h
    rng = np.random.default_rng(3)
    t = np.arange(14) * 50.0
    k = np.clip(0.00012 * t + np.where(t >= 75, 0.12, 0) + np.where(t >= 420, 0.03, 0)
                + rng.normal(0, 0.003, len(t)), 0, None)
    F = _prognose_fsj(tmp_path / "h.csv", t, k)
    at_mean_rate = (F["threshold"] - k[-1]) / (k[-1] / t[-1])
    assert F["rul_p05_h"] is not None and F["rul_p05_h"] < at_mean_rate, (F, at_mean_rate)


def test_gaussian_increments_keep_the_whole_likelihood():
    t = np.arange(16) * 50.0
    alpha = []
    for seed in range(200):
        r = np.random.default_rng(seed)
        y = np.cumsum(np.r_[0.0, 0.02 + 0.01 * r.standard_normal(15)]) + r.normal(0, 0.003, 16)
        alpha.append(increment_temper(t[None] / t[-1], y[None], np.ones((1, 16), bool))[0])
    assert np.median(alpha) == 1.0 and np.mean(alpha) > 0.9
    # one jump among steady steps: tempered; fewer than 4 increments: never
    y = 0.01 * np.arange(12.0) + np.where(np.arange(12) >= 3, 0.2, 0.0)
    assert increment_temper(np.arange(12.0)[None], y[None], np.ones((1, 12), bool))[0] < 0.5
    assert increment_temper(np.arange(4.0)[None], y[None, :4], np.ones((1, 4), bool))[0] == 1.0
