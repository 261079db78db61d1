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
* ``hyperbolic``  g = t~ (c - 1) / (c - t~), c > 1     sigma = 0   (l0, a, c, eta)
  (a finite-time blow-up at t~ = c: Paris-law crack growth da/dN = C a^2 integrates to
  a = a0 / (1 - N / N_c), Paris & Erdogan 1963; the exponential's wear rate grows at the
  constant relative rate b, this one's at 2 / (c - t~), without bound. Not in the default
  set: deterministic, it was too sure; by default it is a time scale of the Wiener model)
* ``wiener``      g of any kind above, Wiener process u in the   sigma > 0   (l0, a, b, sigma, eta)
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
AICc = -2 max log L_ML + 2k + 2k(k+1)/(n-k-1), or by their evidence (the default), and averaged
with weights w_m ~ prior_m exp(-Delta_m / 2), models with Delta_m > ``aic_delta_max`` dropped; the
prior (:func:`model_prior`) gives the Wiener model ``stochastic_prior`` and the path models the rest.

Heavy-tailed increments. The Wiener model's likelihood is Gaussian in the increments; wear by
random shocks (a compound Poisson process) has increments of kurtosis far above 3, and its
Gaussian posterior over the cells is too sure: one early jump is read as a decelerating time
scale, the steps between the jumps as a small sigma (an independent probe, 2026-12-07: 12.5 %
of the failures before the 5 % quantile). The variance of a sample variance is (kurt - 1) s^4 / n,
not 2 s^4 / n, so the cell weights use the likelihood tempered by alpha = min(1, 2 / (kurt - 1))
(a sandwich correction; :func:`increment_temper`), kurt the moment ratio of the series' increments
per sqrt(time), times (n + 1) / (n - 1) (its mean for n Gaussian increments is 3 (n - 1) / (n + 1)),
less its standard error sqrt(24 / n): Gaussian increments keep alpha = 1 but by chance (without
that allowance, 38 % of 200 Gaussian series of 15 increments were tempered, down to alpha 0.39;
with it, 6.5 %, alpha >= 0.52).
The evidence that compares the models is not tempered.

The filter is written out for the 3-state case and vectorised over (series x grid cells)
by hand: filterpy's KalmanFilter runs one filter per Python object, and a fleet needs
~10^6 filters per prognosis; tests check this one against filterpy step by step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .config import ModelSettings

MODELS = ("linear", "exponential", "power", "hyperbolic", "wiener")
KAPPA_A = 1.0e4          # prior variance of a [K^2]: diffuse against any rise K <= 1.5
N_KEEP = 48              # grid cells kept per (series, model) for sampling
# state rows: x0 x1 x2 (l0, a, u), p00 p01 p02 p11 p12 p22, log-likelihood
_X, _P, _LL = slice(0, 3), slice(3, 9), 9


# ----------------------------------------------------------------------------- shapes
LINEAR, EXPONENTIAL, POWER, HYPERBOLIC = 0, 1, 2, 3     # shape kinds of g
N_KINDS = 4


def shape_g(kind, t, b) -> np.ndarray:
    """g(t~; b) of a shape kind (0 linear t~, 1 exponential expm1(b t~)/expm1(b), 2 power t~^b,
    3 hyperbolic t~ (b - 1) / (b - t~), inf from the blow-up t~ = b on)."""
    t = np.maximum(t, 0.0)
    kind, b = np.asarray(kind), np.asarray(b, float)
    bb = np.where(kind == EXPONENTIAL, b, 1.0)
    cc = np.where(kind == HYPERBOLIC, b, 2.0)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        e = np.expm1(bb * t) / np.expm1(bb)
        pw = t ** np.where(kind == POWER, b, 1.0)
        hy = np.where(t < cc, t * (cc - 1.0) / (cc - t), np.inf)
    return np.where(kind == EXPONENTIAL, e, np.where(kind == POWER, pw, np.where(kind == HYPERBOLIC, hy,
                                                                                  t + 0.0 * b)))


