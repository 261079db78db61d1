"""Fault identification: fit the monitor's K_GM, K_FSJ, K_BKL to a measured FDI response.

Methods (``diagnose(..., method=...)``):

* ``deterministic`` -- paper Sec. V.A: sequential, FSJ first (Nelder-Mead on the
  ramp pressure), then GM with that K_FSJ (Nelder-Mead on the step position), then
  BKL with both (bounded scalar search on the ramp velocity); start point given,
  default from the coarse signature detector; finished by a bounded least-squares
  refinement when the fitness is ``lsq``.
* ``ga`` -- paper Sec. V.B: pymoo GA on all three at once (:mod:`genetic`), then
  the local (hybrid-function) refinement.
* ``hybrid`` -- paper Sec. VII's proposal: the deterministic estimate seeds the GA
  population, then the local refinement. The default.

The ``lsq`` refinement is a trust-region least-squares fit followed by a compass
polish (:func:`compass_polish`), which finishes where stick-slip and backlash events
leave the cost too rough for finite-difference steps.

Uncertainty: from the Jacobian of the residual at the optimum (Gauss-Newton
covariance ``s^2 (J'J)^-1``), inflated by the residual autocorrelation (effective
sample size), plus, in quadrature, the monitor model's measured model-form error
(``data/model_error.yaml``: the RMS error on clean reference runs, which no fit
residual can reveal) and the error the sensor noise adds through the loop's
stick-slip and backlash events (the excess RMS error on noisy runs, scaled by the
position noise measured in the data). ``std`` is the total, ``std_stat`` the
Gauss-Newton part.
Correlations between coefficients above 0.95, or a distinct fault combination in
the final GA population that fits almost as well, raise a "twin cases" warning.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import least_squares, minimize, minimize_scalar

from .fitness import CHANNEL_SCALES, LsqFitness, Measured, PaperFitness, make_fitness
from .genetic import GAOptions, run_ga
from ..physics.layout import O_P12, O_POS, O_VEL
from ..physics.model import response_from_rows, simulate_batch
from ..physics.faults import Faults
from ..physics.params import ModelParams, load
from ..signals.residuals import noise_level
from ..signals.response import Response
from ..physics.sequence import FDISequence

NAMES = ("k_gm", "k_fsj", "k_bkl")
METHODS = ("deterministic", "ga", "hybrid")
UPPER = 1.5        # default upper bound of every coefficient (beyond-limit damage findable)


@dataclass
class Diagnosis:
    """Result of one identification (scipy.optimize-style result object)."""
    faults: Faults                      # estimated coefficients
    std: dict[str, float]               # standard errors (noise and model-form error)
    std_stat: dict[str, float]          # the noise part alone (Gauss-Newton)
    correlation: np.ndarray             # 3x3 correlation of the estimates
    method: str
    fitness: str
    cost: float                         # final fitness value
    evaluations: int                    # monitor simulations run
    wall_time_s: float
    history: list[float] = field(default_factory=list)   # best cost per iteration/generation
    warnings: list[str] = field(default_factory=list)
    start: Faults | None = None
    fitted: Response | None = None      # monitor response at the estimate
    rms: dict[str, float] = field(default_factory=dict)  # per-channel RMS fitted - measured [SI]
    seed: int = 0

    def as_dict(self) -> dict:
        k = self.faults
        return {"k_gm": k.k_gm, "k_fsj": k.k_fsj, "k_bkl": k.k_bkl, "std": self.std, "std_stat": self.std_stat,
                "correlation": np.round(self.correlation, 4).tolist(), "method": self.method,
                "fitness": self.fitness, "cost": self.cost, "evaluations": self.evaluations,
                "wall_time_s": self.wall_time_s, "warnings": self.warnings, "rms": self.rms,
                "start": dict(zip(NAMES, self.start.as_tuple())) if self.start else None, "seed": self.seed}


class Evaluator:
    """Runs the monitor for batches of fault coefficients (all cores) and counts runs."""

    def __init__(self, meas: Measured, params: ModelParams | None = None):
        p = params if params is not None else load("monitor")
        rate = meas.response.sample_rate
        if abs(rate - p.integration.sample_rate) > 1e-6 * rate:
            p = p.updated("integration", sample_rate=round(rate, 6))
        self.params = p
        self.cmd = np.ascontiguousarray(meas.command, dtype=float)
        self.n = 0

    def run(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        faults = [Faults(*np.maximum(x, 0.0)) for x in X]
        self.n += len(faults)
        return simulate_batch(self.params, faults, self.cmd)

    def one(self, x) -> np.ndarray:
        return self.run(x)[0]


# --------------------------------------------------------------------------- local refinement
def _perturbed(x: np.ndarray, h: float, upper: float):
    """The point and its three forward perturbations (backward at the upper bound), and the steps."""
    steps = np.where(x + h <= upper, h, -h)
    return np.vstack([x, x + np.diag(steps)]), steps


def _jacobian(fit: LsqFitness, outs: np.ndarray, steps: np.ndarray):
    """Residual at the point and its finite-difference Jacobian from one batch of outputs."""
    r0 = fit.residuals(outs[0])
    return r0, np.column_stack([(fit.residuals(outs[i + 1]) - r0) / steps[i] for i in range(3)])


def refine_lsq(ev: Evaluator, fit: LsqFitness, x0: np.ndarray, upper: float = UPPER, history=None):
    """Bounded least squares (trust-region reflective) with a batched finite-difference Jacobian."""
    h = 2e-3
    cache: dict = {}

    def outs_at(x):
        key = tuple(np.round(x, 12))
        if key not in cache:
            X, steps = _perturbed(x, h, upper)   # one parallel batch
            cache.clear()
            cache[key] = (ev.run(X), steps)
        return cache[key]

    def fun(x):
        r = fit.residuals(outs_at(x)[0][0])
        if history is not None:
            history.append(float(r @ r))
        return r

    def jac(x):
        return _jacobian(fit, *outs_at(x))[1]

    x0 = np.clip(np.asarray(x0, float), 0.0, upper)
    sol = least_squares(fun, x0, jac=jac, bounds=(np.zeros(3), np.full(3, upper)), method="trf",
                        x_scale=np.full(3, 0.1), xtol=1e-6, ftol=1e-10, gtol=1e-10, max_nfev=60)
    return compass_polish(ev, fit, sol.x, float(2 * sol.cost), upper, history)


def compass_polish(ev: Evaluator, fit, x: np.ndarray, cost: float, upper: float = UPPER, history=None,
                   step: float = 4e-3, min_step: float = 2.5e-4):
    """Derivative-free finish: try +-step on each coefficient (one parallel batch of six), move to
    the best that lowers the cost, halve the step when none does, down to ``min_step``.

    Stick-slip and backlash events leave the cost slightly rough on the scale of the
    finite-difference step, where trust-region steps built on that Jacobian stall
    (measured: TRF stopped 0.003 short in K_FSJ on a valley that falls by 3 %).
    """
    x = np.asarray(x, float).copy()
    while step >= min_step:
        X = np.clip(np.vstack([x + s * e for e in np.eye(3) for s in (step, -step)]), 0.0, upper)
        c = fit.costs(ev.run(X))
        i = int(np.argmin(c))
        if c[i] < cost:
            x, cost = X[i], float(c[i])
            if history is not None:
                history.append(cost)
        else:
            step /= 2
    return x, cost


def refine_paper(ev: Evaluator, fit: PaperFitness, x0: np.ndarray, upper: float = UPPER, history=None):
    """The paper's hybrid function (fmincon): bounded local search on the combined GA fitness."""
    def f(x):
        c = fit.cost(ev.one(x))
        if history is not None:
            history.append(c)
        return c
    sol = minimize(f, np.clip(x0, 0, upper), method="Powell", bounds=[(0.0, upper)] * 3,
                   options={"xtol": 1e-4, "ftol": 1e-8, "maxfev": 200})
    return sol.x, float(sol.fun)


