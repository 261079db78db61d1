"""Fault identification: fit the monitor's K_GM, K_FSJ, K_BKL to a measured FDI response.

Methods (``diagnose(..., method=...)``), each a chain of the engine's algorithms on one
:class:`~.problem.Problem` (the monitor with the three fault knobs, the measured record,
the fitness):

* ``deterministic`` -- paper Sec. V.A (:mod:`.sequential`): K_FSJ on the ramp pressure, then
  K_GM on the step position, then K_BKL on the ramp velocity; start point given, default
  from the coarse signature detector; finished by the local refinement when the fitness is
  ``lsq``.
* ``ga`` -- paper Sec. V.B (:mod:`.genetic`) on all three at once, then the local refinement.
* ``hybrid`` -- paper Sec. VII's proposal: the deterministic estimate seeds the GA
  population, then the local refinement. The default.

The ``lsq`` refinement is bounded least squares then a compass polish (:mod:`.local`); the
``paper`` fitness is refined by bounded Powell (the paper's fmincon hybrid function).

Uncertainty (:mod:`.uncertainty`): the Gauss-Newton covariance of the ``lsq`` residual at
the estimate, inflated for residual autocorrelation, plus in quadrature the monitor's
measured model-form error and the error sensor noise adds through stick-slip and backlash
events. ``std`` is the total, ``std_stat`` the Gauss-Newton part. Correlations above 0.95,
or a distinct fault combination in the final GA population that fits almost as well,
raise a "twin cases" warning.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..physics.faults import FAULT_NAMES, Faults
from ..physics.model import response_from_rows
from ..physics.packing import pack
from ..physics.params import ModelParams, load
from ..physics.sequence import FDISequence
from ..signals.channels import MEASURED
from ..signals.residuals import noise_level
from ..signals.response import Response
from .fitness import FITNESSES, fdi_stages, make_fitness
from .genetic import GAOptions, genetic
from .jacobian import jacobian
from .knobs import FAULT_KNOBS
from .local import compass, least_squares, powell
from .problem import KnobModel, Problem
from .record import fdi_record
from .residual import Residual
from .result import FitResult
from .sequential import sequential
from .signatures import Detector, signatures
from .uncertainty import (COVARIANCE_STEP_SCALE, autocorr_inflation, correlation, covariance, model_error, noise_error,
                          twin_warnings)

#: Identification methods.
METHODS = ("deterministic", "ga", "hybrid")
DEFAULT_METHOD = "hybrid"
#: Settings of the bounded least-squares refinement of a diagnosis.
REFINE = {"xtol": 1e-6, "max_nfev": 60}


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
                "start": self.start.as_dict() if self.start else None, "seed": self.seed}


def refine(problem: Problem, x0, history: list) -> FitResult:
    """The local finish of every method: least squares + compass (lsq), or Powell (paper)."""
    if isinstance(problem.objective, Residual):
        ls = least_squares(problem, x0, history=history, output=False, **REFINE)
        return compass(problem, ls.x, ls.cost, history=history)
    return powell(problem, x0, history)


def search(problem: Problem, method: str, x_start: np.ndarray, stages, seed: int, options: GAOptions,
           history: list, progress=None) -> FitResult:
    """The method's global search then the local refinement; returns the estimate."""
    def ga_progress(gen, best):
        if progress:
            progress(f"GA generation {gen:2d}  best fitness {best:.6g}")

    if method == "deterministic":
        x = sequential(problem, x_start, stages, history, progress).x
        if not isinstance(problem.objective, Residual):
            return FitResult(x, problem.model.names, problem.free, float("nan"), 0)
        return refine(problem, x, history)
    seeds = None
    if method == "hybrid":
        seeds = sequential(problem, x_start, stages, history, progress).x[None, :]
        options = GAOptions(**{**options.__dict__, "initial_spread": 0.05})
    g = genetic(problem, seed, options, seeds, ga_progress)
    history += g.history
    r = refine(problem, g.x, history)
    r.population, r.population_cost = g.population, g.population_cost
    return r


def start_point(model: KnobModel, response: Response, sequence: FDISequence) -> Faults:
    """The coarse detector's estimate from the response's signatures (0.5 each if they cannot be read)."""
    try:
        return _coarse_detector(model.base).coarse_estimate(signatures(response, sequence))
    except ValueError:
        return Faults(0.5, 0.5, 0.5)


def error_bars(problem: Problem, x: np.ndarray, position_noise_m: float):
    """``(sd, corr, sd_stat)`` at the estimate: Gauss-Newton (lsq residual, autocorrelation-inflated)
    plus the model-form and noise errors in quadrature."""
    r, J, _ = jacobian(problem, x, COVARIANCE_STEP_SCALE)
    cov_stat = covariance(J, r, autocorr_inflation(r, len(problem.objective.channels)))
    sd_stat = np.sqrt(np.maximum(np.diag(cov_stat), 0.0))
    extra = np.hypot(model_error(estimate=x), noise_error(position_noise_m))
    cov = cov_stat + np.diag(extra ** 2)
    return np.sqrt(np.maximum(np.diag(cov), 0.0)), correlation(cov), sd_stat


def diagnose(response: Response, method: str = DEFAULT_METHOD, fitness: str = "lsq", seed: int = 0,
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
    params : ModelParams, optional
        The monitor model (default: the shipped, calibrated one).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if fitness not in FITNESSES:
        raise ValueError(f"unknown fitness {fitness!r}; choose from {', '.join(FITNESSES)}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    t0 = time.perf_counter()
    seq = sequence or FDISequence()
    record = fdi_record(response, seq)
    model = KnobModel(params if params is not None else load("monitor"), FAULT_KNOBS, record)
    objective = make_fitness(fitness, record, seq)
    problem = Problem(model, objective)
    start = start if start is not None else start_point(model, response, seq)
    history: list[float] = []
    est = search(problem, method, np.array(start.as_tuple(), float), fdi_stages(objective, record, seq), seed,
                 ga_options or GAOptions(), history, progress)
    x = est.x
    cost, out = problem.cost_at(x)
    lsq = problem if isinstance(objective, Residual) else Problem(model, make_fitness("lsq", record, seq))
    sd, corr, sd_stat = error_bars(lsq, x, noise_level(response.position))
    warn = twin_warnings(corr, x, est.population, est.population_cost, cost)
    if np.any(x >= model.upper - 1e-6):
        warn.append("an estimate sits on the upper search bound: damage beyond the modelled range")
    fitted = response_from_rows(record.t, out, {"label": "monitor fit"})
    rms = {c: float(np.sqrt(np.mean((getattr(fitted, c) - getattr(response, c)) ** 2))) for c in MEASURED}
    return Diagnosis(faults=Faults(*(float(v) for v in x)), std=dict(zip(FAULT_NAMES, map(float, sd))),
                     std_stat=dict(zip(FAULT_NAMES, map(float, sd_stat))), correlation=corr, method=method,
                     fitness=fitness, cost=cost, evaluations=model.runs, wall_time_s=time.perf_counter() - t0,
                     history=history, warnings=warn, start=start, fitted=fitted, rms=rms, seed=int(seed))


_DETECTORS: dict = {}


def _coarse_detector(params: ModelParams):
    """Coarse detector built on the monitor model (cached per parameter set)."""
    key = pack(params).tobytes()
    if key not in _DETECTORS:
        _DETECTORS.clear()
        _DETECTORS[key] = Detector.build(params=params, kind="monitor")
    return _DETECTORS[key]
