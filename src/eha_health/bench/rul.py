"""Validation harness: simulated run-to-failure fleets (CLI: ``eha-health bench rul``).

Each unit of the fleet (unit i, its own random stream ``SeedSequence([seed, i])``):

* a primary fault (gm, fsj, bkl in turn) degrading by a law (linear, exponential, power,
  two-phase in turn) after a healthy period, with its own life L (lognormal, median
  ``life_median_h``, sd of log ``life_spread``) from onset to the threshold of the mean path;
  optionally a slower second fault;
* the true K(t) of a degrading fault is a non-stationary gamma process (van Noortwijk 2009)
  with mean mu(t) = thr h((t - t_on)/L): increments dK ~ Gamma(shape dmu/nu, scale nu),
  so E K = mu and Var K = nu mu; monotone, as wear is;
* the true end of life (EOL) is the first time a fault's true K reaches its physics threshold;
* a test schedule every ``test_interval_h`` (+- jitter) up to the EOL; at each test the
  reference EHA with sensor noise is simulated at the true K and **diagnosed for real**
  (``eha_health.diagnose``); diagnoses are cached on disk as JSON keyed by the sha256 of
  their inputs (true K, noise seed, method, diagnosis seed, package version, and the
  :func:`diagnosis_fingerprint` of the code and data a diagnosis depends on).

Scoring: at every test from ``first_prediction_test`` on, the prognosis of the history so
far (fleet prior from the other units' complete histories) is compared with the true RUL
(:mod:`metrics`), side by side with the naive baseline (a straight line through the last
``naive_window`` points of each fault).
"""
from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..physics.faults import FAULT_UPPER
from ..prognostics.config import BenchSettings, Settings, load_settings
from ..prognostics.thresholds import FAULTS, threshold_values

FINE_DT_H = 1.0   # h, grid of the simulated gamma process
#: Shape parameter range of each law (exponential beta, power p, two-phase slope ratio), drawn
#: uniformly per unit, and the two-phase knee range (fraction of the life).
SHAPE_RANGES = {"linear": (1.0, 1.0), "exponential": (1.5, 3.0), "power": (1.5, 2.5), "two_phase": (2.0, 3.0)}
KNEE_RANGE = (0.4, 0.6)


@dataclass
class FaultPath:
    """True degradation of one fault of one unit."""
    fault: str
    law: str
    onset_h: float
    life_h: float           # onset to threshold of the mean path
    volatility: float       # gamma-process scale nu [K]
    shape: float            # law parameter (exponential beta, power p, two-phase slope ratio)
    knee: float             # two-phase knee (fraction of life), else nan
    t_h: np.ndarray         # fine time grid
    k: np.ndarray           # true K on the grid


@dataclass
class Unit:
    """One simulated actuator: its true paths, EOL and test schedule."""
    index: int
    actuator_id: str
    paths: list[FaultPath]
    eol_h: float
    eol_fault: str
    test_h: np.ndarray
    true_k: np.ndarray      # [n_tests, 3] (gm, fsj, bkl) at the tests
    seeds: np.ndarray       # noise seed of each test
    diag_k: np.ndarray | None = None     # diagnosed K [n_tests, 3]
    diag_std: np.ndarray | None = None   # their standard errors


def _mean_shape(law: str, x: np.ndarray, shape: float, knee: float) -> np.ndarray:
    """h(x), x = (t - t_on)/L, with h(0) = 0 and h(1) = 1."""
    x = np.maximum(x, 0.0)
    if law == "linear":
        return x
    if law == "exponential":
        return np.expm1(shape * x) / math.expm1(shape)
    if law == "power":
        return x ** shape
    if law == "two_phase":
        # slope 1 up to the knee, then `shape` times steeper; normalised to h(1) = 1
        raw = np.where(x <= knee, x, knee + shape * (x - knee))
        return raw / (knee + shape * (1 - knee))
    raise ValueError(f"unknown degradation law {law!r}")


def _fault_path(rng: np.random.Generator, fault: str, law: str, life: float, onset: float, thr: float,
                nu: float, horizon: float) -> FaultPath:
    # every law's draw is made, whichever the law, so that the fleet's random stream does not depend on it
    draws = {name: (lo if lo == hi else rng.uniform(lo, hi)) for name, (lo, hi) in SHAPE_RANGES.items()}
    shape = draws[law]
    knee = rng.uniform(*KNEE_RANGE) if law == "two_phase" else float("nan")
    t = np.arange(0.0, horizon + FINE_DT_H, FINE_DT_H)
    mu = thr * _mean_shape(law, (t - onset) / life, shape, knee)
    dmu = np.diff(mu)
    inc = np.where(dmu > 0, rng.gamma(np.maximum(dmu, 1e-300) / nu, nu), 0.0)
    k = np.concatenate([[0.0], np.cumsum(inc)])
    return FaultPath(fault, law, onset, life, nu, shape, knee, t, k)