def shape_g_inv(kind, g, b) -> np.ndarray:
    """t~ with g(t~; b) = g (g >= 0); each kind computed on its own elements only."""
    kind, b, g = np.broadcast_arrays(np.asarray(kind), np.asarray(b, float), np.asarray(g, float))
    out = np.array(np.maximum(g, 0.0), float)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        m = kind == EXPONENTIAL
        if m.any():
            out[m] = np.log1p(out[m] * np.expm1(b[m])) / b[m]
        m = kind == POWER
        if m.any():
            out[m] = out[m] ** (1.0 / b[m])
        m = kind == HYPERBOLIC
        if m.any():     # g (c - t) = t (c - 1); g -> inf at t -> c
            gm, c = out[m], b[m]
            out[m] = np.where(np.isfinite(gm), gm * c / (gm + c - 1.0), c)
    return out


@dataclass(frozen=True)
class Grid:
    """Grid cells of one model: shape kind and its rate/exponent b, scatter eta [K], diffusion sigma [K]."""
    model: str
    kind: np.ndarray
    b: np.ndarray
    eta: np.ndarray
    sigma: np.ndarray
    rate_sd: np.ndarray    # sd of the wear-rate random walk over one span [K/span]
    n_params: int        # l0, a and every grid dimension with more than one value
    log_prior: np.ndarray  # log prior weight of each cell (each shape kind gets equal mass)

    def __len__(self) -> int:
        return len(self.b)


def _cells(kind: int, bs, etas, sigmas, rates=(0.0,)):
    B, E, S, R = np.meshgrid(*(np.asarray(v, float) for v in (bs, etas, sigmas, rates)), indexing="ij")
    return np.full(B.size, kind), B.ravel(), E.ravel(), S.ravel(), R.ravel()


def model_grids(ms: ModelSettings) -> dict[str, Grid]:
    """The grid of every model named in the settings.

    linear / exponential / power / hyperbolic: deterministic mean path (sigma = 0) plus iid scatter eta.
    wiener: the Wiener process in the time scale g of the linear, exponential or power shape (and
    the hyperbolic one where ``wiener_hyperbolic_blowup`` is set; kind and b on the grid), sigma > 0,
    scatter ``wiener_scatter``.
    """
    shapes = {"linear": (LINEAR, [1.0]), "exponential": (EXPONENTIAL, ms.exponential_rate),
              "power": (POWER, ms.power_exponent), "hyperbolic": (HYPERBOLIC, ms.hyperbolic_blowup)}
    out = {}
    for m in ms.names:
        if m == "wiener":
            rs = ms.rate_diffusion
            parts = [_cells(LINEAR, [1.0], ms.wiener_scatter, ms.diffusion, rs),
                     _cells(EXPONENTIAL, ms.wiener_exponential_rate, ms.wiener_scatter, ms.diffusion, rs),
                     _cells(POWER, ms.wiener_exponent, ms.wiener_scatter, ms.diffusion, rs)]
            if ms.wiener_hyperbolic_blowup:
                parts.append(_cells(HYPERBOLIC, ms.wiener_hyperbolic_blowup, ms.wiener_scatter, ms.diffusion, rs))
            kind, b, e, s, r = (np.concatenate(x) for x in zip(*parts))
            # l0, a, time scale (kind, b), eta, sigma, rate diffusion
            k = 2 + 1 + (len(ms.wiener_scatter) > 1) + 1 + (len(rs) > 1)
        else:
            kd, bs = shapes[m]
            kind, b, e, s, r = _cells(kd, bs, ms.scatter, [0.0])
            k = 2 + (len(bs) > 1) + (len(ms.scatter) > 1)
        # prior: equal mass per shape kind, uniform over the cells of a kind (log-uniform grids)
        counts = np.bincount(kind, minlength=N_KINDS)
        out[m] = Grid(m, kind, b, e, s, r, k, -np.log(counts[kind] * len(np.unique(kind))))
    return out


# ----------------------------------------------------------------------------- Kalman filter
NX = 4                                   # state (l0, a, u, v)
_PI = {}                                 # (i, j) -> row of P_ij in the state array
for _i in range(NX):
    for _j in range(_i, NX):
        _PI[(_i, _j)] = _PI[(_j, _i)] = NX + len({v for v in _PI.values()})
LL = NX + NX * (NX + 1) // 2             # row of the log-likelihood
NROW = LL + 1


def kf_init(y0, r0, shape) -> np.ndarray:
    """State after the first point: l0 ~ N(y0, r0) exactly (flat prior), a ~ N(0, KAPPA_A), u = v = 0."""
    st = np.zeros((NROW,) + tuple(shape))
    st[0] = y0
    st[_PI[0, 0]] = r0
    st[_PI[1, 1]] = KAPPA_A
    st[LL] = 0.5 * math.log(2 * math.pi * KAPPA_A)
    return st


