"""Fault identification: fit the monitor's K_GM, K_FSJ, K_BKL to a measured FDI response.

Methods (``diagnose(..., method=...)``), each a chain of the engine's algorithms on one
:class:`~.problem.Problem` (the monitor with the three fault knobs, the measured record,
the fitness):

* ``fast`` -- the default: the paper's three stage objectives (:func:`~.fitness.fdi_stages`)
  stacked into one residual (:func:`~.fitness.fdi_stage_residual`) and solved jointly by
  bounded least squares (one batched Jacobian, four monitor runs in parallel, per iteration)
  from the signature tables' start (:mod:`.start`). Those segments carry no backlash impacts
  of the sine, so that residual is smooth in the coefficients where the whole-test ``lsq``
  cost is a saw-tooth (period ~0.0075 in K_BKL). The global guard: when the fit quality (the
  stage cost over the model's floor plus the cost the measured noise explains) exceeds
  :data:`GUARD_FACTOR`, the start was in a wrong basin or the model misses something, and the
  ``hybrid`` global search runs from the same start (its estimate then finished by the same
  joint least squares when that fit passes); ``guard`` and the warnings say so.
* ``deterministic`` -- paper Sec. V.A (:mod:`.sequential`): K_FSJ on the ramp pressure, then
  K_GM on the step position, then K_BKL on the ramp velocity; start point given, default
  from the coarse signature detector; finished by the local refinement when the fitness is
  ``lsq``.
* ``ga`` -- paper Sec. V.B (:mod:`.genetic`) on all three at once, then the local refinement.
* ``hybrid`` -- paper Sec. VII's proposal: the deterministic estimate seeds the GA
  population, then the local refinement (the default before ``fast``; the discrepancy loop
  starts from it).

A stage channel with no sample left on its segments (a dead transducer, set aside whole by the
cleaning: :func:`~.fitness.blind_stages`) leaves the stage objectives and the start blind to its
coefficients: every method but ``ga`` then runs ``ga`` on the whole test instead, and says so.

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

import threading
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from ..physics.faults import FAULT_NAMES, Faults
from ..physics.model import response_from_rows
from ..physics.packing import pack
from ..physics.params import ModelParams, load
from ..physics.sequence import FDISequence
from ..signals.channels import MEASURED
from ..signals.cleaning import Cleaned
from ..signals.cleaning import clean as clean_channels
from ..signals.residuals import noise_level
from ..signals.response import Response
from .fitness import FITNESSES, blind_stages, fdi_stage_residual, fdi_stages, make_fitness
from .genetic import GAOptions, genetic
from .jacobian import jacobian
from .knobs import FAULT_KNOBS
from .local import compass, least_squares, powell
from .problem import COMMAND_RATE_HZ, KnobModel, Problem, oversampling
from .record import fdi_record, logged_command
from .units import check_units
from .residual import Residual
from .result import FitResult
from .sequential import sequential
from .start import StartTable
from .uncertainty import (COVARIANCE_STEP_SCALE, autocorr_inflation, correlation, covariance, fit_floor,
                          measured_error, twin_warnings)

#: Identification methods.
METHODS = ("fast", "deterministic", "ga", "hybrid")
DEFAULT_METHOD = "fast"
#: Methods whose ``lsq`` estimate is refined on the whole-test residual (``fast`` fits the stage
#: segments only: on the whole test it sits beside a minimum of the saw-tooth in K_BKL).
WHOLE_TEST_METHODS = ("deterministic", "ga", "hybrid")
#: Settings of the bounded least-squares refinement of a diagnosis.
REFINE = {"xtol": 1e-6, "max_nfev": 60}
#: Settings of the fast method's joint least squares (xtol is relative to the knobs' typical 0.1:
#: it stops when a step moves the coefficients by < ~1e-5, far below the model-form error).
FAST = {"xtol": 1e-4, "max_nfev": 30}
#: The global guard fires when the fast fit's stage cost exceeds this many times the model's floor
#: (``fit_floor`` of data/model_error.yaml) plus the cost the measured noise explains.
GUARD_FACTOR = 4.0
#: Offsets of :func:`probe` along each coefficient [-]: the stage cost has cliffs where a discrete
#: event (a stick, a contact in the play) appears or vanishes; the least squares can stop on the
#: wrong side of one, ~0.001 from the truth at 30x the floor (seen at (0.051, 0.465, 0.930)).
PROBE_STEPS = np.array([0.001, 0.003, 0.009])


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
    rms: dict[str, float] = field(default_factory=dict)  # per recorded channel: RMS fitted - measured [SI]
    seed: int = 0
    fit_cost: float = float("nan")      # stage cost at the estimate (fitness.fdi_stage_residual) [-]
    fit_quality: float = float("nan")   # stage cost / (model floor + noise cost) at the estimate [-]
    command_rate: float = float("nan")  # rate at which the monitor held the command [Hz] (the record's, or
    #                                     faster with the command interpolated: problem.oversampling)
    guard: str = ""                     # fast method: "passed", "after a test" (did not start at rest:
    #                                     fitted with the preamble), "probed" (failed, then passed from
    #                                     a neighbouring point: :func:`probe`), "fired" (fell back to the
    #                                     global search), "blind" (a stage channel had no sample left:
    #                                     the GA ran on the whole test) or "unjudged" (paper fitness,
    #                                     or no fit_floor)

    def as_dict(self) -> dict:
        k = self.faults
        return {"k_gm": k.k_gm, "k_fsj": k.k_fsj, "k_bkl": k.k_bkl, "std": self.std, "std_stat": self.std_stat,
                "correlation": np.round(self.correlation, 4).tolist(), "method": self.method,
                "fitness": self.fitness, "cost": self.cost, "evaluations": self.evaluations,
                "wall_time_s": self.wall_time_s, "warnings": self.warnings, "rms": self.rms,
                "start": self.start.as_dict() if self.start else None, "seed": self.seed,
                "fit_cost": self.fit_cost, "fit_quality": self.fit_quality, "guard": self.guard,
                "command_rate_hz": self.command_rate}


def refine(problem: Problem, x0, history: list) -> FitResult:
    """The local finish of every method: least squares + compass (lsq), or Powell (paper)."""
    if isinstance(problem.objective, Residual):
        ls = least_squares(problem, x0, history=history, output=False, **REFINE)
        return compass(problem, ls.x, ls.cost, history=history)
    return powell(problem, x0, history)


def _staged(model: KnobModel, stage_residual, free=None) -> Problem:
    """The fit of the stage residual, its runs stopped after the last sample it reads (the step's end:
    1.5 s of the 3.5 s test; :meth:`~.problem.KnobModel.until`)."""
    return Problem(model.until(getattr(stage_residual, "horizon", None)), stage_residual, free)


def search(problem: Problem, method: str, x_start: np.ndarray, stages, seed: int, options: GAOptions,
           history: list, progress=None, stage_residual=None) -> FitResult:
    """The method's global search then the local refinement; returns the estimate (``fast``: its
    cost is the stage residual's)."""
    def ga_progress(gen, best):
        if progress:
            progress(f"GA generation {gen:2d}  best fitness {best:.6g}")

    if method == "fast":
        r = least_squares(_staged(problem.model, stage_residual), x_start, history=history, output=False, **FAST)
        if progress:
            progress("fast: joint least squares on the stage residual -> "
                     + " ".join(f"{n}={v:.4f}" for n, v in zip(FAULT_NAMES, r.x)))
        return r
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
    """The signature tables' estimate (:mod:`.start`; 0.5 each if the signatures cannot be read)."""
    try:
        k = _start_table(model.base, sequence).estimate_response(response, sequence)
    except ValueError:
        return Faults(0.5, 0.5, 0.5)
    # a channel not recorded (all NaN) leaves its coefficient's signature unread
    return Faults(*(v if np.isfinite(v) else 0.5 for v in k.as_tuple()))


