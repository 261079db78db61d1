"""Degradation models: the hand-written filter against filterpy and against direct least squares,
the inverse-Gaussian sampler against scipy, the online tracker against the batch fit, and
calibration of the RUL intervals on simulated degradation with known truth."""
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from eha_health.prognostics.config import load_settings
from eha_health.prognostics.degradation import (NX, Grid, Series, fit_model, grid_g, kf_init, kf_step, log_ml,
                                                model_grids, shape_g, shape_g_inv, state_cov, summarise)
from eha_health.prognostics.online import OnlineFault
from eha_health.prognostics.rul import (FaultPrediction, inverse_gaussian, predict_series, rate_walk_passage,
                                        weighted_quantiles)


def one_cell(kind=0, b=1.0, eta=0.0, sigma=0.0, rate=0.0):
    return Grid("t", np.array([kind]), np.array([b]), np.array([eta]), np.array([sigma]), np.array([rate]), 3,
                np.zeros(1))


def test_filter_matches_filterpy_step_by_step():
    from filterpy.kalman import KalmanFilter
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 1, 9))
    t[0] = 0.0
    g = t ** 1.5
    y = 0.05 + 0.4 * g + rng.normal(0, 0.01, len(t))
    r = rng.uniform(0.5e-4, 2e-4, len(t))
    sigma2, q = 0.02 ** 2, 0.1 ** 2
    st = kf_init(np.array([y[0]]), np.array([r[0]]), (1,))
    kf = KalmanFilter(dim_x=NX, dim_z=1)
    kf.x = np.array([y[0], 0.0, 0.0, 0.0])
    kf.P = np.diag([r[0], 1e4, 0.0, 0.0])
    for k in range(1, len(t)):
        dg = g[k] - g[k - 1]
        kf.F = np.eye(NX)
        kf.F[2, 3] = dg
        kf.Q = np.diag([0.0, 0.0, sigma2 * dg, q * dg])
        kf.H = np.array([[1.0, g[k], 1.0, 0.0]])
        kf.R = np.array([[r[k]]])
        kf.predict()
        kf.update(np.array([y[k]]))
        kf_step(st, np.array([g[k - 1]]), np.array([g[k]]), np.array([y[k]]), np.array([r[k]]), sigma2, q)
        np.testing.assert_allclose(st[:NX, 0], kf.x, rtol=1e-7, atol=1e-10)
        np.testing.assert_allclose(state_cov(st[:, 0]), kf.P, rtol=1e-6, atol=1e-12)


def test_profile_likelihood_equals_weighted_least_squares():
    """log L_ML of a path model (sigma = 0) is the Gaussian log-likelihood at the WLS estimate."""
    rng = np.random.default_rng(1)
    n = 12
    t = np.linspace(0, 1, n)
    s = rng.uniform(0.005, 0.02, n)
    for kind, b in ((0, 1.0), (1, 2.0), (2, 1.7)):
        g = shape_g(kind, t, b)
        y = 0.02 + 0.5 * g + rng.normal(0, s)
        X = np.stack([np.ones(n), g], 1)
        W = 1 / s ** 2
        beta = np.linalg.solve(X.T @ (W[:, None] * X), X.T @ (W * y))
        res = y - X @ beta
        ll = -0.5 * np.sum(np.log(2 * math.pi * s ** 2) + res ** 2 / s ** 2)
        grid = one_cell(kind, b)
        st = kf_init(np.array([y[0]]), np.array([s[0] ** 2]), (1, 1))
        for k in range(1, n):
            kf_step(st, np.array([[g[k - 1]]]), np.array([[g[k]]]), np.array([[y[k]]]), np.array([[s[k] ** 2]]),
                    0.0, 0.0)
        assert log_ml(st)[0, 0] == pytest.approx(ll, abs=1e-4)
        np.testing.assert_allclose(st[:2, 0, 0], beta, rtol=1e-5, atol=1e-8)
        fit = fit_model([Series(t, y, s, 1.0)], grid)
        assert fit.max_log_ml[0] == pytest.approx(ll, abs=1e-4)