def kf_step(st: np.ndarray, g_prev, g, y, r, sigma2, q, active=None) -> None:
    """One predict + update of the (l0, a, u, v) filter, in place, vectorised over cells.

    Predict over dg = g - g_prev: u += v dg + w (Var w = sigma2 dg), v += w' (Var w' = q dg).
    Update with y = l0 + a g + u + e, Var e = r. ``active`` (0/1) masks cells without a
    point: pass them dg = 0 and a huge r, so that only the likelihood needs the mask.
    """
    dg = np.maximum(g - g_prev, 0.0)
    P = {k: st[v] for k, v in _PI.items()}
    # predict: F = I + dg e_u e_v', Q = diag(0, 0, sigma2 dg, q dg)
    st[2] += dg * st[3]
    p22 = P[2, 2] + 2 * dg * P[2, 3] + dg * dg * P[3, 3] + sigma2 * dg
    p20 = P[2, 0] + dg * P[3, 0]
    p21 = P[2, 1] + dg * P[3, 1]
    p23 = P[2, 3] + dg * P[3, 3]
    st[_PI[2, 2]], st[_PI[0, 2]], st[_PI[1, 2]], st[_PI[2, 3]] = p22, p20, p21, p23
    st[_PI[3, 3]] += q * dg
    # update with h = (1, g, 1, 0)
    ph = [st[_PI[i, 0]] + g * st[_PI[i, 1]] + st[_PI[i, 2]] for i in range(NX)]
    F = ph[0] + g * ph[1] + ph[2] + r
    inv = 1.0 / F
    v = y - (st[0] + st[1] * g + st[2])
    kv = v * inv
    phf = [p * inv for p in ph]
    for i in range(NX):
        st[i] += ph[i] * kv
        for j in range(i, NX):
            st[_PI[i, j]] -= ph[i] * phf[j]
    ll = np.log(2 * math.pi * F) + v * kv
    st[LL] -= 0.5 * (ll if active is None else ll * active)


@njit(cache=True, nogil=True, error_model="numpy")
def _filter_cells(st, g, gi, y, r, mask, eta2, sig2, q, start):  # pragma: no cover - compiled
    """:func:`kf_step` over points ``start..N-1`` for every series and cell, in place (the filter
    every fit and the online tracker run; kf_step is the readable reference the tests hold it to): the same
    arithmetic in the same order, a scalar loop per cell instead of numpy temporaries per step
    (the temporaries were 2/3 of a 1000-actuator prognosis). st [NROW, S, C], g [S, U, N]: cell c's
    time scale is g[:, gi[c], :] (the grid's cells share a few shapes). The state is held in named
    scalars (pij: P[i, j], i <= j), not a 4x4 array kept symmetric: a quarter less time, the
    stores of both triangles gone."""
    n_s, n_k, n_c = g.shape[0], g.shape[2], len(gi)
    for i_s in range(n_s):
        for c in range(n_c):
            x0, x1, x2, x3 = st[0, i_s, c], st[1, i_s, c], st[2, i_s, c], st[3, i_s, c]
            p00, p01, p02, p03 = st[4, i_s, c], st[5, i_s, c], st[6, i_s, c], st[7, i_s, c]
            p11, p12, p13 = st[8, i_s, c], st[9, i_s, c], st[10, i_s, c]
            p22, p23, p33 = st[11, i_s, c], st[12, i_s, c], st[13, i_s, c]
            ll = st[14, i_s, c]
            u = gi[c]
            for k in range(start, n_k):
                act = mask[i_s, k]
                gk = g[i_s, u, k]
                dg = max(gk - g[i_s, u, k - 1], 0.0)
                yk = y[i_s, k] if act else 0.0
                rk = r[i_s, k] + eta2[c] if act else 1e300
                # predict: F = I + dg e_u e_v', Q = diag(0, 0, sigma2 dg, q dg)
                x2 += dg * x3
                p22 = p22 + 2 * dg * p23 + dg * dg * p33 + sig2[c] * dg
                p02 = p02 + dg * p03
                p12 = p12 + dg * p13
                p23 = p23 + dg * p33
                p33 += q[c] * dg
                # update with h = (1, g, 1, 0): ph = P h
                h0 = p00 + gk * p01 + p02
                h1 = p01 + gk * p11 + p12
                h2 = p02 + gk * p12 + p22
                h3 = p03 + gk * p13 + p23
                F = h0 + gk * h1 + h2 + rk
                inv = 1.0 / F
                v = yk - (x0 + x1 * gk + x2)
                kv = v * inv
                x0 += h0 * kv
                x1 += h1 * kv
                x2 += h2 * kv
                x3 += h3 * kv
                p00 -= h0 * (h0 * inv)
                p01 -= h0 * (h1 * inv)
                p02 -= h0 * (h2 * inv)
                p03 -= h0 * (h3 * inv)
                p11 -= h1 * (h1 * inv)
                p12 -= h1 * (h2 * inv)
                p13 -= h1 * (h3 * inv)
                p22 -= h2 * (h2 * inv)
                p23 -= h2 * (h3 * inv)
                p33 -= h3 * (h3 * inv)
                if act:
                    ll -= 0.5 * (np.log(2 * math.pi * F) + v * kv)
            st[0, i_s, c], st[1, i_s, c], st[2, i_s, c], st[3, i_s, c] = x0, x1, x2, x3
            st[4, i_s, c], st[5, i_s, c], st[6, i_s, c], st[7, i_s, c] = p00, p01, p02, p03
            st[8, i_s, c], st[9, i_s, c], st[10, i_s, c] = p11, p12, p13
            st[11, i_s, c], st[12, i_s, c], st[13, i_s, c] = p22, p23, p33
            st[14, i_s, c] = ll


