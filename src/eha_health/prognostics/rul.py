"""Remaining useful life as a distribution, per fault and overall (CLI: ``eha-health prognose``).

For each fault of each actuator, the tests since the fault's last repair (recorded, or a fall
of K that persists), less those far off their neighbours (failed diagnoses, :mod:`scatter`; a
last test off the trend gives an even mixture of the predictions with and without it); its onset anchor
(:func:`degradation.degradation_segment`; where no test clears the first, the tests' rise as a
whole, :func:`degradation.rise_onset`) and ``prognosis.onset_candidates`` onset times from the
first post-repair test to it, each with the models of :mod:`degradation` fitted to every
post-repair point; weights over (onset, model) from their criteria; then S Monte Carlo samples
of the RUL [h], each drawing its onset first:

* model m drawn with its Akaike weight, grid cell with its posterior weight, and
  beta = (l0, a, u_now) ~ N(mean, cov) of that cell (the filter's posterior: it carries
  each test's diagnosis error);
* path models (linear, exponential, power, hyperbolic): the mean path l0 + a g(t~) reaches the
  threshold at t~* = g^-1((thr - l0) / a); RUL = (t~* - t~_now) T_s (0 if already above,
  no crossing if a <= 0);
* Wiener: from X_now = l0 + a g_now + u_now and the current rate a + v_now, the rate's random
  walk drawn as one smooth path per sample, kept from turning negative
  (:func:`rate_walk_passage`), and the diffusion about it inverse Gaussian in the time scale g,
  dg ~ IG(mean = that path's passage, shape (thr - X_now)^2/sigma^2); t~* = g^-1(g_now + dg).

Samples beyond ``horizon_factor`` data spans count as "beyond the horizon" (inf). The
overall RUL is the first fault to reach its threshold, faults independent:
P(R <= t) = 1 - prod_f (1 - F_f(t)) from each fault's weighted samples (:func:`overall`).
``p_fail_next`` = P(RUL <= next_check_h); when the next check lies beyond the horizon and
samples do too, only its lower bound is known (``p_fail_next_min``).

Fleet prior: the other actuators with at least ``fleet.min_points`` points since onset
give lives from onset to threshold L_j = tau_now + median RUL, each with the sd s_j of its log
(from its own 5 % quantile); the prior on the life of this fault is the lognormal with mu =
mean(log L_j), sd^2 = var(log L_j) + mean(s_j^2) (an actuator that is a member itself gets the
prior of the others). An actuator with fewer than
``fleet.use_below_points`` points since onset has its samples importance-weighted by that
prior density at tau_now + RUL (Bayes: posterior ~ likelihood x prior); ``fleet_prior``
says so in the output. With fewer than ``min_tests`` tests since the last repair no RUL
is given and ``reason`` says why.

On the usage clock (``prognosis.clock: usage``, :mod:`clock`) the same is done with each
actuator's usage as the time axis; the samples are then usage, made hours by
:func:`to_hours` (kept as ``usage_samples``).

Random draws are common random numbers per fault (``SeedSequence([seed, fault])``), so an
actuator's result depends on its own data (and the fleet prior) only, and the same seed
gives the same result.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from numba import njit

from .config import PrognosticsError, Settings, load_settings
from .degradation import (ModelFit, Series, akaike_weights, degradation_segment, fit_models, rise_onset,
                          shape_g, shape_g_inv)
from .prior_cache import FleetPriorCache
from .scatter import (first_above_the_rest, isolated_outliers, isolated_outliers_of, last_persistent_fall,
                      last_persistent_falls, noise_estimate)
from .records import trend_start_h
from .thresholds import FAULTS, threshold_values

if TYPE_CHECKING:
    from .clock import UsageClock

CHUNK = 256   # series per sampling chunk (memory ~ CHUNK x samples x 30 floats)
PARALLEL_MIN = 16   # actuators per thread task of prognose at the least (fewer: serial, threads cost more than they give)


# ----------------------------------------------------------------------------- random draws
@dataclass(frozen=True)
class Draws:
    """Common random numbers of one fault: uniforms and normals of every sample."""
    u_model: np.ndarray
    u_cell: np.ndarray
    z: np.ndarray        # [M, 4]
    z_ig: np.ndarray
    u_ig: np.ndarray
    u_onset: np.ndarray
    u_last: np.ndarray   # with or without a last test that is off the trend

    @classmethod
    def make(cls, seed: int, fault_index: int, m: int) -> "Draws":
        rng = np.random.default_rng([seed, fault_index])
        return cls(rng.random(m), rng.random(m), rng.standard_normal((m, 4)), rng.standard_normal(m),
                   rng.random(m), rng.random(m), rng.random(m))


def inverse_gaussian(mean: np.ndarray, shape: np.ndarray, z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Inverse Gaussian IG(mean, shape) from a standard normal z and a uniform u.

    Michael, Schucany & Haas (1976), in the cancellation-free form
    x = mean 2 shape / (2 shape + mean y + sqrt(mean y (4 shape + mean y))), y = z^2;
    return x if u <= mean / (mean + x) else mean^2 / x. Written out (numpy's ``wald``
    draws its own numbers) so that the draws are common random numbers.
    """
    y = z * z
    my = mean * y
    x = mean * 2 * shape / (2 * shape + my + np.sqrt(my * (4 * shape + my)))
    return np.where(u <= mean / (mean + x), x, mean * mean / x)


REFLECTED_GROWTH = (2.0 / 3.0) * math.sqrt(2.0 / math.pi)   # E int_0^u |W| = this u^(3/2), W standard


def rate_walk_passage(d: np.ndarray, rate: np.ndarray, z: np.ndarray, rate_sd: np.ndarray,
                      iterations: int = 40) -> np.ndarray:
    """dg > 0 at which the smooth path of a random-walking wear rate first reaches d [g units]:
    inf where rate <= 0, 0 where d <= 0.

    The walk (sd ``rate_sd`` per sqrt(g)) adds q dg^3 / 3 to the level variance at dg; each sample
    draws it as L(dg) = rate dg + c dg^(3/2), c = z sqrt(q / 3), whose rate is rate + 3/2 c
    sqrt(dg). A wear rate does not turn negative (K does not heal): where c < 0 the rate reaches 0
    at dg* = (2 rate / (3 c))^2 with L at its peak 4 rate^3 / (27 c^2), and a walk restarted there
    from 0 and reflected grows the level by E int |W| = (2/3) sqrt(2 / pi) sqrt(q) u^(3/2) in u =
    dg - dg*. So: the first root of c x^3 + rate x^2 = d (x = sqrt(dg), bracketed Newton steps) if
    the peak reaches d, else dg* + ((d - peak) / ((2/3) sqrt(2 / pi) sqrt(q)))^(2/3). Against
    simulated paths of the reflected walk: tests/test_prognostics_models.py."""
    d, rate, z, rate_sd = np.broadcast_arrays(*(np.asarray(v, float) for v in (d, rate, z, rate_sd)))
    out = np.where(~(rate > 0), np.inf, np.where(~(d > 0), 0.0, np.nan))
    go = np.isnan(out)
    d, rate, c, rq = d[go], rate[go], z[go] * rate_sd[go] / math.sqrt(3.0), rate_sd[go]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x0 = np.sqrt(d / rate)
        neg = c < 0
        xs = np.where(neg, -2.0 * rate / (3.0 * c), np.inf)
        peak = np.where(neg, 4.0 * rate ** 3 / (27.0 * c * c), np.inf)
        after = neg & (peak < d)
        res = np.where(after, xs * xs + ((d - peak) / (REFLECTED_GROWTH * rq)) ** (2.0 / 3.0), x0 * x0)
        # the first root: c > 0 in (0, x0]; c < 0 with the peak above d in [x0, x*]; c = 0: x0
        it = np.nonzero((c != 0) & ~after)[0]
        cc, rr, dd = c[it], rate[it], d[it]
        lo, hi = np.where(cc < 0, x0[it], 0.0), np.where(cc < 0, xs[it], x0[it])
        res[it] = _newton_roots(cc, rr, dd, lo, hi, x0[it], iterations) ** 2
    out[go] = res
    return out


def _newton_roots(c: np.ndarray, rate: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  x0: np.ndarray, iterations: int) -> np.ndarray:
    """Root x of c x^3 + rate x^2 = d in [lo, hi] from x0, per element (:func:`rate_walk_passage`).

    Bracketed Newton steps (a step that leaves the bracket bisects it), one step of every element
    at a time until all have moved by <= 1e-13 x in one step: the numpy loop this replaced, fused
    into one pass per step (its 20 temporaries per step were a sixth of a 1000-actuator
    prognosis), the same arithmetic in the same order, so the same roots to the last bit."""
    lo, hi = np.array(lo, float), np.array(hi, float)       # copies: the kernel moves the brackets
    x = np.array(x0, float)
    _newton_kernel(np.ascontiguousarray(c, float), np.ascontiguousarray(rate, float),
                   np.ascontiguousarray(d, float), lo, hi, x, iterations)
    return x