def error_bars(problem: Problem, x: np.ndarray, position_noise_m: float, method: str = DEFAULT_METHOD):
    """``(sd, corr, sd_stat, out)`` at the estimate: Gauss-Newton (lsq residual, autocorrelation-inflated)
    plus the model-form and noise errors of the ``method`` that found ``x``, in quadrature; ``out`` is
    the model output at ``x``."""
    r, J, out = jacobian(problem, x, COVARIANCE_STEP_SCALE)
    cov_stat = covariance(J, r, autocorr_inflation(r, len(problem.objective.channels)))
    sd_stat = np.sqrt(np.maximum(np.diag(cov_stat), 0.0))
    extra = measured_error(x, position_noise_m, method)
    cov = cov_stat + np.diag(extra ** 2)
    return np.sqrt(np.maximum(np.diag(cov), 0.0)), correlation(cov), sd_stat, out


def fit_quality(stage_residual, stage_cost: float, record) -> float:
    """Stage cost over what a right fit leaves: the model's floor (``fit_floor``, clean runs) plus
    the expected cost of the noise measured in each channel (second differences) [-]."""
    floor = fit_floor()
    if floor is None or not isinstance(stage_residual, Residual):
        # not measured yet (the clean bench that measures it runs unguarded), or the paper's
        # feature fitness, whose floor is not measured: the guard cannot judge
        return float("nan")
    sigma = {c: noise_level(v) for c, v in record.channels.items()}
    return float(stage_cost / (floor + stage_residual.expected_noise_cost(sigma)))


