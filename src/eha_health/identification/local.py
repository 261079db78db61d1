"""Local algorithms over a :class:`~.problem.Problem`: bounded least squares, compass, Powell.

* :func:`least_squares` -- trust-region reflective (scipy) on the residual, with the batched
  finite-difference Jacobian of :mod:`.jacobian` at the points it accepts (a trial point is one
  run); never hands back worse than its start.
* :func:`compass` -- derivative-free finish: +-step on each free knob (one parallel batch),
  move to the best that lowers the cost, halve the step when none does. Stick-slip and
  backlash events leave the cost slightly rough on the scale of the finite-difference step,
  where trust-region steps built on that Jacobian stall (measured: TRF stopped 0.003 short in
  K_FSJ on a valley that falls by 3 %).
* :func:`powell` -- bounded Powell on a scalar objective (the paper's fmincon hybrid function).
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from .jacobian import jacobian, jacobian_at, residual
from .problem import Problem
from .result import FitResult

#: Distance [in typical magnitudes] within which a solver coordinate is the start itself: scipy
#: moves a start on a bound by 1e-10 of the solver variable; a real step is far larger.
START_SNAP = 1e-9


@dataclass
class _Point:
    """A point the solver evaluated: knobs, residual, output, the simulation before the
    measurement-chain knobs (None when run in a Jacobian batch) and the Jacobian once asked for."""
    x: np.ndarray
    r: np.ndarray
    out: np.ndarray
    sim: np.ndarray | None = None
    J: np.ndarray | None = None


def least_squares(problem: Problem, x0, xtol: float = 1e-8, ftol: float = 1e-10, gtol: float = 1e-10,
                  max_nfev: int = 40, history: list | None = None, output: bool = True) -> FitResult:
    """Bounded least squares of ``problem.objective`` (a Residual) over the free knobs, from ``x0``.

    The solver runs on the knobs' offsets from ``x0`` in their typical magnitudes (a start on a
    bound stays on it). ``history`` (optional) gets the squared residual norm of every point the solver evaluates. The result holds the residual and
    Jacobian at the solution and, with ``output``, the model output there (one more run when the
    solver's last trial point was not its solution).
    """
    t0 = time.perf_counter()
    m = problem.model
    free = problem.free
    x0 = problem.clip(x0)
    runs0 = m.runs
    if not len(free):
        r, J, out = jacobian(problem, x0)
        return FitResult(x0, m.names, free, float(r @ r), m.runs - runs0, time.perf_counter() - t0, out, r, J)
    scale = m.typical[free]
    origin = x0[free] - scale
    u0 = np.ones(len(free))
    cache: dict = {}

    # The solver works on u = (x - x0) / typical + 1, two reasons. scipy's TRF moves a start that
    # lies on a bound inside by 1e-10 * max(1, |bound|) of its own variable (make_strictly_feasible):
    # in [unit] that was 1e-10 absolute, so a leakage knob (typical 5e-12 m^3/(s Pa)) started at 20x
    # its typical value; in u it is 1e-10 of the knob's typical magnitude, and a coordinate within
    # START_SNAP of the start is the start itself, evaluated exactly there. And TRF's first trust
    # radius is the norm of the scaled start: a start near 0 (a knob on its 0 bound) gave a radius of
    # ~1e-10 and a fit that never left its start; with the start at u = 1 the first radius is about
    # one typical magnitude per knob, the search scale a Knob declares, wherever the start lies.
    def point(u):
        u = np.asarray(u, float)
        z = np.where(np.abs(u - u0) <= START_SNAP, x0[free], origin + u * scale)
        return problem.full(x0, z), tuple(np.round((z - origin) / scale, 12))

    # A trial point costs one run; its Jacobian (the perturbed rows) is simulated only when TRF
    # accepts it and asks: near a rough optimum most trials are rejected (measured on the
    # discrepancy loop's fits: 45-58 % of the points, each of which cost the whole batch).
    def at(u, with_jacobian: bool) -> _Point:
        x, key = point(u)
        if key not in cache:
            cache.clear()
            if with_jacobian:
                r, J, out = jacobian(problem, x)
                cache[key] = _Point(x, r, out, J=J)
            else:
                cache[key] = _Point(x, *residual(problem, x))
        p = cache[key]
        if with_jacobian and p.J is None:
            p.J = jacobian_at(problem, x, p.r, p.sim)
        return p

    def fun(u):
        r = at(u, False).r
        if history is not None:
            history.append(float(r @ r))
        return r

    s0 = at(u0, True)
    start = (s0.r, s0.J, s0.out)   # the exact start is the reference the result must not be worse than
    with warnings.catch_warnings():
        # on a rough cost (stick-slip) TRF's trust-region arithmetic can divide by zero; the
        # outcome is checked below, so its RuntimeWarnings are noise on the user's terminal
        warnings.simplefilter("ignore", RuntimeWarning)
        # x0 lies within the bounds: rounding of (bound - origin) / scale must not put u0 outside
        lb = np.minimum((m.lower[free] - origin) / scale, u0)
        ub = np.maximum((m.upper[free] - origin) / scale, u0)
        sol = optimize.least_squares(fun, u0, jac=lambda u: at(u, True).J * scale, bounds=(lb, ub),
                                     method="trf", x_scale=1.0, xtol=xtol, ftol=ftol, gtol=gtol,
                                     max_nfev=max_nfev)
    x, key = point(sol.x)
    x = problem.clip(x)
    if key in cache:   # (TRF asks for the Jacobian of every point it accepts: J is there)
        p = cache[key]
        x, r, out, J = p.x, p.r, p.out, sol.jac / scale if p.J is None else p.J
    else:   # the last trial was rejected: scipy holds the residual and Jacobian at its solution
        r, J = sol.fun, sol.jac / scale
        out = m.run(x)[0] if output else None
    if float(r @ r) > float(start[0] @ start[0]):   # never hand back worse than the start
        (r, J, out), x = start, x0.copy()
    return FitResult(x, m.names, free, float(r @ r), m.runs - runs0, time.perf_counter() - t0, out, r, J,
                     history=list(history) if history is not None else [])


def compass(problem: Problem, x, cost: float, step_scale: float = 2.0, shrink_to: float = 1 / 16,
            history: list | None = None) -> FitResult:
    """Compass search from ``x`` (objective ``cost`` there) over the free knobs.

    The first step of each knob is ``step_scale`` times its finite-difference step (0.004 for a
    coefficient); the search stops when the steps have halved to ``shrink_to`` of that.
    """
    t0 = time.perf_counter()
    m = problem.model
    runs0 = m.runs
    x = np.asarray(x, float).copy()
    free = problem.free
    step = m.steps[free] * step_scale
    min_step = step * shrink_to
    while np.all(step >= min_step):
        E = np.zeros((2 * len(free), len(x)))
        for j, i in enumerate(free):
            E[2 * j, i], E[2 * j + 1, i] = step[j], -step[j]
        X = problem.clip(x[None] + E)
        c = problem.costs(X)
        k = int(np.argmin(c))
        if c[k] < cost:
            x, cost = X[k], float(c[k])
            if history is not None:
                history.append(cost)
        else:
            step = step / 2
    return FitResult(x, m.names, free, float(cost), m.runs - runs0, time.perf_counter() - t0,
                     history=list(history) if history is not None else [])


def powell(problem: Problem, x0, history: list | None = None) -> FitResult:
    """Bounded Powell search of the scalar objective over the free knobs (the paper's hybrid function)."""
    t0 = time.perf_counter()
    m = problem.model
    runs0 = m.runs
    x0 = problem.clip(x0)
    free = problem.free

    def f(z):
        c = problem.cost_at(problem.full(x0, z))[0]
        if history is not None:
            history.append(c)
        return c
    sol = optimize.minimize(f, x0[free], method="Powell", bounds=list(zip(m.lower[free], m.upper[free])),
                            options={"xtol": 1e-4, "ftol": 1e-8, "maxfev": 200})
    return FitResult(problem.full(x0, sol.x), m.names, free, float(sol.fun), m.runs - runs0,
                     time.perf_counter() - t0, history=list(history) if history is not None else [])