def refine(ev, fit, x0, upper=UPPER, history=None):
    if isinstance(fit, LsqFitness):
        return refine_lsq(ev, fit, x0, upper, history)
    return refine_paper(ev, fit, x0, upper, history)


# --------------------------------------------------------------------------- deterministic
def _stage_objectives(fit, meas: Measured):
    """Per-fault objectives of the sequential method: (FSJ, GM, BKL) functions of one output."""
    if isinstance(fit, PaperFitness):
        return fit.fsj, fit.gm, fit.bkl
    r = meas.response
    ramp, step = meas.mask("ramp"), meas.mask("step")
    sc = {"p": CHANNEL_SCALES["pressure"], "x": CHANNEL_SCALES["position"], "v": CHANNEL_SCALES["velocity"]}

    def fsj(o):
        return float(np.mean(((o[ramp, O_P12] - r.pressure[ramp]) / sc["p"]) ** 2))

    def gm(o):
        return float(np.mean(((o[step, O_POS] - r.position[step]) / sc["x"]) ** 2))

    def bkl(o):
        return float(np.mean(((o[ramp, O_VEL] - r.velocity[ramp]) / sc["v"]) ** 2)
                     + np.mean(((o[ramp, O_POS] - r.position[ramp]) / sc["x"]) ** 2))
    return fsj, gm, bkl