#: A test is fitted as following another (:func:`after_a_test`) when the stage cost from rest is
#: above this share of the cost with the preamble at the same estimate. Measured on 10 triples: a
#: test from rest gives <= 0.42 with the default sensor noise (<= 0.001 clean) where it has play,
#: up to ~1 without play; one after a test >= 0.75 (>= 459 clean); the whole-test cost then chooses.
AFTER_TEST_RATIO = 0.5
#: ... and the pressure before the actuator answers the ramp (:data:`HELD_WINDOW_S`) holds a load
#: pressure: its mean above this many standard errors of the channel's noise (second differences).
#: Measured on 40 random triples after a test: 41 kPa to 1.1 MPa held; the default noise is 20 kPa,
#: 14 kPa on the mean of the two samples at 1 kHz, so 2.5 sd = 35 kPa. From rest it is 0 plus noise:
#: 1.2 % of tests from rest pay the comparison run (a single sample at 2 sd: 4.6 %, and where the
#: fault has no play the preamble then explains the stage segments as well, so the whole
#: after-a-test fit ran: ~80 runs more, seen on the noisy paper case (1, 0, 0)).
HELD_PRESSURE_SD = 2.5
#: The pressure answers the ramp (which starts at t = 0) 1-2 ms later (measured at 1 kHz: the
#: samples at 0 and 1 ms are the held pressure, the one at 2 ms moves) [s].
HELD_WINDOW_S = 0.0015