def test_shape_inverse():
    t = np.linspace(0, 3, 31)
    for kind, b in ((0, 1.0), (1, 0.05), (1, 6.0), (2, 0.5), (2, 3.0), (3, 1.1), (3, 7.0)):
        tt = t[t < b] if kind == 3 else t
        np.testing.assert_allclose(shape_g_inv(kind, shape_g(kind, tt, b), b), tt, atol=1e-9)
        assert shape_g(kind, 1.0, b) == pytest.approx(1.0)


def test_hyperbolic_shape_blows_up_at_c():
    """g = t (c - 1) / (c - t): the Paris-law crack length a0 / (1 - t / c) less a0, normalised;
    its log-growth rate g'' / g' = 2 / (c - t) rises without bound, and it is infinite from t = c
    on, which the inverse maps back to c (every path crosses any threshold before the blow-up)."""
    c = 1.5
    t = np.array([0.0, 0.5, 1.0, 1.4, 1.499, 1.5, 2.0])
    g = shape_g(3, t, c)
    a = 1.0 / (1.0 - t[:5] / c) - 1.0
    np.testing.assert_allclose(g[:5], a / a[2], rtol=1e-12)
    assert np.all(np.isinf(g[5:]))
    np.testing.assert_allclose(shape_g_inv(3, np.array([1e12, np.inf]), c), [c, c], rtol=1e-9)


def test_inverse_gaussian_sampler_matches_scipy():
    m = 50000
    for seed, (mean, shape) in enumerate(((1.0, 0.5), (2.0, 50.0), (0.3, 3.0))):
        rng = np.random.default_rng(seed)
        x = inverse_gaussian(np.full(m, mean), np.full(m, shape), rng.standard_normal(m), rng.random(m))
        ks = stats.kstest(x, stats.invgauss(mean / shape, scale=shape).cdf)
        assert ks.pvalue > 1e-3, (mean, shape, ks)


def test_rate_walk_passage_is_the_first_crossing_of_the_reflected_path():
    """The smooth path L(dg) = rate dg + c dg^(3/2), c = z sqrt(q / 3), while its rate is positive;
    after its rate reaches 0 at dg*, the peak plus the reflected walk's mean growth (2/3) sqrt(2 /
    pi) sqrt(q) (dg - dg*)^(3/2): rate_walk_passage is its first crossing of d, checked on a fine
    grid of 10000 random cases. Every case with rate > 0 crosses."""
    from eha_health.prognostics.rul import REFLECTED_GROWTH
    rng = np.random.default_rng(0)
    n = 10000
    d, rate, z, rq = rng.uniform(0.1, 1, n), rng.uniform(0.01, 1, n), rng.standard_normal(n), rng.uniform(0, 0.9, n)
    dg = rate_walk_passage(d, rate, z, rq)
    assert np.isfinite(dg).all() and (dg > 0).all()
    c = z * rq / math.sqrt(3)

    def level(s):
        L = rate[:, None] * s + c[:, None] * s ** 1.5
        star = np.where(c < 0, (2 * rate / (3 * c)) ** 2, np.inf)[:, None]
        peak = np.where(np.isfinite(star), rate[:, None] * star + c[:, None] * star ** 1.5, 0.0)
        grown = peak + REFLECTED_GROWTH * rq[:, None] * np.maximum(s - star, 0.0) ** 1.5
        return np.where(s <= star, L, grown)

    np.testing.assert_allclose(level(dg[:, None])[:, 0], d, atol=1e-8)
    before = level(dg[:, None] * np.linspace(0, 1, 400)[None, 1:-1])
    assert not (before >= d[:, None] + 1e-9).any()                     # no earlier crossing
    turned = (c < 0) & (4 * rate ** 3 / (27 * c * c) < d)               # crosses only after the rate's turn
    assert 0.1 < turned.mean() < 0.5
    assert rate_walk_passage(np.array([0.5]), np.array([0.25]), np.array([1.0]), np.array([0.0]))[0] == \
        pytest.approx(2.0)                                              # no walk: d / rate
    assert np.isinf(rate_walk_passage(np.array([0.5]), np.array([-0.1]), np.array([1.0]), np.array([0.3]))[0])
    assert rate_walk_passage(np.array([-0.1]), np.array([0.2]), np.array([1.0]), np.array([0.3]))[0] == 0.0