def make_fleet(bench: BenchSettings | None = None, thresholds: dict[str, float] | None = None) -> list[Unit]:
    """The simulated fleet: true paths, EOLs, test schedules and noise seeds (no diagnosis yet)."""
    b = bench or load_settings().bench
    thr = thresholds or threshold_values()
    units = []
    for i in range(b.n_units):
        rng = np.random.default_rng([b.seed, i])
        primary = FAULTS[i % 3]
        law = b.laws[(i // 3) % len(b.laws)]
        life = b.life_median_h * math.exp(b.life_spread * rng.standard_normal())
        onset = rng.uniform(*b.healthy_fraction) * life
        nu = math.exp(rng.uniform(math.log(b.volatility[0]), math.log(b.volatility[1])))
        second = rng.random() < b.second_fault_probability
        f2 = rng.choice([f for f in FAULTS if f != primary])
        law2 = b.laws[rng.integers(len(b.laws))]
        life2 = life * rng.uniform(*b.second_fault_slowdown)
        onset2 = rng.uniform(*b.healthy_fraction) * life2
        horizon = 3.0 * (onset + life)
        paths = [_fault_path(rng, primary, law, life, onset, thr[primary], nu, horizon)]
        if second:
            paths.append(_fault_path(rng, str(f2), law2, life2, onset2, thr[str(f2)], nu, horizon))
        eol, eol_fault = math.inf, None
        for p in paths:
            hit = np.nonzero(p.k >= thr[p.fault])[0]
            if len(hit):
                j = hit[0]   # j >= 1: K(0) = 0 < thr
                frac = (thr[p.fault] - p.k[j - 1]) / (p.k[j] - p.k[j - 1])
                te = p.t_h[j - 1] + frac * FINE_DT_H
                if te < eol:
                    eol, eol_fault = float(te), p.fault
        if eol_fault is None:
            raise RuntimeError(f"unit {i}: no fault reached its threshold within {horizon:.0f} h")
        tests = [0.0]
        while True:
            nxt = tests[-1] + b.test_interval_h * (1 + rng.uniform(-b.test_jitter, b.test_jitter))
            if nxt >= eol:
                break
            tests.append(round(nxt, 3))
        test_h = np.array(tests)
        true_k = np.zeros((len(test_h), 3))
        for p in paths:
            true_k[:, FAULTS.index(p.fault)] = np.interp(test_h, p.t_h, p.k)
        seeds = np.array([b.seed * 1_000_000 + i * 1000 + k for k in range(len(test_h))])
        units.append(Unit(i, f"U{i:03d}", paths, eol, eol_fault, test_h, true_k, seeds))
    return units


# ----------------------------------------------------------------------------- diagnoses
#: What a simulated diagnosis depends on: the code of these packages and these data files.
DIAGNOSIS_CODE = ("physics", "identification", "signals")
DIAGNOSIS_DATA = ("params.yaml", "model_error.yaml", "monitor.yaml")


@functools.lru_cache(maxsize=1)
def diagnosis_fingerprint() -> str:
    """sha256 of the sources and data files a simulated diagnosis depends on (:data:`DIAGNOSIS_CODE`,
    :data:`DIAGNOSIS_DATA`): any change to them keys a fresh cache entry, so a cached diagnosis is
    never one of older code (a version string is not bumped on every change)."""
    root = Path(__file__).resolve().parents[1]
    files = sorted(f for pkg in DIAGNOSIS_CODE for f in (root / pkg).rglob("*.py"))
    files += [root / "data" / n for n in DIAGNOSIS_DATA if (root / "data" / n).is_file()]
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def _cache_key(k: np.ndarray, seed: int, method: str) -> tuple[str, dict]:
    import eha_health
    inputs = {"k": [round(float(v), 12) for v in k], "noise_seed": int(seed), "effects": ["sensor_noise"],
              "method": method, "diagnosis_seed": 0, "version": eha_health.__version__,
              "code": diagnosis_fingerprint()}
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest(), inputs


def diagnose_test(k: np.ndarray, seed: int, method: str, cache_dir: str | Path) -> dict:
    """Diagnosis of a simulated noisy FDI test of the reference EHA at true ``k`` (cached).

    Returns ``{"k": [gm, fsj, bkl], "std": [...], "cost", "wall_time_s", "inputs", "cached"}``.
    """
    key, inputs = _cache_key(k, seed, method)
    path = Path(cache_dir) / key[:2] / f"{key}.json"
    if path.is_file():
        d = json.loads(path.read_text())
        d["cached"] = True
        return d
    from eha_health import Faults, diagnose, load, simulate
    params = load("reference").with_effect_names(["sensor_noise"])
    r = simulate(kind="reference", faults=Faults(*map(float, k)), params=params, seed=int(seed))
    d = diagnose(r, method=method, seed=0)
    out = {"k": list(d.faults.as_tuple()), "std": [d.std["k_gm"], d.std["k_fsj"], d.std["k_bkl"]],
           "cost": d.cost, "wall_time_s": d.wall_time_s, "warnings": d.warnings, "inputs": inputs}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out))
    tmp.replace(path)   # atomic: a killed run leaves no half-written cache entry
    out["cached"] = False
    return out