@njit(cache=True, nogil=True, error_model="numpy")
def _newton_kernel(c, r, d, lo, hi, x, iterations):  # pragma: no cover - compiled
    """:func:`_newton_roots` in place on lo, hi, x."""
    n = len(x)
    for _ in range(iterations):
        done = True
        for i in range(n):
            xi = x[i]
            h = (c[i] * xi + r[i]) * xi * xi - d[i]
            if h < 0:
                lo[i] = xi
            else:
                hi[i] = xi
            step = xi - h / ((3.0 * c[i] * xi + 2.0 * r[i]) * xi)
            nxt = step if (step > lo[i]) and (step < hi[i]) else 0.5 * (lo[i] + hi[i])
            if not abs(nxt - xi) <= 1e-13 * xi:
                done = False
            x[i] = nxt
        if done:
            break


def weighted_quantiles(x: np.ndarray, w: np.ndarray | None, qs) -> np.ndarray:
    """Quantiles of samples ``x`` (inf allowed) with weights ``w`` (inverted CDF, last axis)."""
    order = np.argsort(x, axis=-1)
    xs = np.take_along_axis(x, order, -1)
    if w is None:
        cw = np.broadcast_to(np.arange(1, x.shape[-1] + 1) / x.shape[-1], x.shape)
    else:
        ws = np.take_along_axis(w, order, -1)
        cw = np.cumsum(ws, -1)
        cw = cw / cw[..., -1:]
    out = []
    for q in qs:
        i = np.minimum((cw < q - 1e-12).sum(-1), x.shape[-1] - 1)
        out.append(np.take_along_axis(xs, i[..., None], -1)[..., 0])
    return np.stack(out, -1)