def test_wiener_passage_with_a_rate_walk_matches_simulated_paths():
    """The Wiener model's passage where its rate random-walks and is reflected at 0 (a wear rate
    does not turn negative): each sample's smooth path (rate_walk_passage), the diffusion as an
    inverse Gaussian about it, against 4000 simulated paths (Euler, dg 0.01, |v| after each step):
    p05 within 5 %, p25 and the median within 12 %, p95 at most 1.6x the walk's and never below it.
    Until 2026-11-29 (late) the rate walk was folded into a diffusion matched at the mean passage,
    which put p05 3-13x too early (0.27 for a true 3.5 in the first case): young wear gave false
    WARNs; a walk free to turn the rate negative (each sample's smooth path, unreflected) matched
    p05-p50 but read a fifth of the passages as never."""
    for seed, (d, rate, sig, q) in enumerate(((0.85, 0.06, 0.02, 0.01), (0.5, 0.2, 0.05, 0.04),
                                              (0.3, 0.3, 0.02, 0.09), (0.6, 0.25, 0.03, 0.09))):
        rng = np.random.default_rng(seed)
        n, dt = 4000, 0.01
        x, v, hit = np.zeros(n), np.full(n, rate), np.full(n, np.inf)
        for k in range(6000):
            x += v * dt + sig * math.sqrt(dt) * rng.standard_normal(n)
            v = np.abs(v + math.sqrt(q * dt) * rng.standard_normal(n))
            hit = np.where(np.isinf(hit) & (x >= d), (k + 1) * dt, hit)
        assert np.isfinite(hit).all()
        m = 20000
        mean = rate_walk_passage(np.full(m, d), np.full(m, rate), rng.standard_normal(m), np.full(m, math.sqrt(q)))
        ours = inverse_gaussian(mean, d * d / sig ** 2, rng.standard_normal(m), rng.random(m))
        for qq, tol in ((0.05, 0.05), (0.25, 0.12), (0.5, 0.12)):
            want, got = np.quantile(hit, qq), np.quantile(ours, qq)
            assert got == pytest.approx(want, rel=tol), (seed, qq, want, got)
        assert 1.0 <= np.quantile(ours, 0.95) / np.quantile(hit, 0.95) <= 1.6, seed
        # the folded diffusion of before, for the record: p05 far too early
        s2 = sig * sig + q * (d / rate) ** 2 / 3
        folded = inverse_gaussian(np.full(m, d / rate), np.full(m, d * d / s2), rng.standard_normal(m), rng.random(m))
        assert np.quantile(folded, 0.05) < 0.7 * np.quantile(hit, 0.05), seed