def diagnose_fleet(units: list[Unit], method: str, cache_dir: str | Path,
                   progress: Callable[[str], None] | None = print) -> dict:
    """Fill ``diag_k`` / ``diag_std`` of every unit; returns counts and time."""
    total = sum(len(u.test_h) for u in units)
    done = cached = 0
    t0 = time.perf_counter()
    for u in units:
        ks, ss = [], []
        for k, seed in zip(u.true_k, u.seeds):
            d = diagnose_test(k, int(seed), method, cache_dir)
            ks.append(d["k"])
            ss.append(d["std"])
            done += 1
            cached += d["cached"]
            if progress and (not d["cached"] or done == total):
                el = time.perf_counter() - t0
                progress(f"diagnosis {done}/{total} ({cached} cached) unit {u.actuator_id} "
                         f"true K {np.round(k, 3).tolist()} -> {np.round(d['k'], 3).tolist()}  {el:.0f} s")
        u.diag_k, u.diag_std = np.array(ks), np.array(ss)
    return {"diagnoses": total, "cached": cached, "wall_time_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------------- oracle
def oracle_rul(u: Unit, t_h: float, thr: dict[str, float], n_paths: int = 400, seed: int = 0) -> np.ndarray:
    """RUL samples [h] of an oracle that knows each fault's true K at ``t_h``, its law, life and
    volatility: gamma-process continuations from there (only the future randomness is unknown).
    Its median is the best point prediction any method can make; it bounds alpha-lambda."""
    rng = np.random.default_rng([seed, u.index, int(t_h)])
    best = np.full(n_paths, np.inf)
    for p in u.paths:
        j = int(np.searchsorted(p.t_h, t_h))
        k0 = np.interp(t_h, p.t_h, p.k)
        mu = thr[p.fault] * _mean_shape(p.law, (p.t_h[j:] - p.onset_h) / p.life_h, p.shape, p.knee)
        dmu = np.maximum(np.diff(mu), 0.0)
        inc = np.where(dmu > 0, rng.gamma(np.maximum(dmu, 1e-300) / p.volatility, p.volatility,
                                          size=(n_paths, len(dmu))), 0.0)
        k = k0 + np.cumsum(inc, 1)
        hit = k >= thr[p.fault]
        first = np.where(hit.any(1), p.t_h[j + 1:][np.argmax(hit, 1)] - t_h, np.inf)
        best = np.minimum(best, first)
    return best


def law_cells(law: str, n: int = 5) -> list[tuple[str, float, float]]:
    """(law, shape, knee) cells spanning the fleet's range of a law (:data:`SHAPE_RANGES`; two-phase:
    3 slope ratios x 3 knees)."""
    lo, hi = SHAPE_RANGES[law]
    if law == "linear":
        return [(law, 1.0, float("nan"))]
    if law == "two_phase":
        return [(law, float(v), float(kn)) for v in np.linspace(lo, hi, 3) for kn in np.linspace(*KNEE_RANGE, 3)]
    return [(law, float(v), float("nan")) for v in np.linspace(lo, hi, n)]


def reference_rul(u: Unit, k: int, thr: dict[str, float], cells: list[tuple[str, float, float]],
                  volatilities: list[float], life_median_h: float) -> float:
    """Median RUL [h] at test ``k`` of a Bayesian predictor that is told which fault fails, and which
    (law, shape, knee) ``cells`` and gamma-process ``volatilities`` nu the truth is among (each law
    named in the cells equally likely a priori, its cells alike; the volatilities alike), and learns
    the onset and the life L from the unit's own diagnoses up to test k.

    Grid posterior over (cell, nu, onset uniform on [0, t_k], L log-uniform over 0.1 to 10 fleet
    median lives). Likelihood: the gamma process's independent increments, taken Gaussian,
    dK_j ~ N(dmu_j, nu dmu_j + s_j^2 + s_{j-1}^2), mu = thr h((t - onset)/L), and the first point
    K_0 ~ N(mu_0, nu mu_0 + s_0^2). RUL of a cell: the mean path continued from the last diagnosed
    K (the level the unit is at, not the one its mean path would be at) to the threshold,
    h(x_c) = h(x_k) + (thr - K_k) / thr, RUL = onset + x_c L - t_k.
    With one cell and the true nu it is what learning a known law's onset and life from a unit's
    partial history can give; with every law of the fleet, what knowing the fleet's family of laws
    (but not the unit's) can give."""
    p = next(q for q in u.paths if q.fault == u.eol_fault)
    fi = FAULTS.index(p.fault)
    T = thr[p.fault]
    t, y, sd = u.test_h[:k + 1], u.diag_k[:k + 1, fi], u.diag_std[:k + 1, fi]
    life = np.geomspace(0.1 * life_median_h, 10 * life_median_h, 200)[:, None, None]
    onset = np.linspace(0.0, t[-1], 80)[None, :, None]
    xs = np.linspace(0.0, 30.0, 30001)          # fractions of life on which h is inverted
    laws = [c[0] for c in cells]
    lls, ruls = [], []
    for law, shape, knee in cells:
        log_prior = -math.log(len(set(laws)) * laws.count(law))
        mu = T * _mean_shape(law, (t - onset) / life, shape, knee)            # [L, onset, n]
        dmu = np.diff(mu, axis=-1)
        hs = _mean_shape(law, xs, shape, knee)
        x_now = (t[-1] - onset) / life
        target = np.minimum(_mean_shape(law, x_now, shape, knee) + (T - y[-1]) / T, hs[-1])
        x_c = np.maximum(np.interp(target, hs, xs), x_now)
        rul = (onset + x_c * life - t[-1])[..., 0].ravel()
        for nu in volatilities:
            var = nu * np.maximum(dmu, 1e-12) + sd[1:] ** 2 + sd[:-1] ** 2
            ll = -0.5 * np.sum((np.diff(y) - dmu) ** 2 / var + np.log(var), -1)
            v0 = nu * np.maximum(mu[..., 0], 1e-12) + sd[0] ** 2
            ll = ll - 0.5 * ((y[0] - mu[..., 0]) ** 2 / v0 + np.log(v0))
            lls.append(ll.ravel() + log_prior)
            ruls.append(rul)
    ll, rul = np.concatenate(lls), np.concatenate(ruls)
    w = np.exp(ll - ll.max())
    o = np.argsort(rul)
    return float(rul[o][np.searchsorted(np.cumsum(w[o]) / w.sum(), 0.5)])


#: The reference predictors of the bench table: what each is told (besides the failing fault).
REFERENCES = {
    "law_and_shape_known": "law, its shape parameter and the volatility known",
    "law_known": "law known, its shape parameter and the volatility within the fleet's ranges",
    "fleet_laws_known": "the fleet's four laws (each 1/4 a priori) and their ranges known, not which one the "
                        "unit follows",
    "generic_shapes": "no law known: a generic library of power (p 0.3-4, linear included) and exponential "
                      "(beta 0.5-6) shapes, each family 1/2 a priori",
}
#: The generic library of the last reference: what a learner without the fleet's laws might use (the
#: power family and the exponential one equally likely a priori).
GENERIC_CELLS = ([("power", p, float("nan")) for p in (0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 4.0)]
                 + [("exponential", beta, float("nan")) for beta in (0.5, 1.0, 2.0, 4.0, 6.0)])


def reference_alpha_lambda(units: list[Unit], scores: list["UnitScore"], thr: dict[str, float],
                           b: BenchSettings) -> dict:
    """alpha-lambda of the :data:`REFERENCES` predictors (:func:`reference_rul`) at the scored points."""
    from ..prognostics import metrics as M
    nus = list(np.geomspace(b.volatility[0], b.volatility[1], 4))
    every_law = [c for law in b.laws for c in law_cells(law)]
    out = {}
    for key in REFERENCES:
        out[key] = {}
        for lam in b.lambdas:
            res = []
            for u, sc in zip(units, scores):
                tl = sc.t_h[0] + lam * (sc.eol_h - sc.t_h[0])
                i = int(np.nonzero(sc.t_h <= tl)[0][-1])
                k = int(np.searchsorted(u.test_h, sc.t_h[i]))
                p = next(q for q in u.paths if q.fault == u.eol_fault)
                cells, vols = {"law_and_shape_known": ([(p.law, p.shape, p.knee)], [p.volatility]),
                               "law_known": (law_cells(p.law), nus),
                               "fleet_laws_known": (every_law, nus),
                               "generic_shapes": (GENERIC_CELLS, nus)}[key]
                r = np.full(len(sc.t_h), np.nan)
                r[i] = reference_rul(u, k, thr, cells, vols, b.life_median_h)
                res.append(M.alpha_lambda(sc.t_h[:i + 1], r[:i + 1], sc.eol_h, b.alpha, lam))
            res = [v for v in res if v is not None]
            out[key][str(lam)] = {"fraction": float(np.mean(res)) if res else float("nan"),
                                  "misses": int(len(res) - sum(res)), "units": len(res)}
    return out


# ----------------------------------------------------------------------------- evaluation
@dataclass
class UnitScore:
    """Predictions of one unit at every scored test, ours and the baseline's."""
    actuator_id: str
    eol_h: float
    t_h: np.ndarray          # prediction times
    r_true: np.ndarray
    p05: np.ndarray
    p50: np.ndarray
    p95: np.ndarray
    pit: np.ndarray          # predicted P(RUL <= true RUL)
    naive: np.ndarray
    fleet_prior: np.ndarray  # bool per point
    dominant_ok: np.ndarray  # predicted dominant fault == the true first fault
    p_next: np.ndarray | None = None   # predicted P(failure before the next check), one interval on


def _predict_unit_points(units: list[Unit], s: Settings, thr: dict[str, float],
                         progress: Callable[[str], None] | None = None) -> list[UnitScore]:
    from ..prognostics.rul import (FaultPrediction, apply_fleet_prior, fleet_prior, member_lives, overall,
                                   prepare_fault, predict_series, shared_wear, weighted_quantiles)
    from ..prognostics.metrics import naive_rul
    b = s.bench
    first = b.first_prediction_test - 1
    points = [(ui, k) for ui, u in enumerate(units) for k in range(first, len(u.test_h))]
    preds: dict[tuple, dict[str, FaultPrediction]] = {pt: {} for pt in points}
    for fi, f in enumerate(FAULTS):
        if progress:
            progress(f"predictions: fault {f} ({fi + 1}/{len(FAULTS)}), {len(points)} prediction points "
                     f"and {len(units)} completed histories")
        # full histories (the fleet's completed run-to-failure records) give the leave-one-out priors
        full = []
        for u in units:
            p, _ = prepare_fault(u.test_h, u.diag_k[:, fi], u.diag_std[:, fi], thr[f], len(u.test_h), s)
            full.append(p)
        predict_series(full, np.full(len(full), thr[f]), fi, s)
        members = member_lives([u.actuator_id for u in units], full, s)
        plist = []
        for ui, k in points:
            u = units[ui]
            p, _ = prepare_fault(u.test_h[:k + 1], u.diag_k[:k + 1, fi], u.diag_std[:k + 1, fi], thr[f], k + 1, s)
            preds[(ui, k)][f] = p
            plist.append(p)
        predict_series(plist, np.full(len(plist), thr[f]), fi, s)
        # each unit takes the prior of the others (apply_fleet_prior leaves its own life out)
        prior = fleet_prior(members, s.fleet.min_members)
        for (ui, k), p in zip(points, plist):
            apply_fleet_prior(p, prior, s, units[ui].actuator_id)
    scores = []
    for ui, u in enumerate(units):
        ks = [k for (uj, k) in points if uj == ui]
        rows = []
        for k in ks:
            ov = overall(preds[(ui, k)], k + 1, shared_wear(preds[(ui, k)], s))
            rt = u.eol_h - u.test_h[k]
            # no RUL (no trend): no failure expected before the next check
            p_next = ov.p_fail(b.test_interval_h) if ov.samples is not None else 0.0
            if ov.samples is None:
                q = (np.inf, np.inf, np.inf)
                pit = 0.0
            else:
                q = weighted_quantiles(ov.samples, ov.weights, (0.05, 0.5, 0.95))
                w = ov.weights if ov.weights is not None else np.ones_like(ov.samples)
                pit = float(np.sum(w * (ov.samples <= rt)) / np.sum(w))
            nv = min(naive_rul(u.test_h[:k + 1], u.diag_k[:k + 1, fi], thr[f], b.naive_window)
                     for fi, f in enumerate(FAULTS))
            fp = any(p.fleet_prior for p in preds[(ui, k)].values())
            dom = getattr(ov, "dominant", None) == u.eol_fault
            rows.append((u.test_h[k], rt, *q, pit, nv, fp, dom, p_next))
        a = np.array(rows, dtype=float).reshape(-1, 10)
        scores.append(UnitScore(u.actuator_id, u.eol_h, a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5],
                                a[:, 6], a[:, 7].astype(bool), a[:, 8].astype(bool), a[:, 9]))
    return scores