def state_cov(st: np.ndarray) -> np.ndarray:
    """Covariance [..., NX, NX] of the state rows ``st`` [NROW, ...]."""
    return np.stack([np.stack([st[_PI[i, j]] for j in range(NX)], -1) for i in range(NX)], -2)


def log_ml(st: np.ndarray) -> np.ndarray:
    """Profile (maximum) log-likelihood over (l0, a) from the integrated one (Laplace, exact)."""
    det = st[_PI[0, 0]] * st[_PI[1, 1]] - st[_PI[0, 1]] ** 2
    return st[LL] - math.log(2 * math.pi) - 0.5 * np.log(np.maximum(det, 1e-300))


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
    log_evidence: np.ndarray  # [S] log of the likelihood integrated over (l0, a) and the grid prior
    cell: np.ndarray       # [S, K] grid index of the kept cells
    weight: np.ndarray     # [S, K] posterior weight (sums to 1)
    kind: np.ndarray       # [S, K] shape kind of the time scale g
    b: np.ndarray          # [S, K]
    sigma: np.ndarray      # [S, K]
    eta: np.ndarray        # [S, K]
    rate_sd: np.ndarray    # [S, K]
    mean: np.ndarray       # [S, K, 4] posterior mean of (l0, a, u_now, v_now)
    cov: np.ndarray        # [S, K, 4, 4]
    g_now: np.ndarray      # [S, K] g at the last point
    mean2: np.ndarray      # [S, K, 2] path: (l0, a); wiener: (X_now, rate a + v_now)
    cov2: np.ndarray       # [S, K, 2, 2]


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