def run_deterministic(ev: Evaluator, fit, meas: Measured, x0: np.ndarray, upper: float = UPPER,
                      history=None, progress=None) -> np.ndarray:
    """Sequential FSJ -> GM -> BKL (paper V.A); returns the coefficient vector."""
    f_fsj, f_gm, f_bkl = _stage_objectives(fit, meas)
    x = np.clip(np.asarray(x0, float), 0.0, upper)

    def stage(i, obj, label):
        def f(v):
            xi = x.copy()
            xi[i] = float(np.clip(np.ravel(v)[0], 0.0, upper))
            c = obj(ev.one(xi))
            if history is not None:
                history.append(c)
            return c
        if i == 2:   # BKL: bounded (fmincon-like); backlash cannot be negative
            sol = minimize_scalar(f, bounds=(0.0, upper), method="bounded", options={"xatol": 1e-4})
            v = sol.x
        else:        # fminsearch-like
            sol = minimize(f, [max(x[i], 0.05)], method="Nelder-Mead",
                           options={"xatol": 1e-4, "fatol": 1e-12, "initial_simplex": [[max(x[i], 0.05)], [max(x[i], 0.05) + 0.1]]})
            v = sol.x[0]
        x[i] = float(np.clip(v, 0.0, upper))
        if progress:
            progress(f"deterministic: {label} -> {x[i]:.4f}")

    stage(1, f_fsj, "K_FSJ")
    stage(0, f_gm, "K_GM")
    stage(2, f_bkl, "K_BKL")
    return x


