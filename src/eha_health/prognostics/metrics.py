"""Prognostic performance metrics (Saxena et al., "Metrics for offline evaluation of prognostic
performance", IJPHM 2010; Saxena et al., PHM08 score).

Notation for one unit: prediction times t_i [h] (the tests), predicted RUL r_i (median of the
distribution), true RUL r*_i = EOL - t_i, t_P the first prediction time, EOL the true end of life.

* alpha-lambda: at t_lambda = t_P + lambda (EOL - t_P), the latest prediction at or before it
  is accurate if (1 - alpha) r* <= r <= (1 + alpha) r*.
* prognostic horizon PH = EOL - t_i for the first i with |r_i - r*_i| <= alpha EOL (the
  constant-width band of Saxena 2010); ``stay=True``: the first i from which every later
  prediction stays in the band. 0 if never.
* relative accuracy RA_i = 1 - |r*_i - r_i| / r*_i; cumulative relative accuracy CRA = mean RA_i.
* convergence: distance from (t_P, 0) to the centroid of the area under the error curve
  M_i = |r_i - r*_i|, both axes in fractions of EOL (smaller converges faster).
* coverage: fraction of points whose interval [p05, p95] holds r*.
* Brier score of the probability of failure before the next check p_i against the outcome
  y_i = [r*_i <= next check] (Brier 1950): BS = mean (p_i - y_i)^2; skill 1 - BS / (y(1 - y)), the
  climatology (every point given the fleet's event rate) scoring 0. Reliability: per bin of p,
  the mean p against the observed frequency of y (a calibrated p lies on the diagonal).
* NASA score per point: exp(-d/13) - 1 if d < 0 else exp(d/10) - 1, with d = r - r* in
  percent of the unit's life (the PHM08 constants, which were in cycles of ~200-cycle lives;
  percent keeps them scale-free), d capped at +-100 % (a missing prediction counts as
  +100 %). Late predictions cost more.
"""
from __future__ import annotations

import numpy as np


def alpha_lambda(t: np.ndarray, r: np.ndarray, eol: float, alpha: float, lam: float) -> bool | None:
    """Whether the prediction in force at t_lambda is within +-alpha of the true RUL (None: no prediction)."""
    t, r = np.asarray(t, float), np.asarray(r, float)
    tl = t[0] + lam * (eol - t[0])
    i = np.nonzero(t <= tl)[0]
    if not len(i):
        return None
    i = i[-1]
    rs = eol - t[i]
    return bool(np.isfinite(r[i]) and (1 - alpha) * rs <= r[i] <= (1 + alpha) * rs)


def prognostic_horizon(t: np.ndarray, r: np.ndarray, eol: float, alpha: float, stay: bool = False) -> float:
    """PH [h]: EOL minus the first prediction time inside r* +- alpha EOL (0 if none)."""
    t, r = np.asarray(t, float), np.asarray(r, float)
    ok = np.isfinite(r) & (np.abs(r - (eol - t)) <= alpha * eol)
    if stay:
        ok = np.logical_and.accumulate(ok[::-1])[::-1]
    i = np.nonzero(ok)[0]
    return float(eol - t[i[0]]) if len(i) else 0.0


def relative_accuracy(r: np.ndarray, r_true: np.ndarray) -> np.ndarray:
    r, rt = np.asarray(r, float), np.asarray(r_true, float)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(r), 1 - np.abs(rt - r) / rt, -np.inf)


def cumulative_relative_accuracy(r: np.ndarray, r_true: np.ndarray) -> float:
    ra = relative_accuracy(r, r_true)
    return float(np.mean(np.maximum(ra, -1.0)))   # a missing prediction counts as RA = -1


def convergence(t: np.ndarray, r: np.ndarray, eol: float) -> float:
    """Saxena's convergence of |error| (fractions of EOL on both axes); inf errors capped at EOL."""
    t, r = np.asarray(t, float) / eol, np.asarray(r, float) / eol
    m = np.minimum(np.abs(np.where(np.isfinite(r), r, 1e9) - (1 - t)), 1.0)
    if len(t) < 2:
        return float(m[0]) if len(m) else float("nan")
    dt = np.diff(t)
    mi = m[:-1]
    area = np.sum(dt * mi)
    if area <= 0:
        return 0.0
    xc = np.sum((t[1:] ** 2 - t[:-1] ** 2) * mi) / (2 * area)
    yc = np.sum(dt * mi ** 2) / (2 * area)
    return float(np.hypot(xc - t[0], yc))


def coverage(lo: np.ndarray, hi: np.ndarray, r_true: np.ndarray) -> float:
    lo, hi, rt = (np.asarray(v, float) for v in (lo, hi, r_true))
    return float(np.mean((lo <= rt) & (rt <= hi)))


def nasa_score(r: np.ndarray, r_true: np.ndarray, life: float) -> np.ndarray:
    d = 100.0 * (np.asarray(r, float) - np.asarray(r_true, float)) / life
    d = np.clip(np.where(np.isfinite(d), d, 100.0), -100.0, 100.0)   # capped at a whole life either way
    return np.where(d < 0, np.expm1(-d / 13.0), np.expm1(d / 10.0))


def brier(p: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(Brier score, skill against the climatology of the same events); skill NaN without both outcomes."""
    p, y = np.asarray(p, float), np.asarray(y, float)
    bs = float(np.mean((p - y) ** 2))
    ref = float(np.mean(y) * (1 - np.mean(y)))
    return bs, (1.0 - bs / ref if ref > 0 else float("nan"))


def reliability(p: np.ndarray, y: np.ndarray, edges=(0.0, 0.05, 0.2, 0.5, 1.0)) -> list[dict]:
    """Per bin [lo, hi) of p (the last closed): points, mean p, observed frequency of y."""
    p, y = np.asarray(p, float), np.asarray(y, bool)
    out = []
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        m = (p >= lo) & ((p <= hi) if i == len(edges) - 2 else (p < hi))
        out.append({"p_lo": lo, "p_hi": hi, "n": int(m.sum()),
                    "mean_p": float(p[m].mean()) if m.any() else None,
                    "observed": float(y[m].mean()) if m.any() else None})
    return out


def naive_rul(time_h: np.ndarray, k: np.ndarray, threshold: float, window: int) -> float:
    """Naive baseline: straight line (least squares) through the last ``window`` points; RUL [h]."""
    t, y = np.asarray(time_h[-window:], float), np.asarray(k[-window:], float)
    if len(t) < 2:
        return float("inf")
    slope, icpt = np.polyfit(t, y, 1)
    now = icpt + slope * t[-1]
    if now >= threshold:
        return 0.0
    if slope <= 0:
        return float("inf")
    return float((threshold - icpt) / slope - t[-1])