# ----------------------------------------------------------------------------- sampling
def _pick(cum: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index per row of ``cum`` [s, K] (cumulative weights) for uniforms ``u`` [M]: [s, M].

    Row r is searched as cum[r] + 2 r for (u + 2 r)(1 - 1e-12) (the rows apart by 2, so that
    one search of the flattened rows found them all). Where every value lies in [0, 1.5] (weights
    summed, normalised), the values below a query are the first of its row, so searching the row
    alone (:func:`_pick_rows`, twice as fast as one search of the flattened rows) finds the same
    index; otherwise (NaN) the flattened search, whose order of NaN is numpy's, as before."""
    s, k = cum.shape
    out = np.empty((s, len(u)), np.int64)
    if _pick_rows(np.ascontiguousarray(cum, float), np.ascontiguousarray(u, float), out):
        return out
    flat = (cum + 2.0 * np.arange(s)[:, None]).ravel()
    idx = np.searchsorted(flat, (u[None, :] + 2.0 * np.arange(s)[:, None]).ravel() * (1 - 1e-12), "left")
    return np.minimum(idx.reshape(s, -1) - k * np.arange(s)[:, None], k - 1)


@njit(cache=True, nogil=True)
def _pick_rows(cum, u, out):  # pragma: no cover - compiled
    """:func:`_pick` row by row into ``out``, the same floats compared; False (out unset) where
    a value of ``cum`` lies outside [0, 1.5]."""
    if not _normalised(cum):
        return False
    for r in range(cum.shape[0]):
        for j in range(len(u)):
            out[r, j] = _search(cum, r, u[j])
    return True


def _pick_at(cum: np.ndarray, u: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``_pick(cum, u)[rows, cols]``, searching those entries only (a model's samples need their
    own cells only: a quarter of the searches on four models)."""
    out = np.empty(len(rows), np.int64)
    if _pick_rows_at(np.ascontiguousarray(cum, float), np.ascontiguousarray(u, float), rows, cols, out):
        return out
    return _pick(cum, u)[rows, cols]


@njit(cache=True, nogil=True)
def _pick_rows_at(cum, u, rows, cols, out):  # pragma: no cover - compiled
    """:func:`_pick_rows` at the entries (rows[e], cols[e]) into ``out[e]``."""
    if not _normalised(cum):
        return False
    for e in range(len(rows)):
        out[e] = _search(cum, rows[e], u[cols[e]])
    return True


@njit(cache=True, nogil=True)
def _normalised(cum):  # pragma: no cover - compiled
    """Whether every value of ``cum`` lies in [0, 1.5] (:func:`_pick`)."""
    s, k = cum.shape
    for r in range(s):
        for j in range(k):
            if not (0.0 <= cum[r, j] <= 1.5):
                return False
    return True


@njit(cache=True, nogil=True)
def _search(cum, r, u):  # pragma: no cover - compiled
    """Index of uniform ``u`` in row ``r`` of ``cum``: the first value with cum[r] + 2 r >=
    (u + 2 r)(1 - 1e-12) ("left"), at most the last."""
    k = cum.shape[1]
    off = 2.0 * r
    q = (u + off) * (1 - 1e-12)
    a, b = 0, k
    while a < b:
        m = (a + b) >> 1
        if cum[r, m] + off < q:
            a = m + 1
        else:
            b = m
    return min(a, k - 1)


def _chol2(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cholesky factor (l00, l10, l11) of 2x2 covariances [..., 2, 2] (semi-definite allowed)."""
    l00 = np.sqrt(np.maximum(c[..., 0, 0], 0.0))
    l10 = np.divide(c[..., 0, 1], l00, out=np.zeros_like(l00), where=l00 > 0)
    l11 = np.sqrt(np.maximum(c[..., 1, 1] - l10 * l10, 0.0))
    return l00, l10, l11


def sample_rul(series: list[Series], fits: list[ModelFit], model_w: np.ndarray, thr: np.ndarray,
               draws: Draws) -> np.ndarray:
    """RUL samples [S, M] in hours (inf: no crossing); the horizon cut is the caller's
    (:func:`_predict_prepared`: the fleet prior weighs the samples before it)."""
    S, M = len(series), len(draws.u_model)
    out = np.empty((S, M))
    span = np.array([s.span_h for s in series])
    t_now = np.array([s.tau_h[-1] for s in series]) / span
    cum_models = np.cumsum(model_w, -1)
    cum_models[:, -1] = 1.0
    for a in range(0, S, CHUNK):
        sl = slice(a, min(S, a + CHUNK))
        n = sl.stop - sl.start
        which = _pick(cum_models[sl], draws.u_model)
        rul = np.full((n, M), np.inf)
        for mi, f in enumerate(fits):
            use = which == mi
            if not use.any():
                continue
            # this model's samples only (row ri, sample si, cell ci), in the order of the whole
            # chunk: each element's arithmetic is the one the whole chunk had, the others' is not done.
            # Gathered by flat indices into the chunk's [n, M] and [n, K] arrays: the same elements
            # as indexing by (ri, ci), in a third of the time
            at = np.flatnonzero(use)                        # ri M + si
            ri, si = np.divmod(at, M)
            cum = np.cumsum(f.weight[sl], -1)
            cum[:, -1] = 1.0
            cell = ri * cum.shape[1] + _pick_at(cum, draws.u_cell, ri, si)    # ri K + ci
            zs = draws.z[si]
            l00, l10, l11 = (v.ravel()[cell] for v in _chol2(f.cov2[sl]))
            m2 = f.mean2[sl].reshape(-1, 2)[cell]
            p0 = m2[..., 0] + l00 * zs[:, 0]                # path: l0; wiener: X_now
            p1 = m2[..., 1] + l10 * zs[:, 0] + l11 * zs[:, 1]   # path: a;  wiener: current rate
            b, kind, gn = (v[sl].ravel()[cell] for v in (f.b, f.kind, f.g_now))
            tn, th = t_now[sl][ri], thr[sl][ri]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                if f.model == "wiener":
                    sig, rq = (v[sl].ravel()[cell] for v in (f.sigma, f.rate_sd))
                    d = th - p0
                    # the rate's own random walk adds q dg^3 / 3 to the level variance at dg: each
                    # sample's smooth path X_now + rate dg + z sqrt(q / 3) dg^(3/2) (its rate kept
                    # from turning negative) holds it at every dg, and the diffusion sigma spreads
                    # the passage about that path's
                    mean = np.full(d.shape, np.inf)
                    need = (d > 0) & (p1 > 0)               # this model's samples still to cross
                    mean[need] = rate_walk_passage(d[need], p1[need], zs[need, 2], rq[need])
                    dg = np.where(sig > 0, inverse_gaussian(mean, d * d / (sig * sig), draws.z_ig[si],
                                                            draws.u_ig[si]), mean)
                    ok = (d > 0) & (p1 > 0) & np.isfinite(mean)
                    t_star = shape_g_inv(kind, np.where(ok, gn + dg, 0.0), b)
                    r = np.where(d <= 0, 0.0, np.where(ok, t_star - tn, np.inf))
                else:
                    level = p0 + p1 * gn
                    ok = (level < th) & (p1 > 0)
                    t_star = shape_g_inv(kind, np.where(ok, (th - p0) / p1, 0.0), b)
                    r = np.where(level >= th, 0.0, np.where(p1 > 0, t_star - tn, np.inf))
            rul.ravel()[at] = np.where(np.isfinite(r), np.maximum(r, 0.0), np.inf)
        out[sl] = rul * span[sl, None]
    return out


# ----------------------------------------------------------------------------- fleet prior
@dataclass(frozen=True)
class FleetPrior:
    """Lognormal prior on a fault's life from onset to threshold [h]."""
    mu_log: float
    sd_log: float
    members: int
    lives: tuple = ()          # (actuator, life [h], its sd of log life[, entry age h]) of the members
    min_members: int = 0
    entry_h: float = 0.0       # median age since onset [h] at which the members qualified (fleet.min_points)
    waiting: tuple = ()        # actuators whose fault wears but that have not qualified (yet)

    @property
    def unseen(self) -> float:
        """Share of the wearing actuators that are not members: the fleet the members' lives, each
        one that lasted ``entry_h``, may not stand for (0: every one qualified)."""
        return len(self.waiting) / (len(self.waiting) + self.members)

    def logpdf(self, life_h: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (np.log(life_h) - self.mu_log) / self.sd_log
            return np.where(np.isfinite(life_h) & (life_h > 0), -0.5 * z * z - np.log(life_h), -np.inf)

    def excluding(self, actuator: str) -> "FleetPrior | None":
        """The prior of the other members, for ``actuator`` (its own data must not count twice:
        once as a member, once as the data the prior weighs)."""
        if not any(m[0] == actuator for m in self.lives) and actuator not in self.waiting:
            return self
        return fleet_prior({**{m[0]: m[1:] for m in self.lives if m[0] != actuator},
                            **{a: (math.nan,) for a in self.waiting if a != actuator}}, self.min_members)


def fleet_prior(lives: dict[str, tuple[float, float]], min_members: int) -> FleetPrior | None:
    """Lognormal prior of a fault's life from its members' lives; None with fewer than ``min_members``.

    ``lives``: per member actuator, (life [h], sd of its log) -- a member's life is an estimate
    (:func:`life_estimate`), and a young member's is uncertain. The prior is the lognormal matched
    to the mixture of the members' lognormals: mu = mean(log L_j), sd^2 = var(log L_j) +
    mean(s_j^2), so members that know little of their own life make it wide instead of pulling
    every receiver to their (possibly biased) medians. Lives not finite or not > 0 are left out
    (an sd not finite counts as 0); they are the actuators whose fault wears but that have not
    qualified (``waiting``). A third value per member, its age since onset [h] when it qualified
    (:func:`life_estimate`), gives ``entry_h``, their median: the members had to last that long,
    and the more of the wearing fleet waits, the less they tell of lives shorter than it
    (:func:`apply_fleet_prior`).
    """
    ok = [(a, *map(float, v)) for a, v in lives.items() if np.isfinite(v[0]) and v[0] > 0]
    if len(ok) < min_members:
        return None
    waiting = tuple(a for a, v in lives.items() if not (np.isfinite(v[0]) and v[0] > 0))
    entries = [m[3] for m in ok if len(m) > 3 and np.isfinite(m[3])]
    lx = np.log([m[1] for m in ok])
    within = np.array([m[2] if np.isfinite(m[2]) else 0.0 for m in ok])
    between = float(lx.var(ddof=1)) if len(lx) > 1 else 0.0     # one member (min_members 1): its own spread
    sd = math.sqrt(between + float(np.mean(within ** 2)))
    return FleetPrior(float(lx.mean()), max(sd, 0.05), len(ok), tuple(ok), min_members,
                      float(np.median(entries)) if entries else 0.0, waiting)


def prior_weights(samples_h: np.ndarray, tau_now_h: np.ndarray, prior: FleetPrior) -> np.ndarray:
    """Importance weights of RUL samples [S, M] under the prior on tau_now + RUL."""
    lp = prior.logpdf(tau_now_h[:, None] + samples_h)
    top = np.max(lp, -1, keepdims=True)
    return np.exp(lp - np.where(np.isfinite(top), top, 0.0))


# ----------------------------------------------------------------------------- summaries
@dataclass
class FaultPrediction:
    """RUL distribution of one fault (or the overall one) of one actuator."""
    samples: np.ndarray | None          # [M] hours (inf: beyond horizon)
    weights: np.ndarray | None          # [M] or None (equal)
    model: str | None = None
    model_weights: dict = field(default_factory=dict)
    threshold: float | None = None
    n_tests: int = 0
    n_points: int = 0
    onset_h: float | None = None
    k_last: float | None = None
    std_last: float | None = None
    fleet_prior: bool = False
    unrecorded_repair_h: float | None = None          # K fell and stayed down here: the trend restarts [h]
    outliers_h: list = field(default_factory=list)   # tests set aside (scatter.isolated_outliers) [h]
    no_trend: bool = False                            # no degradation since the repair: no failure ahead
    last_off_trend: bool = False                      # the last test is off the trend (unconfirmed) ...
    without_last: "FaultPrediction | None" = None     # ... and the prediction without it ...
    last_gap_h: float = 0.0                           # ... whose RULs count from the test before [h]
    mixed_without: np.ndarray | None = None           # samples drawn from without_last (the even mixture)
    reason: str | None = None
    series: Series | None = None          # since the onset anchor (n_points, fleet life)
    candidates: list | None = None        # Series of every onset candidate (all post-repair points)
    candidate_onsets_h: list | None = None
    onset_weights: np.ndarray | None = None
    fits: list | None = None
    fit_index: int | None = None          # row of ``fits`` the trend is drawn from ...
    trend_candidate: int = 0              # ... and its onset candidate
    horizon_h: float = math.inf           # shortest prediction horizon of the samples (horizon_factor x span) [h]
    raw_samples: np.ndarray | None = None  # [M] before the horizon cut (few points since onset: for the fleet prior)
    usage_samples: np.ndarray | None = None  # [M] usage RUL where fitted on the usage clock (samples: hours) ...
    usage_weights: np.ndarray | None = None  # ... and its weights where they differ (the overall's)
    p95_shared: float | None = None       # overall: the p95 that holds where faults wear together [h] ...
    usage_p95_shared: float | None = None  # ... and in usage (dependence.py)
    shared_wear: list | None = None       # overall: groups of faults seen wearing together

    def quantiles(self) -> np.ndarray | None:
        """(p05, median, p95) of the RUL [h]; inf beyond the horizon."""
        if self.samples is None:
            return None
        if getattr(self, "_q", None) is None:
            self._q = weighted_quantiles(self.samples, self.weights, (0.05, 0.5, 0.95))
            if self.p95_shared is not None:
                self._q[2] = max(self._q[2], self.p95_shared)
        return self._q

    def usage_quantiles(self) -> np.ndarray | None:
        """(p05, median, p95) of the usage RUL where fitted on the usage clock, else None."""
        if self.usage_samples is None:
            return None
        w = self.weights if self.usage_weights is None else self.usage_weights
        q = weighted_quantiles(self.usage_samples, w, (0.05, 0.5, 0.95))
        if self.usage_p95_shared is not None:
            q[2] = max(q[2], self.usage_p95_shared)
        return q

    def p_fail(self, within_h: float) -> float | None:
        """P(RUL <= within_h), counting samples beyond the horizon as later: exact while
        ``within_h`` <= :attr:`horizon_h`, a lower bound beyond it (:meth:`p_fail_known`)."""
        if self.samples is None:
            return None
        w = self.weights if self.weights is not None else np.ones_like(self.samples)
        return float(np.sum(w * (self.samples <= within_h)) / np.sum(w))

    def p_fail_known(self, within_h: float) -> bool:
        """Whether :meth:`p_fail` is exact: no sample beyond a horizon shorter than ``within_h``."""
        return self.samples is None or within_h <= self.horizon_h or bool(np.all(np.isfinite(self.samples)))


def _num(v: float | None, nd: int = 1):
    """``v`` rounded to ``nd`` decimals, or to 4 significant digits where that is finer: nothing in
    the model fixes a time scale, and a test rig whose life is hours (tests every few minutes) must
    read its RUL as precisely as an aircraft's whose life is thousands of hours."""
    if v is None or not np.isfinite(v):
        return None
    v = float(v)
    if v != 0.0:
        nd = max(nd, 3 - int(np.floor(np.log10(abs(v)))))
    return round(v, nd)


def format_hours(v: float | None) -> str:
    """A time [h] for a table: whole hours from 100 h, 3 significant digits below; '-' for None."""
    if v is None:
        return "-"
    return f"{v:.0f}" if abs(v) >= 100.0 else f"{v:.3g}"


def summary(p: FaultPrediction, next_check_h: float, usage_per_h: float | None,
            clock: "UsageClock | None" = None) -> dict:
    """The F object of ``prognose --json``; ``clock``: ``p`` was fitted on the usage clock
    (:mod:`clock`): its samples are hours (:func:`to_hours`), ``usage_samples`` the usage RUL,
    its past times usage values."""
    q = p.quantiles()
    d = {"model": p.model, "rul_median_h": None, "rul_p05_h": None, "rul_p95_h": None,
         "p_fail_next": None, "threshold": _num(p.threshold, 4), "n_tests": p.n_tests}
    past = (lambda v: v) if clock is None else clock.to_hours   # a past test's clock value -> hours
    if q is not None:
        d["rul_p05_h"], d["rul_median_h"], d["rul_p95_h"] = (_num(v) for v in q)
        d["p_fail_next"] = round(p.p_fail(next_check_h), 4)
        if not p.p_fail_known(next_check_h):
            # samples beyond the horizon may fail before the check or after it: a lower bound only
            d["p_fail_next_min"], d["p_fail_next"] = d["p_fail_next"], None
        if p.usage_samples is not None:         # fitted on the usage: its own quantiles
            d["rul_p05_usage"], d["rul_median_usage"], d["rul_p95_usage"] = (_num(v, 2) for v in p.usage_quantiles())
        elif usage_per_h is not None:
            d["rul_p05_usage"], d["rul_median_usage"], d["rul_p95_usage"] = (
                _num(v * usage_per_h, 2) for v in q)
        beyond = [n for n, v in zip(("p05", "median", "p95"), q) if not np.isfinite(v)]
        if beyond and p.reason is None:
            p.reason = f"rul_{', rul_'.join(beyond)} beyond the prediction horizon (null)"
        if (q[1] == 0.0 and p.reason is None and p.k_last is not None and p.threshold is not None
                and p.k_last >= p.threshold):
            p.reason = f"K {p.k_last:.3f} at or beyond the threshold {p.threshold:.3f}: RUL 0"
    if p.model_weights:
        d["model_weights"] = {k: round(v, 3) for k, v in p.model_weights.items() if v > 0}
    d.update({"n_points": p.n_points, "onset_h": _num(None if p.onset_h is None else past(p.onset_h)),
              "k_last": _num(p.k_last, 4), "std_last": _num(p.std_last, 5), "fleet_prior": p.fleet_prior})
    if p.unrecorded_repair_h is not None:
        d["unrecorded_repair_h"] = _num(past(p.unrecorded_repair_h), 3)
    if p.outliers_h:
        d["outliers_h"] = [_num(past(t), 3) for t in p.outliers_h]
    if p.last_off_trend:
        d["last_test_off_trend"] = True
    if p.onset_weights is not None and len(p.onset_weights) > 1:
        # where the wear began: the onset candidates and their posterior weights
        d["onset_posterior"] = {f"{past(t):g}": round(float(w), 3)
                                for t, w in zip(p.candidate_onsets_h, p.onset_weights)}
    reasons = [p.reason] if p.reason else []
    if "p_fail_next_min" in d:
        reasons.append(f"the next check in {next_check_h:g} h lies beyond the prediction horizon "
                       f"({format_hours(p.horizon_h)} h): P(failure before it) >= {d['p_fail_next_min']:g}")
    if reasons:
        d["reason"] = "; ".join(reasons)
    return d


def _cdf_on(grid: np.ndarray, x: np.ndarray, w: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted empirical P(X <= T) and P(X < T) of samples ``x`` (inf: never) at ``grid`` T."""
    order = np.argsort(x)
    xs = x[order]
    ws = np.ones_like(xs) if w is None else w[order]
    cw = np.concatenate([[0.0], np.cumsum(ws)]) / ws.sum()
    return cw[np.searchsorted(xs, grid, "right")], cw[np.searchsorted(xs, grid, "left")]


def shared_wear(preds: dict[str, FaultPrediction], s: Settings) -> list[set]:
    """Groups of an actuator's faults whose wear is seen moving together
    (:func:`dependence.shared_groups` on each fault's series since its onset, at
    ``prognosis.shared_wear_alpha``; 0: none)."""
    from .dependence import shared_groups
    alpha = s.prognosis.shared_wear_alpha
    series = {f: (p.onset_h + p.series.tau_h, p.series.y) for f, p in preds.items()
              if p.samples is not None and p.series is not None and p.onset_h is not None}
    if alpha <= 0 or len(series) < 2:
        return []
    return shared_groups(series, alpha)[0]


def overall(preds: dict[str, FaultPrediction], n_tests: int, groups: list[set] | None = None) -> FaultPrediction:
    """First fault to reach its threshold, faults independent: P(R <= t) = 1 - prod_f (1 - F_f(t)).

    ``groups``: faults seen wearing together (:func:`shared_wear`). Independence stays the
    median and P(failure before the next check) -- the earliest, conservative, answer under any
    positive dependence --, and the 95 % quantile becomes that of each group taken comonotone,
    P(R <= t) = 1 - prod_groups (1 - max_(f in group) F_f(t)): the latest first crossing any
    positive dependence within the groups allows (:mod:`dependence`), so the interval holds
    whatever their dependence is.

    Computed from each fault's weighted empirical CDF F_f, not by pairing samples: a fault on
    the fleet prior carries importance weights, and the product of two such weight sets has
    almost no effective samples (a few draws would set the overall quantiles). The overall
    "samples" are every finite sample time T of any fault, weighted by the mass of P(R <= T),
    and inf with the rest: each of its quantiles is at most the same quantile of every fault. ``p_first[f]`` = P(f is first) =
    sum_T P(R_f = T) prod_(g before f) P(R_g > T) prod_(g after f) P(R_g >= T) (a tie goes to the
    fault named first).
    """
    have = {f: p for f, p in preds.items() if p.samples is not None}
    if not have:
        reasons = "; ".join(f"{f}: {p.reason}" for f, p in preds.items())
        return FaultPrediction(None, None, None, n_tests=n_tests, reason=f"no fault has a RUL ({reasons})")
    fin = np.concatenate([p.samples[np.isfinite(p.samples)] for p in have.values()])
    grid = np.unique(fin)
    le, lt = zip(*(_cdf_on(grid, p.samples, p.weights) for p in have.values()))
    le, lt = np.array(le).reshape(len(have), -1), np.array(lt).reshape(len(have), -1)   # [F, T]
    cdf = 1.0 - np.prod(1.0 - le, 0)
    p95_shared = None
    groups = [g & set(have) for g in groups or ()]
    groups = [g for g in groups if len(g) > 1]
    if groups:
        names = list(have)
        rows = [le[[names.index(f) for f in g]].max(0) for g in groups]
        rows += [le[i] for i, f in enumerate(names) if not any(f in g for g in groups)]
        hit = np.nonzero(1.0 - np.prod(1.0 - np.array(rows), 0) >= 0.95 - 1e-12)[0]
        p95_shared = float(grid[hit[0]]) if len(hit) else math.inf
    beyond = 1.0 - (cdf[-1] if len(cdf) else 0.0)             # no fault within the horizon
    mass = np.diff(cdf, prepend=0.0)
    if beyond > 1e-12 or not len(grid):   # an atom at inf only where some mass lies beyond the horizon
        grid, mass = np.append(grid, np.inf), np.append(mass, beyond)
    out = FaultPrediction(grid, np.maximum(mass, 0.0), "first-to-threshold", n_tests=n_tests)
    out.p95_shared = p95_shared
    out.shared_wear = [sorted(g) for g in groups] or None
    out.horizon_h = min(p.horizon_h for p in have.values())
    out.fleet_prior = any(p.fleet_prior for p in have.values())     # it is built from that fault's samples
    p_first = {}
    for a, f in enumerate(have):
        at = le[a] - lt[a]                                     # P(R_f = T)
        later = np.prod(1.0 - le[:a], 0) * np.prod(1.0 - lt[a + 1:], 0)
        p_first[f] = float(np.sum(at * later))
    out.model_weights = {}
    out.p_first = p_first
    dom = max(p_first, key=p_first.get) if any(p_first.values()) else min(
        have, key=lambda f: np.nanmedian(np.where(np.isfinite(have[f].samples), have[f].samples, np.nan)) if
        np.isfinite(have[f].samples).any() else np.inf)
    out.dominant = dom
    out.threshold = have[dom].threshold
    missing = [f for f in preds if f not in have]
    if missing:
        out.note = "without " + ", ".join(missing) + " (no RUL: " + "; ".join(
            f"{f}: {preds[f].reason}" for f in missing) + ")"
    return out


# ----------------------------------------------------------------------------- per-fault preparation
class _Find(enum.Enum):
    FALL = "find"


#: :func:`prepare_fault`'s default ``fall``: look for it (None is an answer: no fall)
FIND = _Find.FALL


def prepare_fault(time_h: np.ndarray, k: np.ndarray, std: np.ndarray, threshold: float, n_tests: int,
                  s: Settings, check_last: bool = True, repaired: bool = True,
                  fall: int | None | Literal[_Find.FALL] = FIND, outliers: tuple | None = None) -> tuple[FaultPrediction, Series | None]:
    """Degradation segment of one fault's post-repair tests, or the reason there is none
    (``repaired``: whether a maintenance restarted the trend, for the wording of the reason;
    ``fall`` and ``outliers``: :func:`scatter.last_persistent_fall` of these tests and
    :func:`scatter.isolated_outliers` of those from the fall on, where the caller has them).

    A fall of K that persists is a repair the history does not hold: the trend restarts there
    (:func:`scatter.last_persistent_fall`, ``unrecorded_repair_h``). Tests far off their
    neighbours are set aside (:func:`scatter.isolated_outliers`). A last test off the trend cannot
    be told from wear that jumped until the next test: the prediction without it is prepared too
    (``without_last``), and :func:`predict_series` mixes the two evenly.
    """
    p = FaultPrediction(None, None, threshold=threshold, n_tests=n_tests)
    if n_tests:
        p.k_last, p.std_last = float(k[-1]), float(std[-1])
    std = np.maximum(std, s.prognosis.min_std)     # no diagnosis is exact; a zero variance is singular
    if fall is FIND:
        fall = last_persistent_fall(time_h, k, std, s.prognosis.outlier_sigma, s.prognosis.repair_fall)
    repaired = repaired or fall is not None
    since = "since the last repair" if repaired else "in the history (no repair recorded)"
    if fall is not None:
        p.unrecorded_repair_h = float(time_h[fall])
        time_h, k, std = time_h[fall:], k[fall:], std[fall:]
        n_tests = p.n_tests = len(k)
    first_off = first_above_the_rest(k, std, s.prognosis.outlier_sigma, s.prognosis.repair_fall)
    if first_off:
        # wear does not heal: the test that found the wear, recorded at the repair's time (the
        # trend restarts at or after it), or a failed diagnosis. Kept, it was the new unit's
        # baseline and hid its wear (an independent probe); set aside and named
        p.outliers_h = [float(time_h[0])]
        time_h, k, std = time_h[1:], k[1:], std[1:]
        n_tests = len(k)
        outliers = None      # the caller's were judged with it
    if n_tests < s.prognosis.min_tests:
        p.reason = f"only {n_tests} test(s) {since} (fewer than {s.prognosis.min_tests}): no RUL"
        return p, None
    off, last = outliers or isolated_outliers(time_h, k, std, s.prognosis.outlier_sigma, s.prognosis.outlier_min_jump)
    if last and check_last:
        p.last_off_trend = True
        p.last_gap_h = float(time_h[-1] - time_h[-2])
        p.without_last = prepare_fault(time_h[:-1], k[:-1], std[:-1], threshold, n_tests - 1, s, False, repaired)[0]
        # the tests before it are judged among themselves: beside a failed last diagnosis, the
        # good test before it lay off the line through it and was set aside (an independent probe)
        off = np.r_[isolated_outliers(time_h[:-1], k[:-1], std[:-1], s.prognosis.outlier_sigma,
                                      s.prognosis.outlier_min_jump)[0], False]
    if off.any():
        # a failed or disturbed diagnosis: set aside, named in the output
        p.outliers_h += [float(t) for t in time_h[off]]
        time_h, k, std = time_h[~off], k[~off], std[~off]
    # a rise only the last test shows is judged as a test off its neighbours is (outlier_sigma)
    last_sigma = max(s.prognosis.onset_sigma, s.prognosis.outlier_sigma)
    anchor = degradation_segment(time_h, k, std, s.prognosis.onset_sigma, s.prognosis.onset_delta, last_sigma)
    if anchor is not None and anchor >= 4:
        # the tests before the rise show the diagnosis scatter; where it exceeds the stated errors
        # (understated), a rise of a few stated sd is noise: judge the onset by the larger one
        est = noise_estimate(k[:anchor + 1])
        if est > 1.5 * float(np.median(std[:anchor + 1])):   # beyond what a few points make of a right one
            anchor = degradation_segment(time_h, k, np.maximum(std, est), s.prognosis.onset_sigma,
                                         s.prognosis.onset_delta, last_sigma)
    pooled = anchor is None and s.prognosis.onset_chi2 > 0
    if pooled:
        # no single test clears the first one: the rise of the tests as a whole
        anchor = rise_onset(time_h, k, std, s.prognosis.onset_chi2)
    if anchor is None:
        if k[-1] >= threshold:
            p.reason = f"K {k[-1]:.3f} at or beyond the threshold {threshold:.3f} with no trend: RUL 0"
            p.samples = np.zeros(s.prognosis.samples)   # as many as a fault with a RUL: overall takes the minimum per sample
            return p, None
        p.reason = (f"no degradation {since}: K {k[-1]:.4f} +- {p.std_last:.4f} "
                    f"(threshold {threshold:.3f}), no trend to extrapolate")
        p.no_trend = True
        return p, None
    p.onset_h = float(time_h[anchor])
    p.n_points = len(k) - anchor
    if p.n_points < 3 and not (anchor > 0 and s.prognosis.onset_candidates > 1):
        # the models' evidence is proper from 3 points; onset candidates fit every post-repair
        # point (>= min_tests), so there a rise that shows at one test is enough
        p.reason = (f"degradation onset after {time_h[anchor]:g} h: only {p.n_points} points since then "
                    f"(fewer than 3): no RUL")
        return p, None
    tau = time_h[anchor:] - time_h[anchor]
    ser = Series(tau, k[anchor:], std[anchor:], float(tau[-1]))
    p.series = ser
    p.candidates, p.candidate_onsets_h = [ser], [p.onset_h]
    if anchor > 0 and s.prognosis.onset_candidates > 1:
        # the anchor is where the rise shows above the noise, not where it began: a convex path
        # starts long before.  Onsets from the first post-repair test to the anchor, each fitted to
        # every post-repair point (g = 0 before its onset, so the same data and comparable
        # evidence), are weighed by the evidence (uniform prior over the candidates).
        js = np.round(np.linspace(0, anchor, s.prognosis.onset_candidates)).astype(int)
        if s.prognosis.onset_candidates > 2 and not pooled:     # pooled, the anchor is the hinge
            # and where a straight rise from a level fits best (the hinge of rise_onset): a rise
            # shows a test or two after it began, between the even grid's candidates, and from
            # the one before a convex shape took the kink and extrapolated it (medians 0.36x the
            # truth and false WARNs on young linear wear: an independent probe)
            hinge = rise_onset(time_h, k, std, 0.0)
            js = js if hinge is None else np.r_[js, min(hinge, anchor)]
        js = np.unique(js)
        p.candidates = [Series(time_h - time_h[j], k, std, float(time_h[-1] - time_h[j])) for j in js]
        p.candidate_onsets_h = [float(time_h[j]) for j in js]
    return p, ser


def predict_series(preds: list[FaultPrediction], thresholds: np.ndarray, fault_index: int, s: Settings) -> None:
    """Fit and sample every prepared series of one fault (in place).

    Each prediction's onset candidates are fitted in one batch; its weights over (onset, model)
    come from the criteria of all its candidates at once (the same data), and every sample
    draws its onset, then its model within that onset, from them.
    """
    alts = [(i, p.without_last) for i, p in enumerate(preds) if p.without_last is not None]
    if alts:
        predict_series([a for _, a in alts], np.array([thresholds[i] for i, _ in alts]), fault_index, s)
    _predict_prepared(preds, thresholds, fault_index, s)
    u_last = Draws.make(s.prognosis.seed, fault_index, s.prognosis.samples).u_last
    for i, a in alts:
        p = preds[i]
        without, raw_without = _from_last_test(a, p.last_gap_h)
        if without is None and a.no_trend and p.samples is not None:
            without = np.full(len(p.samples), np.inf)     # without the last test, no wear: no failure ahead
        if p.samples is None and p.no_trend and without is not None:
            # the reverse: the last test says no wear (a reading near the first tests'), the tests
            # before it a trend. Taken at its word it hid the trend whole: no RUL, P(fail) 0 on a
            # unit near its threshold (an independent probe). The fit is the one without it; the
            # future with it has no failure ahead.
            p = preds[i] = dataclasses.replace(
                a, n_tests=p.n_tests, k_last=p.k_last, std_last=p.std_last, last_off_trend=True,
                last_gap_h=p.last_gap_h, without_last=a, samples=np.full(len(without), np.inf),
                raw_samples=None if raw_without is None else np.full(len(without), np.inf),
                horizon_h=a.horizon_h - p.last_gap_h)
        if p.samples is not None and without is not None and len(p.samples) == len(without) == len(u_last):
            # an even mixture: with the last test (wear jumped) or without it (a failed diagnosis)
            p.mixed_without = u_last < 0.5
            p.samples = np.where(p.mixed_without, without, p.samples)
            p.horizon_h = min(p.horizon_h, a.horizon_h - p.last_gap_h)
            if p.raw_samples is not None:
                p.raw_samples = np.where(p.mixed_without, without if raw_without is None else raw_without,
                                         p.raw_samples)


def _from_last_test(a: FaultPrediction, gap_h: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """RUL samples (and raw samples) of the prediction without the last test, counted from the
    last test instead of the one before it: R - gap [h], at least 0 (a failure the tests before
    it put between the two is one that may have happened; the probe found them counted from the
    earlier test, up to 108 h past a failure the trend put before the last test)."""
    shift = (lambda x: None if x is None else np.maximum(x - gap_h, 0.0))
    return shift(a.samples), shift(a.raw_samples)


def _predict_prepared(preds: list[FaultPrediction], thresholds: np.ndarray, fault_index: int, s: Settings) -> None:
    idx = [i for i, p in enumerate(preds) if p.series is not None]
    if not idx:
        return
    series, owner = [], []
    for j, i in enumerate(idx):
        p = preds[i]
        if p.candidates is None:          # a series set by hand: its own onset only
            p.candidates, p.candidate_onsets_h = [p.series], [p.onset_h]
        series += p.candidates
        owner += [j] * len(p.candidates)
    owner = np.asarray(owner)
    models = s.models_for(FAULTS[fault_index])
    fits, crit = fit_models(series, models)
    draws = Draws.make(s.prognosis.seed, fault_index, s.prognosis.samples)
    within = np.zeros_like(crit)
    joint = []
    for j in range(len(idx)):
        rows = np.nonzero(owner == j)[0]
        w = akaike_weights(crit[rows].ravel(), models.aic_delta_max).reshape(len(rows), -1)
        wc = w.sum(1)
        within[rows] = np.divide(w, wc[:, None], out=np.full_like(w, 1.0 / w.shape[1]), where=wc[:, None] > 0)
        joint.append((rows, w, wc))
    thr = np.array([thresholds[idx[j]] for j in owner])
    raw = sample_rul(series, fits, within, thr, draws)
    span = np.array([c.span_h for c in series])
    samples = np.where(raw > s.prognosis.horizon_factor * span[:, None], np.inf, raw)
    names = [f.model for f in fits]
    for j, i in enumerate(idx):
        p = preds[i]
        rows, w, wc = joint[j]
        pick = (rows[0], slice(None)) if len(rows) == 1 else (
            rows[_pick(np.cumsum(wc)[None, :] / max(wc.sum(), 1e-300), draws.u_onset)[0]],   # onset per sample
            np.arange(samples.shape[1]))
        p.samples = samples[pick]
        if takes_prior(p, s):
            # kept for the fleet prior, which knows lives beyond the data's horizon (apply_fleet_prior)
            p.raw_samples = raw[pick]
        p.horizon_h = s.prognosis.horizon_factor * min(c.span_h for c in p.candidates)
        mw = w.sum(0)
        p.model_weights = dict(zip(names, map(float, mw)))
        best = int(np.argmax(mw))
        p.model = names[best]
        p.onset_weights = wc
        c = int(np.argmax(w[:, best]))
        p.fits, p.fit_index, p.trend_candidate = fits, int(rows[c]), c


def takes_prior(p: FaultPrediction, s: Settings) -> bool:
    """Whether a prediction has a RUL from fewer than ``fleet.use_below_points`` points since onset:
    the only case the fleet prior weighs."""
    return p.samples is not None and p.series is not None and p.n_points < s.fleet.use_below_points


def apply_fleet_prior(p: FaultPrediction, prior: FleetPrior | None, s: Settings, actuator: str | None = None) -> None:
    """Importance-weight the samples of an actuator with few points since onset by the fleet prior
    (of the other members, where ``actuator`` is one)."""
    if prior is None or not takes_prior(p, s):
        return
    if actuator is not None:
        prior = prior.excluding(actuator)
        if prior is None:
            return
    # the samples before the horizon cut: the prior knows lives beyond the data's horizon, and a
    # cut sample (inf) has no life to weigh -- cut, a young unit's posterior ended at 20 data spans
    tau = float(p.series.tau_h[-1])
    base = p.raw_samples if p.raw_samples is not None else p.samples
    w = prior_weights(base[None, :], np.array([tau]), prior)[0]
    # the even mixture with and without an unconfirmed last test: the prior weighs the lives
    # within each future and each keeps its half (weighed as one, the "no wear without it"
    # half has no finite life and vanished: P(failure) 0.5 became 1 beside a fleet)
    halves = None if p.mixed_without is None else (p.mixed_without, ~p.mixed_without)
    for half in halves or ():
        _keep_share(w, half)
    # the members qualified by lasting prior.entry_h since onset: of the lives shorter than that
    # they tell nothing the actuators still waiting to qualify could not belie. In the share of the
    # wearing fleet that waits (``unseen``), a life shorter keeps the weight of the unit's own data
    # and the prior shares out the rest. (Tests 300 h apart made members of the long lives alone, 35
    # of 40 units waiting, and the prior moved the short ones 2x late: 14 of 65 failed before their
    # 5 % quantile; an independent probe, 2026-12-07.)
    short = tau + base < prior.entry_h
    if prior.unseen > 0 and short.any():
        own = w.copy()
        for half in halves or (np.ones(len(w), bool),):
            own[half & short] = 1.0
            _keep_share(own, half & ~short)
            if halves is None:
                _keep_share(w, half)
        w = (1.0 - prior.unseen) * w + prior.unseen * own
    ess = w.sum() ** 2 / max(np.sum(w * w), 1e-300) if w.sum() > 0 else 0.0
    if ess >= 50:
        # the horizon reaches the prior's 99.9 % life (beyond it, samples count as later)
        p.horizon_h = max(p.horizon_h, math.exp(prior.mu_log + 3.09 * prior.sd_log) - tau)
        p.samples = np.where(base > p.horizon_h, np.inf, base)
        p.weights, p.fleet_prior, p._q = w, True, None
    else:
        p.reason = f"fleet prior not applied: it conflicts with the data (effective samples {ess:.0f})"


def _keep_share(w: np.ndarray, part: np.ndarray) -> None:
    """Scale the weights ``w`` of ``part`` (a mask) in place to sum to its size: the prior moves
    weight within the part, not into or out of it (all 1 where the prior gives the part none)."""
    tot = w[part].sum()
    w[part] = w[part] * (part.sum() / tot) if tot > 0 else 1.0


def life_estimate(p: FaultPrediction, min_points: int = 1) -> tuple[float, float, float]:
    """(life [h], sd of its log, entry age [h]) that a fleet member contributes: L = tau_now + median
    RUL; (log L - log(tau_now + p05 RUL)) / 1.645 (the lower side: the upper may lie beyond the
    horizon); and tau at its ``min_points``-th point since onset, the age it had to reach to count."""
    if p.samples is None or p.series is None:
        return math.nan, math.nan, math.nan
    p05, med = p.quantiles()[:2]      # the summary's own (each quantile is computed alone): sorted once
    tau = float(p.series.tau_h[-1])
    if not np.isfinite(med) or tau + med <= 0:
        return math.nan, math.nan, math.nan
    lo = tau + p05
    entry = float(p.series.tau_h[min(max(min_points, 1), len(p.series.tau_h)) - 1])
    return float(tau + med), (float(math.log((tau + med) / lo) / 1.645) if lo > 0 else math.nan), entry


# ----------------------------------------------------------------------------- prognose
def to_hours(p: FaultPrediction, clock: "UsageClock", s: Settings) -> None:
    """A prediction fitted on the usage clock, its samples made hours (:meth:`clock.UsageClock.hours`;
    the usage RUL kept as ``usage_samples``) and its horizon hours at the usage rate."""
    from .clock import usage_draws
    if p.samples is None:
        return
    zr, z, u = usage_draws(s.prognosis.seed, len(p.samples))
    p.usage_samples, p.samples = p.samples, clock.hours(p.samples, zr, z, u)
    p.horizon_h = p.horizon_h / clock.rate
    p._q = None


def _predict_fault(hist, ids: list[str], fi: int, thr: float, s: Settings) -> list[FaultPrediction]:
    """Predictions of fault ``fi`` for actuators ``ids`` from the tests since its last repair."""
    f = FAULTS[fi]
    plist = []
    hs = [hist.actuators[a] for a in ids]
    sinces = [h.since_repair(f) for h in hs]
    # every actuator's unrecorded repair and tests off their neighbours at once (scatter.by_length:
    # the series of equal length judged together), as prepare_fault would find them one by one
    tests = [(h.time_h[i], h.k[i, fi], np.maximum(h.std[i, fi], s.prognosis.min_std)) for h, i in zip(hs, sinces)]
    falls = last_persistent_falls(tests, s.prognosis.outlier_sigma, s.prognosis.repair_fall)
    offs = isolated_outliers_of([x if at is None else tuple(v[at:] for v in x) for x, at in zip(tests, falls)],
                                s.prognosis.outlier_sigma, s.prognosis.outlier_min_jump)
    for h, since, fall, off in zip(hs, sinces, falls, offs):
        # a maintenance at or before the first test also restarts it (the usage clock's history
        # starts at the new unit's first test: "no repair recorded" was said of a replaced unit)
        p, _ = prepare_fault(h.time_h[since], h.k[since, fi], h.std[since, fi], thr, int(since.sum()), s,
                             repaired=not since.all() or trend_start_h(h.repairs, f) is not None,
                             fall=fall, outliers=off)
        plist.append(p)
    predict_series(plist, np.full(len(plist), thr), fi, s)
    return plist


def _predict_faults(hist, ids: list[str], thr: dict[str, float], s: Settings) -> dict[str, list[FaultPrediction]]:
    """:func:`_predict_fault` of every fault for ``ids``, on up to ``os.cpu_count()`` threads.

    Each actuator's prediction of a fault depends on its own data and the fault's common random
    numbers only (the batches of :mod:`prior_cache` rely on it too), so the (fault, part of
    ``ids``) tasks share no mutable state and give the serial result to the last bit, put back
    in order. The heavy parts (numpy on large arrays, the nogil numba kernels) release the GIL;
    the per-series Python of :func:`prepare_fault` does not. On 2 cores a free second core took
    a 1000-actuator prognosis from 22-24 s to 18 s; held by another job, it cost 2 s (24 -> 26 s).
    Each fault's ids are split in as many parts as there are workers, so that three faults keep
    two cores equally busy."""
    workers = min(len(FAULTS) * 2, os.cpu_count() or 1)
    if workers < 2 or len(ids) < 2 * PARALLEL_MIN:
        return {f: _predict_fault(hist, ids, fi, thr[f], s) for fi, f in enumerate(FAULTS)}
    parts = min(workers, len(ids) // PARALLEL_MIN)
    cuts = [ids[i * len(ids) // parts:(i + 1) * len(ids) // parts] for i in range(parts)]
    with ThreadPoolExecutor(workers) as ex:
        futs = {f: [ex.submit(_predict_fault, hist, part, fi, thr[f], s) for part in cuts]
                for fi, f in enumerate(FAULTS)}
        return {f: [p for fut in fs for p in fut.result()] for f, fs in futs.items()}


def member_lives(ids: list[str], plist: list[FaultPrediction], s: Settings) -> dict[str, tuple[float, float, float]]:
    """(life [h], sd of its log, entry age [h]) of each actuator of ``ids`` whose fault wears: of a
    member of the fleet prior, with at least ``fleet.min_points`` points since onset
    (:func:`life_estimate`); NaN of one still waiting to qualify."""
    return {a: life_estimate(p, s.fleet.min_points) if p.n_points >= s.fleet.min_points else (math.nan,) * 3
            for a, p in zip(ids, plist) if p.series is not None}


def _prior_of(ids: list[str], plist: list[FaultPrediction], s: Settings) -> FleetPrior | None:
    """Fleet prior from the members with enough points since onset."""
    return fleet_prior(member_lives(ids, plist, s), s.fleet.min_members)


def fleet_priors(history, settings: Settings | None = None,
                 thresholds: dict[str, float] | None = None) -> dict[str, FleetPrior | None]:
    """The fleet prior of each fault from every actuator of a history (what :func:`prognose` applies).

    Fitting the whole fleet is the expensive part of a one-actuator prognosis: a caller that
    prognoses one actuator after each test (the monitor) keeps a
    :class:`prior_cache.FleetPriorCache`, which refits only the actuators that changed, and
    passes its priors as ``prognose(..., priors=)``.
    """
    return FleetPriorCache(settings, thresholds).priors(history)


#: F fields of a fault that the overall F does not carry
_FAULT_ONLY = ("n_points", "onset_h", "k_last", "std_last", "onset_posterior")


def prognose(history, actuator: str | None = None, next_check_h: float | None = None,
             settings: Settings | None = None, thresholds: dict[str, float] | None = None,
             details: bool = False, priors: dict[str, FleetPrior | None] | None = None):
    """RUL per fault and overall of every actuator (or one) of a history: the ``prognose --json`` object.

    ``history``: a :class:`records.History`, a :class:`store.HistoryStore`, or a path to a SQLite
    history or a HISTORY.csv. Returns ``{"actuators": {ID: {"faults": {"gm": F, "fsj": F, "bkl": F},
    "overall": F}}}``; F has ``model``, ``rul_median_h``, ``rul_p05_h``, ``rul_p95_h``,
    ``p_fail_next``, ``threshold``, ``n_tests`` (null RUL with a ``reason`` where none can be
    given; overall also ``dominant_fault``). With ``details=True`` returns ``(object,
    {actuator: {fault|'overall': FaultPrediction}})`` for plots. ``priors`` (from
    :func:`fleet_priors`, or a :class:`prior_cache.FleetPriorCache`, asked only where a fault of
    ``actuator`` takes the prior) with ``actuator``: only that actuator is fitted. Raises
    :class:`PrognosticsError`.
    """
    from .clock import on_usage_clock
    from .store import as_history
    s = settings or load_settings()
    hist = as_history(history, s)
    nc = s.prognosis.next_check_h if next_check_h is None else float(next_check_h)
    if not (math.isfinite(nc) and nc > 0):
        raise PrognosticsError(f"next-check interval must be a positive number of hours, got {next_check_h!r}")
    if not hist.actuators:
        raise PrognosticsError("the history is empty: no tests to prognose")
    if actuator is not None and actuator not in hist.actuators:
        known = ", ".join(sorted(hist.actuators)[:10])
        raise PrognosticsError(f"unknown actuator {actuator!r} (the history has: {known}"
                               f"{', ...' if len(hist.actuators) > 10 else ''})")
    thr = thresholds or threshold_values(s)
    ids = [actuator] if actuator is not None else sorted(hist.actuators)
    clocks: dict = {}
    refused: dict = {}
    if s.prognosis.clock == "usage":     # wear against the usage; hours from each unit's usage rate
        raw = hist
        # one actuator asked for must be on the clock; of a fleet, one that is not gets no RUL
        hist, clocks, refused = on_usage_clock(hist, required=set(ids) if actuator is not None else ())
        ids = [a for a in ids if a not in refused]
        if not ids:
            first = next(iter(refused.values()))
            raise PrognosticsError(first if len(refused) == 1 else
                                   f"none of the {len(refused)} actuators can be put on the usage clock; {first}")
    plists = _predict_faults(hist, ids, thr, s)
    if priors is None or isinstance(priors, FleetPriorCache):
        # fleet prior from the members (enough points), applied to the actuators with few points;
        # one actuator's needs the whole fleet fitted, and only when a fault of it takes the prior
        if actuator is None and priors is None:
            priors = {f: _prior_of(ids, plists[f], s) for f in FAULTS}
        elif actuator is None or any(takes_prior(p, s) for pl in plists.values() for p in pl):
            priors = (priors or FleetPriorCache(s, thr)).on_clock(hist)
        else:
            priors = {}
    preds: dict[str, dict[str, FaultPrediction]] = {a: {} for a in ids}
    for f in FAULTS:
        for a, p in zip(ids, plists[f]):
            preds[a][f] = p
            apply_fleet_prior(p, priors.get(f), s, a)
            if a in clocks:
                to_hours(p, clocks[a], s)
    out = {}
    detail = {}
    for a in ids:
        if actuator is not None and a != actuator:
            continue
        h = hist.actuators[a]
        rate = clocks[a].rate if a in clocks else h.usage_per_hour()
        faults = {f: summary(preds[a][f], nc, rate, clocks.get(a)) for f in FAULTS}
        groups = shared_wear(preds[a], s)
        # the tests the overall rests on: the longest current trend of a fault (a test before a
        # repair of every fault counts for none; the same on both clocks)
        n_ov = max(p.n_tests for p in preds[a].values())
        ov = overall(preds[a], n_ov, groups)
        if a in clocks and ov.samples is not None:     # the first fault to use its usage up
            ovu = overall({f: dataclasses.replace(p, samples=p.usage_samples) for f, p in preds[a].items()},
                          n_ov, groups)
            ov.usage_samples, ov.usage_weights, ov.usage_p95_shared = ovu.samples, ovu.weights, ovu.p95_shared
        o = summary(ov, nc, rate, clocks.get(a))
        o["dominant_fault"] = getattr(ov, "dominant", None)
        if hasattr(ov, "p_first"):
            o["p_first"] = {f: round(v, 4) for f, v in ov.p_first.items()}
        if getattr(ov, "note", None):
            o["note"] = ov.note
        if ov.shared_wear:
            o["shared_wear"] = ov.shared_wear
        for key in _FAULT_ONLY:
            o.pop(key, None)
        if clocks:
            o["clock"] = "usage"
        out[a] = {"faults": faults, "overall": o}
        detail[a] = {**preds[a], "overall": ov, "history": h}
    for a, why in refused.items():              # no usage to put it on the clock: said, no RUL
        if actuator is not None and a != actuator:
            continue                            # one actuator asked for: its answer alone
        n = len(raw.actuators[a].time_h)
        out[a] = {"faults": {f: summary(FaultPrediction(None, None, threshold=thr[f], n_tests=n, reason=why), nc, None)
                             for f in FAULTS},
                  "overall": {**summary(FaultPrediction(None, None, n_tests=n, reason=why), nc, None),
                              "dominant_fault": None, "clock": "usage"}}
        for key in _FAULT_ONLY:
            out[a]["overall"].pop(key, None)
    obj = {"actuators": dict(sorted(out.items()))}
    return (obj, detail) if details else obj


# ----------------------------------------------------------------------------- plot
def trend_band(p: FaultPrediction, tau_h: np.ndarray, z: float = 1.645) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean path and +-z sd band [K] of the most probable model's best cell at hours ``tau_h``
    since onset (Wiener, from the last test on: X_now + rate dg, Var + sigma^2 dg + q dg^3 / 3)."""
    f = p.fits[int(np.argmax([p.model_weights.get(ff.model, 0.0) for ff in p.fits]))]
    j = p.fit_index
    m, P = f.mean[j, 0], f.cov[j, 0]
    kind, b = f.kind[j, 0], f.b[j, 0]
    g = shape_g(kind, np.asarray(tau_h, float) / p.candidates[p.trend_candidate].span_h, b)
    if f.model == "wiener":
        gn = f.g_now[j, 0]
        dg = np.maximum(g - gn, 0.0)
        H = np.stack([np.ones_like(g), g, np.ones_like(g), dg], -1)
        mean = H @ m
        var = np.einsum("ni,ij,nj->n", H, P, H) + f.sigma[j, 0] ** 2 * dg + f.rate_sd[j, 0] ** 2 * dg ** 3 / 3
    else:
        H = np.stack([np.ones_like(g), g], -1)
        mean = H @ m[:2]
        var = np.einsum("ni,ij,nj->n", H, P[:2, :2], H)
    sd = np.sqrt(np.maximum(var, 0.0))
    mean = np.where(np.isfinite(mean), mean, np.nan)     # a hyperbolic path is unbounded past its blow-up
    return mean, mean - z * sd, mean + z * sd


def plot_prognosis(history, path, actuator: str | None = None, next_check_h: float | None = None,
                   settings: Settings | None = None) -> dict:
    """PNG of one actuator's prognosis (``prognose --plot FILE.png``); returns the prognose object.

    Per fault: the tests with 1-sd error bars, the fitted trend and its 90 % band, the
    threshold, the onset candidates shaded by their posterior weight, and the RUL distribution
    (histogram of the Monte Carlo samples, on the time axis from the last test). ``actuator``
    defaults to the first of the history.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from .store import as_history
    s = settings or load_settings()
    hist = as_history(history, s)
    if actuator is None:
        if not hist.actuators:
            raise PrognosticsError("the history is empty: no tests to prognose")
        actuator = sorted(hist.actuators)[0]
    obj, detail = prognose(hist, actuator, next_check_h, settings=s, details=True)
    d = detail[actuator]
    h = d["history"]                      # on the clock of the fit: hours, or usage
    unit = "usage" if s.prognosis.clock == "usage" else "h"
    # an id of any length is legal; in a title a long one would push the RUL out of sight
    name = actuator if len(actuator) <= 40 else actuator[:37] + "..."
    fig, axes = plt.subplots(3, 1, figsize=(9, 10), sharex=True)
    for ax, (fi, f) in zip(axes, enumerate(FAULTS)):
        p = d[f]
        ax.errorbar(h.time_h, h.k[:, fi], yerr=h.std[:, fi], fmt="o", ms=3, color="k", label="diagnoses (1 sd)")
        for t, ff, *_ in h.repairs:
            if ff in (f, "all"):
                ax.axvline(t, color="C2", ls=":", lw=1)
        if p.unrecorded_repair_h is not None:
            ax.axvline(p.unrecorded_repair_h, color="C2", ls="--", lw=1, label="unrecorded repair (K fell for good)")
        if p.outliers_h:
            out = np.isin(h.time_h, p.outliers_h)
            ax.plot(h.time_h[out], h.k[out, fi], "x", ms=9, color="C3", label="set aside (off its neighbours)")
        if p.threshold is not None:
            ax.axhline(p.threshold, color="C3", lw=1, label=f"threshold {p.threshold:.3f}")
        q = p.quantiles()
        # on the usage clock the axis is the usage: its RUL samples, not the hours
        ruls = p.samples if p.usage_samples is None else p.usage_samples
        qa = q if p.usage_samples is None else p.usage_quantiles()
        if p.series is not None and q is not None and p.fits is not None:
            cs, t0 = p.candidates[p.trend_candidate], p.candidate_onsets_h[p.trend_candidate]
            end = cs.tau_h[-1] + (qa[2] if np.isfinite(qa[2]) else 2 * cs.span_h)
            wiener = p.model == "wiener"     # its past is the data; its trend starts at the last test
            tau = np.linspace(cs.tau_h[-1] if wiener else 0.0, end, 200)
            mean, lo, hi = trend_band(p, tau)
            lo = np.maximum(lo, 0.0)           # a coefficient K is >= 0 (0: healthy)
            ax.plot(t0 + tau, mean, color="C0", label=f"trend ({p.model})")
            ax.fill_between(t0 + tau, lo, hi, color="C0", alpha=0.2, label="90 % band")
            if p.onset_weights is not None and len(p.onset_weights) > 1:   # where the wear began
                for i, (tc, wc) in enumerate(zip(p.candidate_onsets_h, p.onset_weights)):
                    ax.axvline(tc, color="C4", lw=2, alpha=min(1.0, 0.15 + 0.85 * float(wc)),   # wc may round above 1
                               label="onset (shade: posterior weight)" if i == 0 else None)
            fin = ruls[np.isfinite(ruls)]
            if len(fin):
                ax2 = ax.twinx()
                ax2.hist(h.time_h[-1] + fin, bins=40, weights=None if p.weights is None else
                         p.weights[np.isfinite(ruls)], color="C1", alpha=0.35)
                ax2.set_yticks([])
            fh = format_hours          # 3 significant digits below 100: a rig's life may be hours or less
            hours = "" if unit == "h" else f" = {fh(q[1])} h [{fh(q[0])}, {fh(q[2])}]"
            ax.set_title(f"{name} {f}: RUL median {fh(qa[1])} {unit} [{fh(qa[0])}, {fh(qa[2])}]{hours} (5-95 %)",
                         fontsize=9)
        else:
            ax.set_title(f"{name} {f}: {p.reason}", fontsize=8)
        # the band may run far past the threshold up to the 95 % quantile's time: keep the data's scale
        top = 1.25 * max(p.threshold or 0.0, float(np.nanmax(h.k[:, fi] + h.std[:, fi])))
        ax.set_ylim(-0.03 * top, top)
        ax.set_ylabel(f"K_{f.upper()}")
        ax.legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel(("usage (the fit's clock)" if unit == "usage" else "time [h]")
                        + "  (orange: RUL distribution from the last test)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return obj