def grid_shapes(grid: Grid, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grid's distinct time scales at normalised times t [s, N]: g [s, U, N] and the shape of
    each cell [C] (cell c's g is g[:, shape[c], :])."""
    ug, inv = np.unique(np.stack([grid.kind, grid.b]), axis=1, return_inverse=True)
    return shape_g(ug[0][None, :, None], t[:, None, :], ug[1][None, :, None]), inv.ravel()


def grid_g(grid: Grid, t: np.ndarray) -> np.ndarray:
    """g of every cell at normalised times t [s, N] -> [s, C, N] (distinct shapes computed once)."""
    g, shape = grid_shapes(grid, t)
    return g[:, shape, :]


def run_filters(grid: Grid, g: np.ndarray, y: np.ndarray, r: np.ndarray, mask: np.ndarray,
                st: np.ndarray | None = None, start: int = 1, shape: np.ndarray | None = None) -> np.ndarray:
    """Filter every cell over points ``start..N-1`` (state ``st`` after point start-1, else fresh).

    ``g``: every cell's time scale [s, C, N] (:func:`grid_g`), or with ``shape`` the distinct ones
    [s, U, N] and each cell's (:func:`grid_shapes`), which the filter reads in place: spread to
    the cells, g was copied twice (the indexing, then to C order), 1.6 GB each on a 1000-actuator
    prognosis (the same values)."""
    eta2 = np.ascontiguousarray(grid.eta ** 2, float)
    if st is None:
        st = kf_init(y[:, :1], r[:, :1] + eta2[None, :], (len(y), len(grid)))
    if shape is None:
        shape = np.arange(g.shape[1])
    # padded rows (mask False): no time passes (g constant) and the point carries no information
    _filter_cells(st, np.ascontiguousarray(g, float), np.ascontiguousarray(shape, np.int64),
                  np.ascontiguousarray(y, float), np.ascontiguousarray(r, float),
                  np.ascontiguousarray(mask, np.bool_), eta2, np.ascontiguousarray(grid.sigma ** 2, float),
                  np.ascontiguousarray(grid.rate_sd ** 2, float), start)
    return st


def increment_temper(t: np.ndarray, y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """alpha [S] of each row of ``t, y, mask`` [S, N] (module docstring, "Heavy-tailed increments"):
    min(1, 2 / (kurt - 1)), kurt of the increments dy / sqrt(dt) between the points in ``mask`` (its
    small-sample bias corrected, less its standard error); 1 with
    fewer than 4 increments or none that differ."""
    pair = mask[:, 1:] & mask[:, :-1]
    dt = np.diff(t, axis=1)
    d = np.where(pair, np.diff(y, axis=1) / np.sqrt(np.where(pair & (dt > 0), dt, 1.0)), 0.0)
    n = pair.sum(1)
    nn = np.maximum(n, 1)
    z = np.where(pair, d - (d.sum(1) / nn)[:, None], 0.0)
    m2 = (z * z).sum(1) / nn
    m4 = (z ** 4).sum(1) / nn
    ok = (n >= 4) & (m2 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        kurt = np.where(ok, m4 / np.where(ok, m2, 1.0) ** 2 * (n + 1) / np.maximum(n - 1, 1), 3.0)
    kurt = kurt - np.sqrt(24.0 / np.maximum(n, 1))     # less its standard error (sqrt(24 / n))
    return np.where(ok, np.minimum(1.0, 2.0 / np.maximum(kurt - 1.0, 1e-9)), 1.0)


def summarise(grid: Grid, st: np.ndarray, g_now: np.ndarray, n_pts: np.ndarray,
              temper: np.ndarray | None = None) -> ModelFit:
    """Posterior over the cells from the filter states [NROW, S, C]: top cells, criteria, RUL inputs.
    ``temper`` [S]: the cell weights from the likelihood to this power (:func:`increment_temper`);
    the evidence and AICc from the whole one."""
    K = min(N_KEEP, len(grid))
    lint = st[LL] + grid.log_prior[None, :]
    lpost = lint if temper is None else temper[:, None] * st[LL] + grid.log_prior[None, :]
    lml = log_ml(st).max(1)
    order = np.argsort(-lpost, axis=1)[:, :K]
    top = np.take_along_axis(lpost, order, 1)
    w = np.exp(top - top[:, :1])
    w /= w.sum(1, keepdims=True)
    rows = np.arange(st.shape[1])[:, None]
    sel = st[:, rows, order]                                       # [NROW, S, K]
    mean = np.moveaxis(sel[0:NX], 0, -1)
    cov = state_cov(sel)
    gnow = np.take_along_axis(g_now, order, 1)
    # the two quantities the RUL needs: path models (l0, a); Wiener (X_now, current rate a + v)
    T = np.zeros(gnow.shape + (2, NX))
    if grid.model == "wiener":
        T[..., 0, 0], T[..., 0, 1], T[..., 0, 2] = 1.0, gnow, 1.0
        T[..., 1, 1], T[..., 1, 3] = 1.0, 1.0
    else:
        T[..., 0, 0], T[..., 1, 1] = 1.0, 1.0
    mx = lint.max(1, keepdims=True)
    lev = (mx + np.log(np.exp(lint - mx).sum(1, keepdims=True)))[:, 0]
    k = grid.n_params
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(n_pts - k - 1 > 0, 2.0 * k * (k + 1) / np.maximum(n_pts - k - 1, 1), 0.0)
    aicc = np.where(n_pts >= k + 1, -2 * lml + 2 * k + corr, np.inf)
    lev = np.where(n_pts >= 3, lev, -np.inf)   # proper on the grid from 3 points
    return ModelFit(grid.model, k, aicc, lml, lev, order, w, grid.kind[order], grid.b[order], grid.sigma[order],
                    grid.eta[order], grid.rate_sd[order], mean, cov, gnow,
                    np.einsum("skij,skj->ski", T, mean), np.einsum("skij,skjl,skml->skim", T, cov, T))


def concat_fits(parts: list[ModelFit]) -> ModelFit:
    """One ModelFit from fits of consecutive series chunks."""
    first = parts[0]
    vals = {f: (np.concatenate([getattr(p, f) for p in parts]) if isinstance(getattr(first, f), np.ndarray)
                else getattr(first, f)) for f in first.__dataclass_fields__}
    return ModelFit(**vals)


def fit_model(series: list[Series], grid: Grid, chunk_cells: int = 400_000, batch=None) -> ModelFit:
    """Run the filter of every grid cell over every series; keep the top cells per series
    (``batch``: :func:`_batch` of the series where the caller has it; the filter does not write it)."""
    t, y, r, mask = batch or _batch(series)
    step = max(1, chunk_cells // len(grid))
    parts = []
    for a in range(0, len(y), step):
        sl = slice(a, min(len(y), a + step))
        g, shape = grid_shapes(grid, t[sl])                                 # [s, U, N], [C]
        st = run_filters(grid, g, y[sl], r[sl], mask[sl], shape=shape)
        temper = increment_temper(t[sl], y[sl], mask[sl]) if grid.model == "wiener" else None
        parts.append(summarise(grid, st, g[:, shape, -1], mask[sl].sum(1), temper))
    return concat_fits(parts)


def akaike_weights(aicc: np.ndarray, delta_max: float) -> np.ndarray:
    """Akaike weights over models (last axis), zero beyond ``delta_max`` of the best."""
    best = np.min(aicc, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        d = aicc - best
    w = np.where(np.isfinite(d) & (d <= delta_max), np.exp(-0.5 * np.where(np.isfinite(d), d, 0.0)), 0.0)
    s = w.sum(-1, keepdims=True)
    return np.divide(w, s, out=np.zeros_like(w), where=s > 0)


def fit_models(series: list[Series], ms: ModelSettings) -> tuple[list[ModelFit], np.ndarray]:
    """Fit every model of the settings; returns the fits and the criteria [S, n_models]
    (:func:`model_criteria`; :func:`akaike_weights` turns them into weights)."""
    grids = model_grids(ms)
    batch = _batch(series)                  # the same padded arrays for every model
    fits = [fit_model(series, grids[m], batch=batch) for m in ms.names]
    return fits, model_criteria(fits, ms)


def model_prior(names, stochastic_prior: float) -> np.ndarray:
    """Prior model probabilities: ``stochastic_prior`` for the Wiener model, the rest shared by the
    path models. Each path model is the Wiener model's sigma = q = 0 limit, whose interval holds no
    process noise; one prior per model would put 3:1 on "no process noise" before any data."""
    names = list(names)
    if "wiener" not in names or len(names) == 1:
        return np.full(len(names), 1.0 / len(names))
    return np.array([stochastic_prior if n == "wiener" else (1.0 - stochastic_prior) / (len(names) - 1)
                     for n in names])


def model_criteria(fits: list[ModelFit], ms: ModelSettings) -> np.ndarray:
    """Criterion [S, n_models] of the settings -- AICc, or -2 log evidence (Bayesian) -- less
    2 log of the prior model probabilities (:func:`model_prior`); lower is better."""
    if ms.criterion == "evidence":
        crit = np.stack([-2 * f.log_evidence for f in fits], -1)
    else:
        crit = np.stack([f.aicc for f in fits], -1)
    return crit - 2.0 * np.log(model_prior(ms.names, ms.stochastic_prior))


def model_weights(fits: list[ModelFit], ms: ModelSettings) -> np.ndarray:
    """Weights [S, n_models] from :func:`model_criteria`."""
    return akaike_weights(model_criteria(fits, ms), ms.aic_delta_max)


# ----------------------------------------------------------------------------- onset
def degradation_segment(time_h: np.ndarray, k: np.ndarray, std: np.ndarray, sigma: float,
                        delta: float, sigma_last: float | None = None) -> int | None:
    """Index of the anchor test of the degradation segment, or None if no onset yet.

    Onset: the first test j from which every later K exceeds the first one by more than
    max(sigma sqrt(s_j^2 + s_0^2), delta); the anchor is the test before it (or test 0). A rise
    that only the last test shows must clear ``sigma_last`` sd instead (where given): one test
    3 sd up is 1 flat series in 700 at every look, and it was read as wear with a RUL of hours
    (an independent probe: 9 false WARNs in a 3000-actuator fleet); a real rise shows again at
    the next test.
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
    if js[0] == n - 1 and sigma_last is not None and not rise[-1] > max(
            sigma_last * math.sqrt(std[-1] ** 2 + std[0] ** 2), delta):
        return None
    return max(int(js[0]) - 1, 0)


_ROWS = 256     # onset candidates per block of :func:`rise_onset` (memory ~ 10 x _ROWS x n floats)


def _hinge_gain(time_h, k, w, t_on, sw, sy, syy) -> np.ndarray:
    """Smallest leave-one-out (before the last) hinge gain of :func:`rise_onset`, per onset in ``t_on``."""
    n = len(k)
    x = np.maximum(time_h[None, :] - t_on[:, None], 0.0)            # [J, n]
    wx = w * x
    sx = wx.sum(1, keepdims=True) - wx
    sxx = (wx * x).sum(1, keepdims=True) - wx * x
    sxy = (wx * k).sum(1, keepdims=True) - wx * k
    cxy, cxx = sxy - sx * sy / sw, sxx - sx * sx / sw
    ok = (cxy > 0) & (cxx > 1e-12 * np.maximum(sxx, 1e-300))
    gain = np.where(ok, cxy * cxy / np.where(ok, cxx, 1.0), 0.0)
    if n >= 5:
        # errors understated: the scatter about the hinge itself (n - 1 tests, 2 parameters) is
        # the error scale where it exceeds the stated one -- an F test, never more lenient
        resid = np.maximum((syy - sy * sy / sw) - gain, 0.0) / (n - 3)
        gain = gain / np.maximum(resid, 1.0)
    return gain[:, :-1].min(1)


def rise_onset(time_h: np.ndarray, k: np.ndarray, std: np.ndarray, chi2_min: float,
               min_after: int = 2) -> int | None:
    """Onset test j of the strongest rise of K as a whole, or None if none clears ``chi2_min``.

    For each j with at least ``min_after`` tests after it, the hinge y = c + b max(t - t_j, 0)
    (b > 0) is fitted by weighted least squares (weights 1/s^2); its gain over a constant level
    is Delta chi^2_j = (S_xy - S_x S_y / S_w)^2 / (S_xx - S_x^2 / S_w), the sums weighted. The
    gain counted is the smallest with any one test before the last left out, so no single test
    within the history (a failed diagnosis) makes a rise; the last one may, as it may in
    :func:`degradation_segment` (:func:`rul.prepare_fault` weighs a last test off the trend
    against the history without it). Where the hinge's residual chi^2 per degree of freedom
    exceeds 1, the gain is divided by it (the errors are understated; an F statistic). The onset
    is the j of the largest gain if that is >= ``chi2_min``. Where :func:`degradation_segment`
    asks every later test to clear the first one by sigma sd, this pools the tests: a rise of
    two sd held by several tests is seen (with errors of 0.03, K rises 0.1 long before any single
    test clears the first by 3 sd).
    """
    n = len(k)
    m = n - min_after
    if m < 1:
        return None
    w = 1.0 / np.square(std)
    wk = w * k
    sw, sy = w.sum() - w[None, :], wk.sum() - wk[None, :]     # every test left out once [1, n]
    syy = (wk * k).sum() - wk * k
    # onsets in blocks: the [J, n] sums of a history of thousands of tests would take GBs
    gain = np.concatenate([_hinge_gain(time_h, k, w, time_h[a:min(a + _ROWS, m)], sw, sy, syy)
                           for a in range(0, m, _ROWS)])
    j = int(np.argmax(gain))
    return j if gain[j] >= chi2_min else None