def test_weighted_quantiles():
    x = np.array([3.0, 1.0, np.inf, 2.0])
    np.testing.assert_array_equal(weighted_quantiles(x, None, (0.25, 0.5, 1.0)), [1.0, 2.0, np.inf])
    w = np.array([0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(weighted_quantiles(x, w, (0.05, 0.95)), [2.0, 2.0])


def test_online_updates_equal_the_batch_fit():
    s = load_settings()
    rng = np.random.default_rng(3)
    tau = np.cumsum(np.r_[0.0, rng.uniform(40, 60, 9)])
    y = 0.0008 * tau + np.cumsum(rng.normal(0, 0.005, len(tau)))
    sd = np.full(len(tau), 0.002)
    span = tau[-1] * 1.2       # below the regrid limit: no refit along the way
    on = OnlineFault(tau[:3], y[:3], sd[:3], span_h=span, settings=s)
    for i in range(3, len(tau)):
        on.update(tau[i], y[i], sd[i])
    assert on.regrids == 0
    fits, w = on.fit()
    grids = model_grids(s.models)
    for f in fits:
        b = fit_model([Series(tau, y, sd, span)], grids[f.model])
        np.testing.assert_allclose(f.log_evidence, b.log_evidence, rtol=1e-9)
        np.testing.assert_array_equal(f.cell, b.cell)
        np.testing.assert_allclose(f.mean, b.mean, rtol=1e-7, atol=1e-12)
    # past the regrid limit the tracker refits with the new span
    on.update(tau[-1] * 3, y[-1] + 0.2, 0.002)
    assert on.regrids == 1 and on.span_h == pytest.approx(tau[-1] * 3)


def simulate_fleet(rng, law, n_series, noise, process_nu=None, thr=0.8):
    """Series of a degradation law (gamma process when process_nu) and their true RUL."""
    preds, truths = [], []
    while len(preds) < n_series:
        life = 1000 * math.exp(0.3 * rng.standard_normal())
        t = np.arange(0, 4 * life, 1.0)
        x = t / life
        # paris: Paris-law crack growth a0 / (1 - t / t_c) - a0, its blow-up t_c 15 % of the life past the threshold
        mu = thr * {"linear": x, "exponential": np.expm1(2 * x) / np.expm1(2), "power": x ** 2,
                    "paris": (1 / (1 - np.minimum(x, 1.1499) / 1.15) - 1) / (1 / (1 - 1 / 1.15) - 1)}[law]
        if process_nu:
            k = np.concatenate([[0.0], np.cumsum(rng.gamma(np.diff(mu) / process_nu, process_nu))])
        else:
            k = mu
        eol = t[np.argmax(k >= thr)]
        n = int(rng.integers(5, 18))
        tt = np.arange(n) * 50.0
        if tt[-1] >= eol or np.interp(tt[-1], t, k) < 0.05:
            continue
        y = np.clip(np.interp(tt, t, k) + rng.normal(0, noise, n), 0, 1.5)
        p = FaultPrediction(None, None, threshold=thr, n_tests=n, n_points=n)
        p.series = Series(tt, y, np.full(n, noise), tt[-1])
        preds.append(p)
        truths.append(eol - tt[-1])
    return preds, np.array(truths)


# Measured coverage on 900 series (linear, exponential, linear + gamma 0.002, power + gamma 0.002):
# 97.8, 96.9, 91.0, 91.8 % (2026-11-30, with the hyperbolic time scale in the Wiener model);
# 98.4, 90.1, 92.3, 93.9 % (2026-11-29, the rate walk's passage reflected; with the folded diffusion
# before: 97.9, 93.4, 91.7, 92.6 %). Until then the test drew 150 series: 98.7, 94.0, 92.0, 92.7 %,
# the first one unit below the bound, and the reflected passage read 99.3 % there (unit 67: true RUL
# 474.0 h, p95 473.7 h before, 474.4 h after) -- one unit's Monte Carlo draw, not the intervals; over
# six seeds of 150 both read 98.3-98.6 %. With one prior per model (3:1 against process noise) the
# last case was 77.3 % -- the deterministic power path won the evidence and was too sure.
@pytest.mark.parametrize("law, nu", [("linear", None), ("exponential", None), ("linear", 0.002), ("power", 0.002)])
def test_rul_intervals_are_calibrated_on_known_truth(law, nu):
    """90 % intervals hold the true RUL about 90 % of the time (independent series, fixed seed)."""
    s = load_settings()
    preds, truth = simulate_fleet(np.random.default_rng(11), law, 900, 0.005, nu)
    predict_series(preds, np.full(len(preds), 0.8), 0, s)
    q = np.array([p.quantiles() for p in preds])
    cover = np.mean((q[:, 0] <= truth) & (truth <= q[:, 2]))
    assert 0.80 <= cover <= 0.99, cover
    rel = np.median(np.abs(q[:, 1] - truth) / truth)
    assert rel < 0.25, rel


@pytest.mark.parametrize("nu", [None, 0.002])
def test_wear_that_blows_up_is_not_mostly_predicted_late(nu):
    """On Paris-law wear (a finite-time blow-up, section 3 of docs/prognostics.md) every finite
    shape puts the crossing late; the hyperbolic time scale of the default Wiener model brings the
    share of series failing before their 5 % quantile from 78 % / 59 % (without it: deterministic /
    gamma 0.002) to 28 % / 28 % (measured 2026-11-30, 300 series). Still far above 5 %: the blow-up
    time is not in the data (docs/prognostics.md, "Laws the bench does not simulate")."""
    s = load_settings()
    assert s.models.wiener_hyperbolic_blowup
    preds, truth = simulate_fleet(np.random.default_rng(11), "paris", 300, 0.005, nu)
    predict_series(preds, np.full(len(preds), 0.8), 0, s)
    q = np.array([p.quantiles() for p in preds])
    late = np.mean(truth < q[:, 0])
    assert late <= 0.45, late


CRACK_LIKE = {"names": ["wiener"], "wiener_exponential_rate": [], "wiener_exponent": []}


@pytest.mark.parametrize("nu", [None, 0.002])
def test_a_fault_known_to_grow_as_a_crack_gets_its_own_model_set(nu):
    """A user who knows a fault grows as a crack does (Paris law) says so in fault_models:; that
    fault then fits the Wiener model in the linear and hyperbolic time scales only, and is late
    far less often than with the shared set (the test above); the other faults keep models:.
    Measured 2026-12-07 on these 300 series (deterministic / gamma 0.002): late 27.7 % / 28.0 % with
    the shared set, 0.0 % / 4.3 % with the crack-like set; coverage of the 90 % interval 72 % / 72 %
    -> 99.7 % / 95.7 %; median / true RUL 1.65 / 1.77 -> 1.19 / 1.29 (the blow-up time is still not
    in the data: the medians stay late)."""
    s = load_settings(overrides={"fault_models": {"gm": CRACK_LIKE}})
    # the example file of the docs says the same of fsj
    example = load_settings(Path(__file__).parents[1] / "docs" / "examples" / "crack_like_fsj.yaml")
    assert example.models_for("fsj") == s.models_for("gm") and example.models_for("gm") == s.models
    tau = np.array([0.0, 50.0, 100.0])
    assert set(OnlineFault(tau, [0.0, 0.01, 0.03], [0.005] * 3, settings=s, fault="gm").grids) == {"wiener"}
    assert set(OnlineFault(tau, [0.0, 0.01, 0.03], [0.005] * 3, settings=s, fault="fsj").grids) == set(s.models.names)
    assert s.models_for("gm").names == ("wiener",) and s.models_for("fsj") == s.models == load_settings().models
    preds, truth = simulate_fleet(np.random.default_rng(11), "paris", 300, 0.005, nu)
    predict_series(preds, np.full(len(preds), 0.8), 0, s)          # fault 0: gm
    q = np.array([p.quantiles() for p in preds])
    late = np.mean(truth < q[:, 0])
    assert late <= 0.10, late
    assert all(set(p.model_weights) == {"wiener"} for p in preds)
    shared, _ = simulate_fleet(np.random.default_rng(11), "paris", 300, 0.005, nu)
    predict_series(shared, np.full(len(shared), 0.8), 1, s)        # fault 1: fsj, the shared models:
    q_shared = np.array([p.quantiles() for p in shared])
    assert np.mean(truth < q_shared[:, 0]) > 2 * late


def test_batched_series_of_different_lengths_equal_their_own_fits():
    """The compiled filter over a padded batch gives each series what it gives alone (padding
    carries no time and no information) and what the step-by-step numpy filter gives."""
    s = load_settings()
    rng = np.random.default_rng(5)
    series = []
    for n in (4, 11, 7):
        tau = np.cumsum(np.r_[0.0, rng.uniform(40, 60, n - 1)])
        series.append(Series(tau, 0.001 * tau + rng.normal(0, 0.01, n), np.full(n, 0.01), tau[-1]))
    grid = model_grids(s.models)["wiener"]
    batch = fit_model(series, grid)
    for i, ser in enumerate(series):
        alone = fit_model([ser], grid)
        np.testing.assert_allclose(batch.log_evidence[i], alone.log_evidence[0], rtol=1e-12)
        np.testing.assert_allclose(batch.mean[i], alone.mean[0], rtol=1e-10, atol=1e-14)
        # the numpy step, cell by cell
        t = ser.tau_h / ser.span_h
        g = grid_g(grid, t[None, :])
        eta2 = grid.eta[None, :] ** 2
        st = kf_init(ser.y[None, :1], ser.s[None, :1] ** 2 + eta2, (1, len(grid)))
        for k in range(1, len(t)):
            kf_step(st, g[:, :, k - 1], g[:, :, k], ser.y[None, k:k + 1], ser.s[None, k:k + 1] ** 2 + eta2,
                    grid.sigma[None, :] ** 2, grid.rate_sd[None, :] ** 2)
        ref = summarise(grid, st, g[:, :, -1], np.array([len(t)]))
        np.testing.assert_allclose(alone.log_evidence, ref.log_evidence, rtol=1e-12)
        np.testing.assert_array_equal(alone.cell, ref.cell)