def oracle_alpha_lambda(units: list[Unit], scores: list[UnitScore], thr: dict[str, float],
                        b: BenchSettings) -> dict:
    """alpha-lambda of the oracle's median (:func:`oracle_rul`) at the same prediction points."""
    from ..prognostics import metrics as M
    out = {}
    for lam in b.lambdas:
        res = []
        for u, sc in zip(units, scores):
            med = np.array([np.median(oracle_rul(u, t, thr)) for t in sc.t_h])
            r = M.alpha_lambda(sc.t_h, med, sc.eol_h, b.alpha, lam)
            if r is not None:
                res.append(r)
        out[str(lam)] = {"fraction": float(np.mean(res)) if res else float("nan"),
                         "misses": int(len(res) - sum(res)), "units": len(res)}
    return out


def _wilson(k: int, n: int) -> list[float] | None:
    """95 % Wilson interval of a share k / n of independent units (a fleet of 24 reads +-20 %)."""
    from scipy.stats import binomtest
    if n == 0:
        return None
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return [float(ci.low), float(ci.high)]


def _unit_bootstrap_ci(scores: list[UnitScore], seed: int = 0) -> list[float] | None:
    """95 % interval of the 90 % coverage (points with a RUL), units resampled whole: a unit's
    predictions share its path and are not independent points (scipy.stats.bootstrap, percentile)."""
    from scipy.stats import bootstrap
    hits, counts = [], []
    for sc in scores:
        have = np.isfinite(sc.p05) | np.isfinite(sc.p95)
        hits.append(float(np.sum((sc.p05[have] <= sc.r_true[have]) & (sc.r_true[have] <= sc.p95[have]))))
        counts.append(float(have.sum()))
    if sum(counts) == 0 or len(scores) < 2:
        return None
    res = bootstrap((np.array(hits), np.array(counts)), lambda h, c: np.sum(h) / np.sum(c), paired=True,
                    vectorized=False, n_resamples=2000, method="percentile", random_state=np.random.default_rng(seed))
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def failure_warning(scores: list[UnitScore], interval_h: float, warn: float, error: float) -> dict:
    """How p_fail_next does as a warning: the event is a failure before the next check (true RUL
    <= ``interval_h``); Brier score and skill, reliability, and per level (the monitor's WARN and
    ERROR, ``prognosis.warn_p_fail`` / ``error_p_fail``) the events it raised and the points it
    raised where the true RUL exceeds two intervals (false: the failure is two checks away)."""
    from ..prognostics import metrics as M
    p = np.concatenate([sc.p_next for sc in scores])
    rt = np.concatenate([sc.r_true for sc in scores])
    y, far = rt <= interval_h, rt > 2 * interval_h
    bs, skill = M.brier(p, y)
    out = {"interval_h": interval_h, "points": int(len(p)), "events": int(y.sum()), "brier": bs,
           "brier_skill": skill, "reliability": M.reliability(p, y)}
    for name, level in (("warn", warn), ("error", error)):
        out[name] = {"p": level, "events_raised": int(np.sum(y & (p >= level))),
                     "false": int(np.sum(far & (p >= level))), "far_points": int(far.sum())}
    return out