def after_a_test(model: KnobModel, objective, stage, sequence: FDISequence, est: FitResult, q: float,
                 history: list, progress=None):
    """The fast fit of a test that follows another one, when the data say so; else None.

    The monitor starts at rest, jack centred in its play. After an earlier test the actuator
    rests where dry friction stopped it: off the command, holding a load pressure, the jack
    against one side of the play. A fit from rest then misses (the guard fires) or, with
    noise, passes with K_BKL read off a take-up that did not happen. With the test's preamble
    (:meth:`FDISequence.preamble`, simulated first) the monitor starts where the same
    history leaves it. Tried when the fit from rest fails the guard or the preamble explains
    the stage segments nearly as well (:data:`AFTER_TEST_RATIO`, one run), the latter only when the
    pressure before the ramp is answered holds a load (:data:`HELD_PRESSURE_SD`; a test from rest then
    costs no run more); kept when it passes the guard and leaves a lower whole-test cost. Returns
    ``(model, est, quality, note)``."""
    record = model.record
    p12 = record.channels.get("pressure")
    held = False
    if p12 is not None:
        still = p12[record.t - record.t[0] < HELD_WINDOW_S]
        held = abs(np.mean(still)) > HELD_PRESSURE_SD * noise_level(p12) / np.sqrt(len(still))
    if not held and not q > GUARD_FACTOR:
        return None
    after = KnobModel(model.base, FAULT_KNOBS, replace(record, preroll=sequence.preamble(record.sample_rate)))
    pre_cost = stage.cost(after.run(est.x)[0])
    if not est.cost > AFTER_TEST_RATIO * pre_cost:
        model.runs += after.runs
        return None
    x = least_squares(_staged(after, stage), est.x, history=history, output=False, **FAST).x
    # the stage segments read K_BKL from the take-up of the play before the first ramp, and a
    # jack left against the side the ramp pushes it to takes none: the sine's reversals, on the
    # whole-test residual, tell it; then K_GM and K_FSJ again, with it
    x = backlash_scan(Problem(after, objective), x, history)
    follow = least_squares(_staged(after, stage, np.array([0, 1])), x, history=history, output=False, **FAST)
    q_after = fit_quality(stage, follow.cost, record)
    whole_rest, whole_after = objective.cost(model.run(est.x)[0]), objective.cost(after.run(follow.x)[0])
    if progress:
        progress("after a test: " + " ".join(f"{n}={v:.4f}" for n, v in zip(FAULT_NAMES, follow.x))
                 + f", fit quality {q_after:.2f}, whole-test cost {whole_after:.4g} vs {whole_rest:.4g} from rest")
    if not (q_after <= GUARD_FACTOR and whole_after < whole_rest):
        model.runs += after.runs
        return None
    after.runs += model.runs
    note = (f"the test followed an earlier one: fitted from where its end and the return to start leave the "
            f"actuator (FDISequence.preamble, {len(after.record.preroll) / record.sample_rate:g} s simulated "
            f"first): fit quality {q_after:.2f}, whole-test cost {whole_after:.4g} vs {whole_rest:.4g} from rest")
    return after, follow, q_after, note


def probe(problem: Problem, est: FitResult, history: list) -> FitResult | None:
    """The fast fit restarted from the best of a few points beside ``est`` (one batch: ``est.x`` plus
    and minus :data:`PROBE_STEPS` along each coefficient), or None if none of them is lower. For a
    fit stopped at a cliff of the stage cost next to the right basin; a wrong basin far away stays
    where it is, and the guard then judges the restart as it judged the fit."""
    x = np.asarray(est.x, float)
    steps = np.concatenate([-PROBE_STEPS[::-1], PROBE_STEPS])
    X = np.repeat(x[None, :], 3 * len(steps), axis=0)
    for i in range(3):
        X[i * len(steps):(i + 1) * len(steps), i] += steps
    X = np.clip(X, problem.model.lower, problem.model.upper)
    costs = problem.costs(X)
    history += list(costs)
    b = int(np.argmin(costs))
    if not costs[b] < est.cost:
        return None
    return least_squares(problem, X[b], history=history, output=False, **FAST)


#: K_BKL grid of :func:`backlash_scan` (one parallel batch), finer than the whole-test cost's bowl
BACKLASH_GRID = np.linspace(0.0, 1.0, 41)


def backlash_scan(problem: Problem, x, history: list) -> np.ndarray:
    """``x`` with K_BKL minimising ``problem``'s cost, the others held: a grid (one batch), then a
    bounded scalar search between the best point's neighbours (the cost is a saw-tooth of period
    ~0.0075 in K_BKL on a broad bowl: the grid finds the bowl, the scalar search its tooth)."""
    i = FAULT_NAMES.index("k_bkl")
    X = np.repeat(np.asarray(x, float)[None, :], len(BACKLASH_GRID), axis=0)
    X[:, i] = BACKLASH_GRID
    costs = problem.costs(X)
    history += list(costs)
    b = int(np.argmin(costs))
    lo, hi = BACKLASH_GRID[max(b - 1, 0)], BACKLASH_GRID[min(b + 1, len(BACKLASH_GRID) - 1)]

    def f(v):
        xi = np.array(x, float)
        xi[i] = v
        c = problem.cost_at(xi)[0]
        history.append(c)
        return c
    sol = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    out = np.array(x, float)
    out[i] = sol.x if sol.fun <= costs[b] else BACKLASH_GRID[b]
    return out