# --------------------------------------------------------------------------- uncertainty
def _autocorr_inflation(res: np.ndarray, n_channels: int) -> float:
    """Variance inflation 1 + 2 sum(rho_k) of the residual, averaged over channels (Bartlett)."""
    r = res.reshape(-1, n_channels)
    total, weight = 0.0, 0.0
    for c in range(n_channels):
        x = r[:, c] - r[:, c].mean()
        v = float(x @ x)
        if v <= 0:
            continue
        n = len(x)
        f = np.fft.rfft(x, 2 * n)
        ac = np.fft.irfft(f * np.conj(f))[:n] / v
        s = 0.0
        for k in range(1, min(n // 4, 400)):
            if ac[k] < 0.05:
                break
            s += ac[k] * (1 - k / n)
        total += v * (1 + 2 * s)
        weight += v
    return total / weight if weight > 0 else 1.0


def uncertainty(ev: Evaluator, fit: LsqFitness, x: np.ndarray, upper: float = UPPER,
                model_sd: np.ndarray | None = None):
    """Standard errors and correlation of the estimate at ``x`` (lsq residual).

    Returns ``(sd, corr, sd_stat)``: ``sd_stat`` from the Gauss-Newton covariance
    (noise, inflated for residual autocorrelation); ``sd`` adds the monitor model's
    own (model-form) error ``model_sd`` in quadrature, since the fit residual cannot
    reveal a bias that the model shares with itself.
    """
    X, steps = _perturbed(x, 5e-3, upper)
    r0, J = _jacobian(fit, ev.run(X), steps)
    m = len(r0)
    s2 = float(r0 @ r0) / max(m - 3, 1)
    JtJ = J.T @ J
    try:
        cov = np.linalg.pinv(JtJ) * s2 * _autocorr_inflation(r0, len(fit.meas.channels))
    except np.linalg.LinAlgError:
        cov = np.full((3, 3), np.inf)
    sd_stat = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if model_sd is not None:
        cov = cov + np.diag(np.asarray(model_sd, float) ** 2)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.nan_to_num(corr)
    np.fill_diagonal(corr, 1.0)
    return sd, corr, sd_stat


@functools.lru_cache(maxsize=None)
def _error_file(path: str | None) -> dict:
    import yaml
    from importlib import resources
    where = path or "data/model_error.yaml"
    text = Path(path).read_text() if path else resources.files("eha_health").joinpath(
        "data/model_error.yaml").read_text()
    data = yaml.safe_load(text) or {}

    def triple(key: str, required: bool) -> tuple[float, float, float]:
        sd = data.get(key)
        if sd is None and not required:
            return (0.0, 0.0, 0.0)
        try:
            vals = tuple(float(sd[n]) for n in NAMES)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"model error file {where}: needs {key} with {', '.join(NAMES)}") from None
        if not all(np.isfinite(v) and v >= 0 for v in vals):
            raise ValueError(f"model error file {where}: {key} values must be finite and >= 0, got {vals}")
        return vals

    out = {"model": triple("model_error_sd", True), "noise": triple("noise_error_sd", False)}
    var = data.get("model_error_variance")
    if var is not None:
        try:
            c = np.array([[float(v) for v in var[n]] for n in NAMES])
        except (KeyError, TypeError, ValueError):
            c = None
        if c is None or c.shape != (3, 4) or not (np.isfinite(c).all() and (c >= 0).all()):
            raise ValueError(f"model error file {where}: model_error_variance needs, for each of "
                             f"{', '.join(NAMES)}, four coefficients >= 0 (constant, K_GM, K_FSJ, K_BKL)")
        out["variance"] = c
    else:
        out["variance"] = None
    ref = data.get("noise_reference_m")
    if any(out["noise"]) and not (isinstance(ref, (int, float)) and ref > 0):
        raise ValueError(f"model error file {where}: noise_error_sd needs noise_reference_m > 0 [m]")
    out["noise_reference_m"] = float(ref) if ref else 0.0
    return out


def model_error(path: str | Path | None = None, estimate=None) -> np.ndarray:
    """Model-form error of the monitor model, 1 sd per coefficient (data/model_error.yaml).

    Measured on clean reference runs (no noise, so all of it is model mismatch); the
    file records the command that made it. Without ``estimate``: the RMS error over those
    runs. With the estimated (K_GM, K_FSJ, K_BKL) and a ``model_error_variance`` block:
    the error grows with the damage, var_k = c_k0 + c_k1 K_GM + c_k2 K_FSJ + c_k3 K_BKL
    (non-negative least squares of the squared errors on the same runs).
    """
    f = _error_file(str(path) if path else None)
    if estimate is None or f["variance"] is None:
        return np.array(f["model"])
    k = np.clip(np.asarray(estimate, float), 0.0, None)
    return np.sqrt(f["variance"] @ np.concatenate([[1.0], k]))


def noise_error(position_noise_m: float, path: str | Path | None = None) -> np.ndarray:
    """Error the sensor noise adds beyond the Gauss-Newton term, 1 sd per coefficient.

    Noise inside the loop moves the stick-slip and backlash events, which a local
    linearisation cannot see. Measured as the excess RMS error over noisy reference runs
    (``noise_error_sd`` at position noise ``noise_reference_m``) and scaled linearly with
    the position noise measured in the data [m].
    """
    f = _error_file(str(path) if path else None)
    if f["noise_reference_m"] <= 0:
        return np.zeros(3)
    return np.array(f["noise"]) * (max(float(position_noise_m), 0.0) / f["noise_reference_m"])


def twin_warnings(corr: np.ndarray, x: np.ndarray, pop=None, pop_cost=None, cost=None) -> list[str]:
    out = []
    for i in range(3):
        for j in range(i + 1, 3):
            if abs(corr[i, j]) > 0.95:
                out.append(f"twin cases: {NAMES[i]} and {NAMES[j]} are correlated (rho={corr[i, j]:+.2f}); "
                           f"other combinations of the two explain the data almost as well")
    if pop is not None and cost is not None and cost > 0:
        for xp, cp in zip(pop, pop_cost):
            if np.max(np.abs(xp - x)) > 0.1 and cp < 1.05 * cost:
                out.append("twin cases: the GA population holds gm={:.3f} fsj={:.3f} bkl={:.3f} with fitness within "
                           "5 % of the estimate".format(*xp))
                break
    return out


# --------------------------------------------------------------------------- API
def diagnose(response: Response, method: str = "hybrid", fitness: str = "lsq", seed: int = 0,
             start: Faults | None = None, params: ModelParams | None = None,
             sequence: FDISequence | None = None, ga_options: GAOptions | None = None,
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Identify the fault coefficients from one measured FDI response.

    Parameters
    ----------
    response : Response
        Measured test (channels position, velocity, pressure, current and the command).
    method : {'hybrid', 'deterministic', 'ga'}
    fitness : {'lsq', 'paper'}
    seed : int
        Seed of every random choice (GA); the same seed gives the same diagnosis.
    start : Faults, optional
        Start point of the deterministic search (default: the coarse detector's estimate).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    t0 = time.perf_counter()
    seq = sequence or FDISequence()
    meas = Measured.from_response(response, seq)
    fit = make_fitness(fitness, meas)
    ev = Evaluator(meas, params)
    opts = ga_options or GAOptions()
    history: list[float] = []
    warn: list[str] = []
    pop = pop_cost = None

    if start is None:
        from .signatures import signatures
        try:
            start = _coarse_detector(ev.params).coarse_estimate(signatures(response, seq))
        except ValueError:
            start = Faults(0.5, 0.5, 0.5)
    x_start = np.array(start.as_tuple(), float)

    def ga_progress(gen, best):
        if progress:
            progress(f"GA generation {gen:2d}  best fitness {best:.6g}")

    cost_batch = (lambda X: fit.costs(ev.run(X)))
    if method == "deterministic":
        x = run_deterministic(ev, fit, meas, x_start, history=history, progress=progress)
        if fitness == "lsq":
            x, _ = refine(ev, fit, x, history=history)
    elif method == "ga":
        g = run_ga(cost_batch, seed, opts, progress=ga_progress)
        history += g.history
        pop, pop_cost = g.population, g.population_cost
        x, _ = refine(ev, fit, g.x, opts.upper, history)
    else:
        xd = run_deterministic(ev, fit, meas, x_start, history=history, progress=progress)
        seeded = GAOptions(**{**opts.__dict__, "initial_spread": 0.05})
        g = run_ga(cost_batch, seed, seeded, seeds=xd[None, :], progress=ga_progress)
        history += g.history
        pop, pop_cost = g.population, g.population_cost
        x, _ = refine(ev, fit, g.x, opts.upper, history)

    out = ev.one(x)
    cost = float(fit.cost(out))
    lsq = fit if isinstance(fit, LsqFitness) else LsqFitness(meas)
    sd, corr, sd_stat = uncertainty(ev, lsq, x, opts.upper,
                                    np.hypot(model_error(estimate=x), noise_error(noise_level(response.position))))
    warn += twin_warnings(corr, x, pop, pop_cost, cost)
    if np.any(x >= opts.upper - 1e-6):
        warn.append("an estimate sits on the upper search bound: damage beyond the modelled range")
    fitted = response_from_rows(meas.t, out, {"label": "monitor fit"})
    rms = {c: float(np.sqrt(np.mean((getattr(fitted, c) - getattr(response, c)) ** 2)))
           for c in ("position", "velocity", "pressure", "current")}
    return Diagnosis(faults=Faults(*(float(v) for v in x)), std=dict(zip(NAMES, map(float, sd))),
                     std_stat=dict(zip(NAMES, map(float, sd_stat))), correlation=corr, method=method, fitness=fitness, cost=cost, evaluations=ev.n,
                     wall_time_s=time.perf_counter() - t0, history=history, warnings=warn, start=start,
                     fitted=fitted, rms=rms, seed=int(seed))


_DETECTORS: dict = {}


def _coarse_detector(params: ModelParams):
    """Coarse detector built on the monitor model (cached per parameter set)."""
    from .signatures import Detector
    from ..physics.packing import pack
    key = pack(params).tobytes()
    if key not in _DETECTORS:
        _DETECTORS.clear()
        _DETECTORS[key] = Detector.build(params=params, kind="monitor")
    return _DETECTORS[key]