def score_fleet(scores: list[UnitScore], b: BenchSettings, warn: float, error: float) -> dict:
    """Fleet metrics, ours and the naive baseline's, and their ratios; ``warn`` / ``error``: the
    p_fail_next levels of :func:`failure_warning` (``prognosis.warn_p_fail`` / ``error_p_fail``)."""
    from ..prognostics import metrics as M
    out: dict = {"units": len(scores), "points": int(sum(len(sc.t_h) for sc in scores))}
    for name, pick in (("model", lambda sc: sc.p50), ("naive", lambda sc: sc.naive)):
        al = {}
        for lam in b.lambdas:
            res = [M.alpha_lambda(sc.t_h, pick(sc), sc.eol_h, b.alpha, lam) for sc in scores]
            res = [r for r in res if r is not None]
            al[str(lam)] = {"fraction": float(np.mean(res)) if res else float("nan"),
                            "misses": int(len(res) - sum(res)), "units": len(res),
                            "ci95": _wilson(int(sum(res)), len(res))}
        ph = np.array([M.prognostic_horizon(sc.t_h, pick(sc), sc.eol_h, b.alpha) / sc.eol_h for sc in scores])
        ph_stay = np.array([M.prognostic_horizon(sc.t_h, pick(sc), sc.eol_h, b.alpha, stay=True) / sc.eol_h
                            for sc in scores])
        ra = np.concatenate([M.relative_accuracy(pick(sc), sc.r_true) for sc in scores])
        cra = np.array([M.cumulative_relative_accuracy(pick(sc), sc.r_true) for sc in scores])
        conv = np.array([M.convergence(sc.t_h, pick(sc), sc.eol_h) for sc in scores])
        nasa = np.concatenate([M.nasa_score(pick(sc), sc.r_true, sc.eol_h) for sc in scores])
        out[name] = {
            "alpha_lambda": al,
            "ph_fraction_median": float(np.median(ph)), "ph_stay_fraction_median": float(np.median(ph_stay)),
            "ra_median": float(np.median(np.maximum(ra, -1.0))), "cra_mean": float(np.mean(cra)),
            "convergence_mean": float(np.mean(conv)), "nasa_score_mean": float(np.mean(nasa)),
            "no_prediction_points": int(sum(np.sum(~np.isfinite(pick(sc))) for sc in scores)),
        }
    lo = np.concatenate([sc.p05 for sc in scores])
    hi = np.concatenate([sc.p95 for sc in scores])
    rt = np.concatenate([sc.r_true for sc in scores])
    have = np.isfinite(lo) | np.isfinite(hi)
    pit = np.concatenate([sc.pit for sc in scores])[have]
    out["model"]["coverage90"] = M.coverage(lo[have], hi[have], rt[have])
    out["model"]["coverage90_ci95"] = _unit_bootstrap_ci(scores)
    out["model"]["coverage90_all_points"] = M.coverage(np.where(have, lo, np.inf), hi, rt)
    out["model"]["coverage50"] = float(np.mean((pit >= 0.25) & (pit <= 0.75)))
    out["model"]["coverage80"] = float(np.mean((pit >= 0.10) & (pit <= 0.90)))
    out["model"]["fleet_prior_points"] = int(sum(sc.fleet_prior.sum() for sc in scores))
    out["model"]["dominant_fault_right"] = float(np.mean(np.concatenate([sc.dominant_ok for sc in scores])))
    if all(sc.p_next is not None for sc in scores):
        out["model"]["p_fail_next"] = failure_warning(scores, b.test_interval_h, warn, error)
    m, n = out["model"], out["naive"]

    def ratio(a, c):
        return float(a / c) if c not in (0, 0.0) and np.isfinite(c) else None
    out["ratios_model_to_naive"] = {
        "alpha_lambda_misses@0.5": ratio(m["alpha_lambda"]["0.5"]["misses"], n["alpha_lambda"]["0.5"]["misses"]),
        "ph_fraction_median": ratio(m["ph_fraction_median"], n["ph_fraction_median"]),
        "cra_mean": ratio(m["cra_mean"], n["cra_mean"]),
        "convergence_mean": ratio(m["convergence_mean"], n["convergence_mean"]),
        "nasa_score_mean": ratio(m["nasa_score_mean"], n["nasa_score_mean"]),
    }
    al = m["alpha_lambda"]["0.5"]
    out["targets"] = {
        "alpha_lambda@0.5 >= 0.90": bool(al["fraction"] >= 0.90),
        "misses <= naive misses / 2": bool(al["misses"] * 2 <= n["alpha_lambda"]["0.5"]["misses"]),
        "0.85 <= coverage90 <= 0.95": bool(0.85 <= m["coverage90"] <= 0.95),
        "PH median >= 0.5 life": bool(m["ph_fraction_median"] >= 0.5),
    }
    return out