def diagnose(response: Response, method: str = DEFAULT_METHOD, fitness: str = "lsq", seed: int = 0,
             start: Faults | None = None, params: ModelParams | None = None,
             sequence: FDISequence | None = None, ga_options: GAOptions | None = None,
             progress: Callable[[str], None] | None = None, clean: bool = True,
             command_rate: float | None = None) -> Diagnosis:
    """Identify the fault coefficients from one measured FDI response.

    Parameters
    ----------
    response : Response
        Measured test (channels position, velocity, pressure, current and the command).
    method : {'fast', 'hybrid', 'deterministic', 'ga'}
    fitness : {'lsq', 'paper'}
    seed : int
        Seed of every random choice (GA); the same seed gives the same diagnosis.
    start : Faults, optional
        Start point of the search (default: the signature tables' estimate, :func:`start_point`).
    params : ModelParams, optional
        The monitor model (default: the shipped, calibrated one).
    clean : bool
        With the ``lsq`` fitness: check the recording against the fitted model
        (:func:`~eha_health.signals.cleaning.clean`) and, where it carries samples with no
        information about the actuator (one-sample spikes, a channel pinned at its range, a
        frozen logger) or a stationary interference line, identify again with those samples
        out of the fit and the line removed; the warnings name what was taken out.
    command_rate : float, optional
        Rate at which the actuator's controller updated the command [Hz]. Not given, for a record
        sampled below :data:`~.problem.COMMAND_RATE_HZ`: identified both ways -- the command held
        over each recorded sample (a controller at the record's rate) and interpolated to that rate
        (a faster one) -- and the better stage fit kept, a warning saying which.
    """
    t0 = time.perf_counter()
    seq = sequence or FDISequence()
    # a noisy or quantised recording of the command: the actuator received the controller's
    # command, not the logger's reading of it (record.logged_command)
    response, note = logged_command(response, seq)
    command_warning = [f"data check: {note}"] if note else []
    record = fdi_record(response, seq)
    base = params if params is not None else load("monitor")
    args = (response, method, fitness, seed, start, params, sequence, ga_options, progress)
    rate_note: list[str] = []
    if command_rate is None and oversampling(record.sample_rate, None, base.integration.dt) > 1:
        # the record does not say how fast the controller ran: a 1 kHz run recorded at 500 Hz fitted with
        # the command held over the 2 ms samples read K_BKL 0.016 off, a 500 Hz controller fitted with
        # it interpolated 0.017-0.025 off (measured at three fault sets)
        fast, held = (_identify(*args, command_rate=r) for r in (COMMAND_RATE_HZ, record.sample_rate))
        d = held if held.fit_cost < fast.fit_cost else fast
        note = (f"the record is sampled at {record.sample_rate:.4g} Hz, below the {COMMAND_RATE_HZ:g} Hz the "
                f"monitor takes for the controller: the command fits better "
                + ("held over each sample (a controller at the record's rate)" if d is held else
                   f"interpolated to {fast.command_rate:.4g} Hz (a faster controller)")
                + f" (stage cost {min(held.fit_cost, fast.fit_cost):.4g} vs {max(held.fit_cost, fast.fit_cost):.4g}); "
                f"`command_rate` sets it")
        rate_note = [note]
        d = replace(d, warnings=rate_note + d.warnings, evaluations=fast.evaluations + held.evaluations)
        if progress:
            progress(note)
    else:
        d = _identify(*args, command_rate=command_rate)
    d = replace(d, warnings=command_warning + d.warnings)
    if not clean or fitness != "lsq":
        return replace(d, wall_time_s=time.perf_counter() - t0)
    cleaned = clean_channels(record.t, record.channels, {c: getattr(d.fitted, c) for c in record.channels},
                             record.command, record.sample_rate)
    if not cleaned.changed:
        return replace(d, wall_time_s=time.perf_counter() - t0)
    # (measured: a pressure pinned at +-1 MPa on 68 % of the test took K_FSJ to 0.146 for 0.4)
    for line in cleaned.lines:
        if progress:
            progress(f"data check: {line}; identifying again")
    again = _identify(*args, cleaned=cleaned, command_rate=d.command_rate)
    return replace(again, warnings=command_warning + [f"data check: {line}" for line in cleaned.lines] + rate_note
                   + again.warnings,
                   evaluations=d.evaluations + again.evaluations, wall_time_s=time.perf_counter() - t0)


