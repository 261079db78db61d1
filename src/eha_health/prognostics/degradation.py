"""Degradation models of one fault coefficient, fitted with each point weighted by its error.

Data of one fault since its degradation onset (:func:`degradation_segment`): times tau_k
[h] from the anchor test (tau_0 = 0), diagnosed K y_k with standard errors s_k. Time is
normalised by the data span, t~ = tau / T_s (T_s = tau at the last point unless given),
and every model is one linear-Gaussian state space with a shape g(t~), g(0) = 0, g(1) = 1:

    y_k = l0 + a g_k + u_k + e_k,       e_k ~ N(0, s_k^2 + eta^2)
    u_k = u_{k-1} + w_k,                w_k ~ N(0, sigma^2 (g_k - g_{k-1})),  u_0 = 0

* ``linear``      g = t~                              sigma = 0   (params l0, a, eta)
* ``exponential`` g = expm1(b t~) / expm1(b)          sigma = 0   (l0, a, b, eta)
* ``power``       g = t~^b                            sigma = 0   (l0, a, b, eta)
* ``wiener``      g = t~^b, Wiener process u in the   sigma > 0   (l0, a, b, sigma, eta)
  time scale g (b = 1: the classic Wiener degradation model; first passage is inverse
  Gaussian in g)

l0 (level at onset) and a (rise of the mean path over the data span) have flat priors and
are estimated exactly by a Kalman filter on the state (l0, a, u): the filter *is* the
Bayesian update of the degradation parameters, one test at a time (:mod:`online`). The
nonlinear parameters (b, eta, sigma) live on the grids of ``data/prognostics.yaml``; their
posterior is the normalised integrated likelihood over the grid (log-uniform prior). Each
point's diagnosis error s_k enters the observation noise, so precise tests weigh more and
the filtered state carries their uncertainty into the prediction.

Likelihoods (prediction-error decomposition, v_k innovations, F_k their variances, k >= 1
after conditioning l0 on y_0 exactly):

    log p_int = sum_k log N(v_k; 0, F_k) + 1/2 log(2 pi kappa_a)        (flat prior on a)
    log L_ML  = log p_int - log(2 pi) - 1/2 log det P_beta             (Laplace, exact here)

with P_beta the final posterior covariance of (l0, a). Models are compared by
AICc = -2 max log L_ML + 2k + 2k(k+1)/(n-k-1) and averaged with Akaike weights
w_m ~ exp(-Delta_m / 2), models with Delta_m > ``aic_delta_max`` dropped.

The filter is written out for the 3-state case and vectorised over (series x grid cells)
by hand: filterpy's KalmanFilter runs one filter per Python object, and a fleet needs
~10^6 filters per prognosis; tests check this one against filterpy step by step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import ModelSettings

MODELS = ("linear", "exponential", "power", "wiener")
KAPPA_A = 1.0e4          # prior variance of a [K^2]: diffuse against any rise K <= 1.5
N_KEEP = 48              # grid cells kept per (series, model) for sampling
# state rows: x0 x1 x2 (l0, a, u), p00 p01 p02 p11 p12 p22, log-likelihood
_X, _P, _LL = slice(0, 3), slice(3, 9), 9


# ----------------------------------------------------------------------------- shapes
def shape_g(model: str, t: np.ndarray, b: np.ndarray) -> np.ndarray:
    """g(t~; b) of a model (broadcasting t and b)."""
    t = np.maximum(t, 0.0)
    if model == "linear":
        return t + 0.0 * b
    if model == "exponential":
        with np.errstate(over="ignore"):
            return np.expm1(b * t) / np.expm1(b)
    return t ** b


def shape_g_inv(model: str, g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """t~ with g(t~; b) = g (g >= 0)."""
    g = np.maximum(g, 0.0)
    if model == "linear":
        return g + 0.0 * b
    if model == "exponential":
        return np.log1p(g * np.expm1(b)) / b
    return g ** (1.0 / b)


@dataclass(frozen=True)
class Grid:
    """Grid cells of one model: shape exponent/rate b, extra scatter eta [K], diffusion sigma [K]."""
    model: str
    b: np.ndarray
    eta: np.ndarray
    sigma: np.ndarray
    n_params: int        # l0, a and every grid dimension with more than one value

    def __len__(self) -> int:
        return len(self.b)


def model_grids(ms: ModelSettings) -> dict[str, Grid]:
    """The grid of every model named in the settings."""
    out = {}
    for m in ms.names:
        if m == "wiener":
            B, E, S = np.meshgrid(ms.wiener_exponent, ms.wiener_scatter, ms.diffusion, indexing="ij")
            dims = [ms.wiener_exponent, ms.wiener_scatter, ms.diffusion]
        else:
            bs = {"linear": [1.0], "exponential": ms.exponential_rate, "power": ms.power_exponent}[m]
            B, E = np.meshgrid(bs, ms.scatter, indexing="ij")
            S = np.zeros_like(B)
            dims = [bs, ms.scatter]
        k = 2 + sum(len(d) > 1 for d in dims)
        out[m] = Grid(m, B.ravel().astype(float), E.ravel().astype(float), S.ravel().astype(float), k)
    return out


# ----------------------------------------------------------------------------- Kalman filter
def kf_init(y0, r0, shape) -> np.ndarray:
    """State after the first point: l0 ~ N(y0, r0) exactly (flat prior), a ~ N(0, KAPPA_A), u = 0."""
    st = np.zeros((10,) + tuple(shape))
    st[0] = y0
    st[3] = r0
    st[6] = KAPPA_A
    st[9] = 0.5 * math.log(2 * math.pi * KAPPA_A)
    return st


def kf_step(st: np.ndarray, g_prev, g, y, r, sigma2, active=None) -> None:
    """One predict + update of the (l0, a, u) filter, in place, vectorised over cells.

    Predict: u += w, Var w = sigma2 (g - g_prev).  Update with y = l0 + a g + u + e,
    Var e = r.  ``active`` (bool) masks cells whose series has no point at this step.
    """
    x0, x1, x2 = st[0], st[1], st[2]
    p00, p01, p02, p11, p12, p22 = st[3], st[4], st[5], st[6], st[7], st[8]
    p22p = p22 + sigma2 * np.maximum(g - g_prev, 0.0)
    ph0 = p00 + p01 * g + p02
    ph1 = p01 + p11 * g + p12
    ph2 = p02 + p12 * g + p22p
    F = ph0 + ph1 * g + ph2 + r
    v = y - (x0 + x1 * g + x2)
    ll = -0.5 * (np.log(2 * math.pi * F) + v * v / F)
    kv = v / F
    new = np.stack([x0 + ph0 * kv, x1 + ph1 * kv, x2 + ph2 * kv,
                    p00 - ph0 * ph0 / F, p01 - ph0 * ph1 / F, p02 - ph0 * ph2 / F,
                    p11 - ph1 * ph1 / F, p12 - ph1 * ph2 / F, p22p - ph2 * ph2 / F, st[9] + ll])
    if active is None:
        st[:] = new
    else:
        st[:] = np.where(active, new, st)


def log_ml(st: np.ndarray) -> np.ndarray:
    """Profile (maximum) log-likelihood over (l0, a) from the integrated one (Laplace, exact)."""
    det = st[3] * st[6] - st[4] ** 2
    return st[9] - math.log(2 * math.pi) - 0.5 * np.log(np.maximum(det, 1e-300))


# ----------------------------------------------------------------------------- fitting
@dataclass
class Series:
    """Points of one fault since its onset anchor (padded batch rows use NaN)."""
    tau_h: np.ndarray      # [n] hours since the anchor (tau_0 = 0)
    y: np.ndarray          # [n] K
    s: np.ndarray          # [n] 1-sd of K
    span_h: float          # T_s: normalisation of time (default tau_h[-1])


@dataclass
class ModelFit:
    """Posterior over the grid cells of one model for a batch of series (top cells kept)."""
    model: str
    n_params: int
    aicc: np.ndarray       # [S] (inf where the model has too few points)
    max_log_ml: np.ndarray  # [S]
    cell: np.ndarray       # [S, K] grid index of the kept cells
    weight: np.ndarray     # [S, K] posterior weight (sums to 1)
    b: np.ndarray          # [S, K]
    sigma: np.ndarray      # [S, K]
    eta: np.ndarray        # [S, K]
    mean: np.ndarray       # [S, K, 3] posterior mean of (l0, a, u_now)
    cov: np.ndarray        # [S, K, 3, 3]


def _batch(series: list[Series]):
    n = max(len(s.y) for s in series)
    S = len(series)
    t = np.zeros((S, n))
    y = np.zeros((S, n))
    r = np.ones((S, n))
    mask = np.zeros((S, n), bool)
    for i, s in enumerate(series):
        m = len(s.y)
        t[i, :m] = s.tau_h / s.span_h
        t[i, m:] = t[i, m - 1] if m else 0.0
        y[i, :m], r[i, :m], mask[i, :m] = s.y, s.s ** 2, True
    return t, y, r, mask


def fit_model(series: list[Series], grid: Grid, chunk_cells: int = 400_000) -> ModelFit:
    """Run the filter of every grid cell over every series; keep the top cells per series."""
    t, y, r, mask = _batch(series)
    S, N = y.shape
    C = len(grid)
    n_pts = mask.sum(1)
    K = min(N_KEEP, C)
    out = {k: [] for k in ("cell", "lw", "mean", "cov", "lml")}
    step = max(1, chunk_cells // C)
    for a in range(0, S, step):
        sl = slice(a, min(S, a + step))
        tt, yy, rr, mm = t[sl, None, :], y[sl], r[sl], mask[sl]
        g = shape_g(grid.model, tt, grid.b[None, :, None])            # [s, C, N]
        eta2, sig2 = grid.eta[None, :] ** 2, grid.sigma[None, :] ** 2
        st = kf_init(yy[:, :1], rr[:, :1] + eta2, (len(yy), C))
        for k in range(1, N):
            kf_step(st, g[:, :, k - 1], g[:, :, k], yy[:, k:k + 1], rr[:, k:k + 1] + eta2, sig2,
                    mm[:, k:k + 1])
        lint = st[9]
        lml = log_ml(st)
        order = np.argsort(-lint, axis=1)[:, :K]
        top = np.take_along_axis(lint, order, 1)
        lw = top - top[:, :1]
        rows = np.arange(len(yy))[:, None]
        sel = st[:, rows, order]                                       # [10, s, K]
        mean = np.moveaxis(sel[0:3], 0, -1)
        p = sel[3:9]
        cov = np.stack([np.stack([p[0], p[1], p[2]], -1), np.stack([p[1], p[3], p[4]], -1),
                        np.stack([p[2], p[4], p[5]], -1)], -2)
        out["cell"].append(order)
        out["lw"].append(lw)
        out["mean"].append(mean)
        out["cov"].append(cov)
        out["lml"].append(lml.max(1))
    cell = np.concatenate(out["cell"])
    w = np.exp(np.concatenate(out["lw"]))
    w /= w.sum(1, keepdims=True)
    lml = np.concatenate(out["lml"])
    k = grid.n_params
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(n_pts - k - 1 > 0, 2.0 * k * (k + 1) / np.maximum(n_pts - k - 1, 1), 0.0)
    aicc = np.where(n_pts >= k + 1, -2 * lml + 2 * k + corr, np.inf)
    return ModelFit(grid.model, k, aicc, lml, cell, w, grid.b[cell], grid.sigma[cell], grid.eta[cell],
                    np.concatenate(out["mean"]), np.concatenate(out["cov"]))


def akaike_weights(aicc: np.ndarray, delta_max: float) -> np.ndarray:
    """Akaike weights over models (last axis), zero beyond ``delta_max`` of the best."""
    best = np.min(aicc, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        d = aicc - best
    w = np.where(np.isfinite(d) & (d <= delta_max), np.exp(-0.5 * np.where(np.isfinite(d), d, 0.0)), 0.0)
    s = w.sum(-1, keepdims=True)
    return np.divide(w, s, out=np.zeros_like(w), where=s > 0)


def fit_models(series: list[Series], ms: ModelSettings) -> tuple[list[ModelFit], np.ndarray]:
    """Fit every model of the settings; returns the fits and the Akaike weights [S, n_models]."""
    grids = model_grids(ms)
    fits = [fit_model(series, grids[m]) for m in ms.names]
    aicc = np.stack([f.aicc for f in fits], -1)
    return fits, akaike_weights(aicc, ms.aic_delta_max)


# ----------------------------------------------------------------------------- onset
def degradation_segment(time_h: np.ndarray, k: np.ndarray, std: np.ndarray, sigma: float,
                        delta: float) -> int | None:
    """Index of the anchor test of the degradation segment, or None if no onset yet.

    Onset: the first test j from which every later K exceeds the first one by more than
    max(sigma sqrt(s_j^2 + s_0^2), delta); the anchor is the test before it (or test 0).
    """
    n = len(k)
    if n < 2:
        return None
    rise = k - k[0]
    need = np.maximum(sigma * np.sqrt(std ** 2 + std[0] ** 2), delta)
    above = rise > need
    above[0] = False
    # first j such that above[j:] all true
    tail_ok = np.logical_and.accumulate(above[::-1])[::-1]
    js = np.nonzero(tail_ok)[0]
    if not len(js):
        return None
    return max(int(js[0]) - 1, 0)