def plot_bench(units: list[Unit], scores: list[UnitScore], result: dict, path: str | Path,
               alpha: float) -> None:
    """Example units (RUL median, 90 % band, naive baseline, truth and the alpha cone), the PIT
    histogram, and p_fail_next: its reliability and against the true RUL."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 4, figsize=(18, 8))
    picks = np.linspace(0, len(scores) - 1, 5).round().astype(int)
    for ax, i in zip(axes.flat[:5], picks):
        sc, u = scores[i], units[i]
        t = sc.t_h
        ax.fill_between(t, (1 - alpha) * sc.r_true, (1 + alpha) * sc.r_true, color="0.88", label=f"true RUL +-{alpha:.0%}")
        ax.plot(t, sc.r_true, "k-", lw=1, label="true RUL")
        ok = np.isfinite(sc.p50)
        ax.fill_between(t[ok], sc.p05[ok], np.where(np.isfinite(sc.p95[ok]), sc.p95[ok], np.nan), alpha=0.3,
                        color="C0", label="90 % interval")
        ax.plot(t[ok], sc.p50[ok], "o-", color="C0", ms=3, label="median")
        nv = np.where(np.isfinite(sc.naive), sc.naive, np.nan)
        ax.plot(t, nv, "x--", color="C3", ms=4, label="naive (last 5 points)")
        ax.set_ylim(0, 1.6 * sc.r_true[0])
        laws = ", ".join(f"{p.fault} {p.law}" for p in u.paths)
        ax.set_title(f"{u.actuator_id}: {laws}; EOL {u.eol_h:.0f} h ({u.eol_fault})", fontsize=9)
        ax.set_xlabel("time [h]")
        ax.set_ylabel("RUL [h]")
    axes.flat[0].legend(fontsize=7)
    ax = axes.flat[5]
    pit = np.concatenate([sc.pit[np.isfinite(sc.p05)] for sc in scores])
    ax.hist(pit, bins=10, range=(0, 1), color="C0", alpha=0.7)
    ax.axhline(len(pit) / 10, color="k", ls="--", lw=1, label="calibrated")
    m = result["model"]
    ax.set_title(f"PIT of the true RUL: coverage 90 % = {m['coverage90']:.1%}", fontsize=9)
    ax.set_xlabel("predicted P(RUL <= true RUL)")
    ax.legend(fontsize=7)
    f = m.get("p_fail_next")
    if f:
        ax = axes.flat[6]
        cells = [c for c in f["reliability"] if c["n"]]
        ax.plot([0, 1], [0, 1], "k--", lw=1, label="calibrated")
        ax.plot([c["mean_p"] for c in cells], [c["observed"] for c in cells], "o-", color="C0")
        for c in cells:
            ax.annotate(str(c["n"]), (c["mean_p"], c["observed"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel("p_fail_next, mean of the bin")
        ax.set_ylabel("failures before the next check, observed")
        ax.set_title(f"p_fail_next reliability (points per bin); Brier skill {f['brier_skill']:.2f}", fontsize=9)
        ax.legend(fontsize=7)
        ax = axes.flat[7]
        p = np.concatenate([sc.p_next for sc in scores])
        rt = np.concatenate([sc.r_true for sc in scores]) / f["interval_h"]
        ax.semilogx(np.maximum(rt, 0.05), p, ".", color="C0", ms=4)
        for key, ls in (("warn", ":"), ("error", "--")):
            ax.axhline(f[key]["p"], color="C3", ls=ls, lw=1, label=f"{key.upper()} {f[key]['p']:g}")
        ax.axvline(1.0, color="k", lw=1)
        ax.set_xlabel("true RUL / check interval")
        ax.set_ylabel("p_fail_next")
        ax.set_title(f"p_fail_next vs the true RUL ({f['events']} failures left of the line)", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def bench_rul(settings: Settings | None = None, cache_dir: str | Path = "out/rul_cache",
              plot: str | Path | None = "out/bench_rul.png", progress: Callable[[str], None] | None = print) -> dict:
    """Run the harness: fleet, real diagnoses (cached), predictions, metrics, plot. Returns the
    result dict (:func:`format_result` prints it); ``progress`` hears each stage."""
    s = settings or load_settings()
    t0 = time.perf_counter()
    thr = threshold_values(s)
    units = make_fleet(s.bench, thr)
    if progress:
        progress(f"fleet: {len(units)} units, {sum(len(u.test_h) for u in units)} tests, thresholds "
                 + ", ".join(f"{f} {v:.3f}" for f, v in thr.items()))
    diag = diagnose_fleet(units, s.bench.method, cache_dir, progress)
    t1 = time.perf_counter()
    scores = _predict_unit_points(units, s, thr, progress)
    result = score_fleet(scores, s.bench, s.prognosis.warn_p_fail, s.prognosis.error_p_fail)
    if progress:
        progress(f"reference predictors (oracle and {len(REFERENCES)} Bayesian) at {result['points']} points")
    result["oracle"] = {"alpha_lambda": oracle_alpha_lambda(units, scores, thr, s.bench),
                        **reference_alpha_lambda(units, scores, thr, s.bench)}
    result["thresholds"] = thr
    result["diagnoses"] = diag
    result["prediction_wall_time_s"] = time.perf_counter() - t1
    result["wall_time_s"] = time.perf_counter() - t0
    result["settings"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in s.bench.__dict__.items()}
    if plot:
        plot_bench(units, scores, result, plot, s.bench.alpha)
        result["plot"] = str(plot)
    return result


def _ci(ci: list[float] | None, how: str = "") -> str:
    return "" if not ci else f"; 95 % CI {100 * ci[0]:.0f}-{100 * ci[1]:.0f} %{how}"


def format_result(r: dict) -> str:
    """Markdown table of a bench result (model vs naive baseline, targets)."""
    m, n = r["model"], r["naive"]
    lines = [f"units {r['units']}, scored predictions {r['points']}", "",
             "| metric | model | naive (last 5 points) | ratio |", "|---|---|---|---|"]
    for lam in m["alpha_lambda"]:
        a, c = m["alpha_lambda"][lam], n["alpha_lambda"][lam]
        lines.append(f"| alpha-lambda (alpha {r['settings']['alpha']}) at lambda {lam}: units within | "
                     f"{a['fraction']:.0%} ({a['misses']} misses{_ci(a.get('ci95'))}) | {c['fraction']:.0%} "
                     f"({c['misses']} misses{_ci(c.get('ci95'))}) | "
                     f"{(a['misses'] / c['misses']) if c['misses'] else float('nan'):.2f} (misses) |")
    if "oracle" in r:
        o = r["oracle"]["alpha_lambda"]
        lines.append("| alpha-lambda of an oracle knowing each unit's law, life and volatility (lambda "
                     + " / ".join(o) + ") | " + " / ".join(f"{v['fraction']:.0%}" for v in o.values())
                     + " | - | - |")
        for key, label in REFERENCES.items():
            if key in r["oracle"]:
                o = r["oracle"][key]
                lines.append(f"| alpha-lambda of a Bayesian predictor, {label}, onset and life learnt from the "
                             "unit's diagnoses (lambda " + " / ".join(o) + ") | "
                             + " / ".join(f"{v['fraction']:.0%}" for v in o.values()) + " | - | - |")
    for key, label in (("ph_fraction_median", "prognostic horizon / life, median (first entry)"),
                       ("ph_stay_fraction_median", "prognostic horizon / life, median (stays in band)"),
                       ("ra_median", "relative accuracy, median over points"),
                       ("cra_mean", "cumulative relative accuracy, mean over units"),
                       ("convergence_mean", "convergence (fraction of life, lower is better)"),
                       ("nasa_score_mean", "NASA score per point (d in % of life, lower is better)")):
        a, c = m[key], n[key]
        lines.append(f"| {label} | {a:.3f} | {c:.3f} | {a / c if c else float('nan'):.2f} |")
    lines.append(f"| 90 % interval coverage (points with a RUL) | {m['coverage90']:.1%}"
                 f"{_ci(m.get('coverage90_ci95'), ', units resampled')} | - | - |")
    lines.append(f"| 90 % interval coverage (all points, no RUL = miss) | {m['coverage90_all_points']:.1%} | - | - |")
    lines.append(f"| 80 % / 50 % interval coverage | {m['coverage80']:.1%} / {m['coverage50']:.1%} | - | - |")
    lines.append(f"| points without a RUL | {m['no_prediction_points']} | {n['no_prediction_points']} | - |")
    lines.append(f"| points with the fleet prior | {m['fleet_prior_points']} | - | - |")
    lines.append(f"| dominant fault right | {m['dominant_fault_right']:.1%} | - | - |")
    if "p_fail_next" in m:
        f = m["p_fail_next"]
        lines.append(f"| p_fail_next (failure within the next {f['interval_h']:g} h): Brier score, skill against the "
                     f"fleet's event rate | {f['brier']:.4f}, skill {f['brier_skill']:.2f} ({f['events']} failures "
                     f"in {f['points']} points) | - | - |")
        for key in ("warn", "error"):
            w = f[key]
            lines.append(f"| {key.upper()} (p_fail_next >= {w['p']:g}): failures warned / false, true RUL "
                         f"beyond 2 checks | {w['events_raised']} of {f['events']} / {w['false']} of "
                         f"{w['far_points']} | - | - |")
        lines.append("| p_fail_next reliability: bin, points, mean predicted -> observed | "
                     + "; ".join(f"[{c['p_lo']:g}, {c['p_hi']:g}{']' if c['p_hi'] >= 1 else ')'} {c['n']}"
                                 + (f": {c['mean_p']:.3f} -> {c['observed']:.3f}" if c["n"] else "")
                                 for c in f["reliability"]) + " | - | - |")
    lines += ["", "targets: " + "; ".join(f"{k}: {'met' if v else 'NOT met'}" for k, v in r["targets"].items())]
    return "\n".join(lines)


def synthetic_history_csv(path: str | Path, n_actuators: int = 1000, n_tests: int = 25, seed: int = 0) -> Path:
    """A HISTORY.csv where every fault of every actuator degrades (linear, onset at 100 h, rate
    lognormal, noise 0.003): the worst case for the ``prognose`` timing target."""
    import csv
    rng = np.random.default_rng(seed)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    t = np.arange(n_tests) * 40.0
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["actuator_id", "time_h", *(f"k_{f}" for f in FAULTS), *(f"std_{f}" for f in FAULTS)])
        for a in range(n_actuators):
            ks = [np.clip(6e-4 * math.exp(0.3 * rng.standard_normal()) * np.maximum(t - 100, 0)
                          + rng.normal(0, 0.003, n_tests), 0, FAULT_UPPER) for _ in FAULTS]
            for i in range(n_tests):
                w.writerow([f"A{a:04d}", t[i], *(round(float(k[i]), 6) for k in ks), 0.003, 0.003, 0.003])
    return path


def time_prognose(n_actuators: int = 1000, path: str | Path | None = None) -> dict:
    """Wall time of ``prognose`` (thresholds included, computed afresh) on a synthetic history
    (written to ``path``, default a temporary file); then the monitor's step on that history as
    a SQLite file: its first step for an actuator with its own trend (no fleet prior needed), the
    first fit of the fleet prior (every actuator: the first step of an actuator that takes it),
    and such a step after another actuator's test (read the file, refit the changed actuator,
    prognose its own)."""
    import tempfile
    from ..prognostics.prior_cache import FleetPriorCache
    from ..prognostics.rul import prognose
    from ..prognostics.records import HealthRecord
    from ..prognostics.store import HistoryStore
    from ..prognostics.thresholds import _thresholds
    with tempfile.TemporaryDirectory() as tmp:
        p = synthetic_history_csv(path or Path(tmp) / f"history_{n_actuators}.csv", n_actuators)
        _thresholds.cache_clear()
        load0 = os.getloadavg()[0]
        t0, c0 = time.perf_counter(), time.process_time()
        obj = prognose(p)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        ids = sorted(obj["actuators"])
        with HistoryStore(Path(tmp) / "history.db") as st:
            st.import_csv(p)
            cache = FleetPriorCache()
            t0 = time.perf_counter()
            hist = st.history()
            prognose(hist, ids[0], priors=cache)       # as the monitor asks: the prior only if needed
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            cache.priors(hist)
            prior_fit = time.perf_counter() - t0
            other = st.list_tests(ids[-1])[-1]
            st.add_tests([HealthRecord(ids[-1], other["time_h"] + 40.0,
                                       tuple(min(other[f"k_{f}"] + 0.02, 1.0) for f in FAULTS), (0.003,) * 3)])
            t0 = time.perf_counter()
            hist = st.history()
            prognose(hist, ids[0], priors=cache.priors(hist))
            step = time.perf_counter() - t0
    # on a shared machine the wall time grows with the load; the process's CPU time much less
    return {"actuators": len(obj["actuators"]), "series": 3 * n_actuators, "wall_time_s": wall,
            "cpu_time_s": cpu, "monitor_first_step_s": first, "fleet_prior_fit_s": prior_fit,
            "monitor_step_s": step,
            "monitor_step_refitted": cache.refitted,
            "load_1min_before": load0, "load_1min_after": os.getloadavg()[0]}


MARK_BEGIN = "<!-- bench rul: begin (made by the command below; do not edit by hand) -->"
MARK_END = "<!-- bench rul: end -->"


def write_markdown(r: dict, path: str | Path, command: str) -> None:
    """The figures of a bench result, with the command that made them, into a Markdown file: between
    :data:`MARK_BEGIN` and :data:`MARK_END` if the file has them (the rest is kept), else the whole file."""
    import platform
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    block = "\n".join([MARK_BEGIN, "", f"`{command}` ({r['units']} units, {r['diagnoses']['diagnoses']} real "
                       f"diagnoses; predictions {r['prediction_wall_time_s']:.0f} s on {platform.machine()}, "
                       f"load {load:.1f}):", "", format_result(r), "", MARK_END])
    path = Path(path)
    text = path.read_text() if path.is_file() else ""
    if MARK_BEGIN in text and MARK_END in text:
        a, rest = text.split(MARK_BEGIN, 1)
        text = a + block + rest.split(MARK_END, 1)[1]
    else:
        text = block + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