def _identify(response: Response, method: str, fitness: str, seed: int, start: Faults | None,
              params: ModelParams | None, sequence: FDISequence | None, ga_options: GAOptions | None,
              progress: Callable[[str], None] | None, cleaned: Cleaned | None = None,
              command_rate: float | None = None) -> Diagnosis:
    """:func:`diagnose` without its cleaning: one identification, on the ``cleaned`` channels
    (excluded samples weigh nothing) when given, with the command updated at ``command_rate``."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if fitness not in FITNESSES:
        raise ValueError(f"unknown fitness {fitness!r}; choose from {', '.join(FITNESSES)}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    t0 = time.perf_counter()
    seq = sequence or FDISequence()
    record = fdi_record(response, seq)
    if cleaned is not None:
        record = replace(record, channels=cleaned.channels, excluded=cleaned.excluded)
    record = replace(record, command_rate=command_rate)
    model = KnobModel(params if params is not None else load("monitor"), FAULT_KNOBS, record)
    check_units(model)
    objective = make_fitness(fitness, record, seq)
    problem = Problem(model, objective)
    start = start if start is not None else start_point(model, response, seq)
    stage = fdi_stage_residual(objective, record, seq)
    history: list[float] = []
    x_start, stages, options = np.array(start.as_tuple(), float), fdi_stages(objective, record, seq), ga_options or GAOptions()
    # a stage channel with no sample left (a dead transducer the cleaning set aside): the stage
    # objectives and the start cannot see its coefficients (measured, dead pressure at (0.3, 0.4, 0.3):
    # fast K_FSJ 0.013 +- 0.007, deterministic 0.066; the GA on the whole test 0.388)
    blind = blind_stages(record, seq) if isinstance(objective, Residual) and method != "ga" else {}
    run = "ga" if blind else method
    est = search(problem, run, x_start, stages, seed, options, history, progress, stage)
    guard, guard_warn = ("blind" if blind and method == "fast" else ""), []
    finished_by = run                   # whose measured error terms the error bars take
    if blind:
        seen = sorted({f for fs in blind.values() for f in fs})
        guard_warn.append(f"{' and '.join(blind)} {'has' if len(blind) == 1 else 'have'} no sample left on "
                          f"the test's stage segments (not recorded, or set aside by the data check): the stage "
                          f"objectives and the start cannot see "
                          f"{', '.join(seen)}; identified on the whole test from the other channels by the "
                          f"global search (ga) instead of {method}")
        if progress:
            progress(guard_warn[-1])
    if run == "fast":
        q = fit_quality(stage, est.cost, record)
        guard = "passed" if np.isfinite(q) else "unjudged"
        after = after_a_test(model, objective, stage, seq, est, q, history, progress)
        if after is not None:
            model, est, q, note = after
            record, problem, guard = model.record, Problem(model, objective), "after a test"
            guard_warn.append(note)
        if q > GUARD_FACTOR:
            near = probe(_staged(model, stage), est, history)
            q_near = fit_quality(stage, near.cost, record) if near is not None else float("inf")
            if progress:
                progress(f"guard failed ({q:.1f}x the floor); local probe: "
                         + ("no lower neighbour" if near is None else f"fit quality {q_near:.2f}"))
            if q_near <= GUARD_FACTOR:
                guard_warn.append(f"global guard: the fast fit left {q:.1f}x the cost of the model's floor and the "
                                  f"measured noise (limit {GUARD_FACTOR:g}); restarted from a neighbouring point "
                                  f"(a cliff of the cost: an event that comes or goes) it leaves {q_near:.2f}x")
                est, q, guard = near, q_near, "probed"
        if q > GUARD_FACTOR:
            guard = "fired"
            guard_warn.append(f"global guard: the fast fit leaves {q:.1f}x the cost of the model's floor and the "
                              f"measured noise (limit {GUARD_FACTOR:g}): a wrong basin, or an effect the model lacks; "
                              f"the global search (hybrid) ran instead")
            if progress:
                progress(guard_warn[-1])
            est = search(problem, "hybrid", x_start, stages, seed, options, history, progress)
            finished_by = "hybrid"
            # the global search's estimate is a start in the right basin: finish it on the stage residual
            polished = search(problem, "fast", est.x, stages, seed, options, history, progress, stage)
            if fit_quality(stage, polished.cost, record) <= GUARD_FACTOR:
                polished.population, polished.population_cost = est.population, est.population_cost
                est, finished_by = polished, "fast"
    x = est.x
    lsq = problem if isinstance(objective, Residual) else Problem(model, make_fitness("lsq", record, seq))
    # (no position recorded: the sensor-noise term of the error bars, scaled by its noise, is left out)
    sd, corr, sd_stat, out = error_bars(lsq, x, noise_level(response.position) if "position" in record.channels
                                        else 0.0, finished_by)
    cost = float(objective.cost(out))
    warn = guard_warn + twin_warnings(corr, x, est.population, est.population_cost, cost)
    fit_cost = stage.cost(out)
    q_final = fit_quality(stage, fit_cost, record)
    if method == "fast" and q_final > GUARD_FACTOR:
        # the global search did not bring the fit within the guard either: the record is not the
        # monitor model's (measured: a time base 1 % fast, 1974x, the coefficients 0.3 off; the undeclared
        # bags: a 1 ms sensor delay 16x, 0.061 off; a null bias with backlash 41x, 0.046 off)
        warn.append(f"the estimate leaves {q_final:.1f}x the cost of the model's floor and the measured noise "
                    f"(limit {GUARD_FACTOR:g}) after the global search: the record does not fit the monitor "
                    f"model (an effect it lacks, or a recording problem): the coefficients are not to be "
                    f"trusted; `eha-health discrepancy` looks for what is missing")
    if np.any(x >= model.upper - 1e-6):
        warn.append("an estimate sits on the upper search bound: damage beyond the modelled range")
    fitted = response_from_rows(record.t, out, {"label": "monitor fit"})
    # (on the samples that carry information: a cleaned record's excluded ones are left out)
    # (a channel excluded whole -- a dead transducer -- is reported over all its samples)
    keep = {c: ~record.excluded[c] if c in record.excluded and not record.excluded[c].all() else slice(None)
            for c in record.channels}
    rms = {c: float(np.sqrt(np.mean((getattr(fitted, c)[keep[c]] - record.channels[c][keep[c]]) ** 2)))
           for c in MEASURED if c in record.channels}
    return Diagnosis(faults=Faults(*(float(v) for v in x)), std=dict(zip(FAULT_NAMES, map(float, sd))),
                     std_stat=dict(zip(FAULT_NAMES, map(float, sd_stat))), correlation=corr, method=method,
                     fitness=fitness, cost=cost, evaluations=model.runs, wall_time_s=time.perf_counter() - t0,
                     history=history, warnings=warn, start=start, fitted=fitted, rms=rms, seed=int(seed),
                     fit_cost=fit_cost, fit_quality=q_final, guard=guard,
                     command_rate=float(model.base.integration.sample_rate))


_TABLES: dict = {}
_TABLES_LOCK = threading.Lock()     # diagnoses may run in threads (see .concurrency)


def prepare(params: ModelParams | None = None, sequence: FDISequence | None = None) -> None:
    """Build what diagnoses with ``params`` cache (the start's signature tables, one batch of monitor
    runs), so that a long-lived process (a fleet worker, the monitor node) pays it before its first test."""
    _start_table(params if params is not None else load("monitor"), sequence or FDISequence())


def _start_table(params: ModelParams, sequence: FDISequence) -> StartTable:
    """Signature tables of the monitor model (cached per parameter set and sequence, the last few:
    the discrepancy loop alternates between the shipped monitor and a candidate's)."""
    key = (pack(params).tobytes(), repr(sequence))
    with _TABLES_LOCK:
        table = _TABLES.get(key)
    if table is None:
        # built outside the lock: two threads may build the same table, never a half one
        table = StartTable.shipped(params, sequence) or StartTable.build(params, sequence)
        with _TABLES_LOCK:
            while len(_TABLES) >= 4:
                _TABLES.pop(next(iter(_TABLES)))
            _TABLES[key] = table
    return table
