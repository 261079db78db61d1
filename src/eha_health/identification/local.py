"""Local algorithms over a :class:`~.problem.Problem`: bounded least squares, compass, Powell.

* :func:`least_squares` -- trust-region reflective (scipy) on the residual, with the batched
  finite-difference Jacobian of :mod:`.jacobian`; never hands back worse than its start.
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

import numpy as np
from scipy import optimize

from .jacobian import jacobian
from .problem import Problem
from .result import FitResult


def least_squares(problem: Problem, x0, xtol: float = 1e-8, ftol: float = 1e-10, gtol: float = 1e-10,
                  max_nfev: int = 40, history: list | None = None, output: bool = True) -> FitResult:
    """Bounded least squares of ``problem.objective`` (a Residual) over the free knobs, from ``x0``.

    Knobs are scaled by their typical magnitudes (``x_scale``); ``history`` (optional) gets the
    squared residual norm of every point the solver evaluates. The result holds the residual and
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
    cache: dict = {}

    def at(z):
        # keyed relative to each knob's magnitude (a leakage of 5e-12 must not round to 0)
        key = tuple(np.round(np.asarray(z) / scale, 12))
        if key not in cache:
            cache.clear()
            cache[key] = jacobian(problem, problem.full(x0, z))
        return cache[key]

    def fun(z):
        r = at(z)[0]
        if history is not None:
            history.append(float(r @ r))
        return r

    start = at(x0[free])   # scipy moves a start on a bound inside it: the exact start is the reference
    with warnings.catch_warnings():
        # on a rough cost (stick-slip) TRF's trust-region arithmetic can divide by zero; the
        # outcome is checked below, so its RuntimeWarnings are noise on the user's terminal
        warnings.simplefilter("ignore", RuntimeWarning)
        sol = optimize.least_squares(fun, x0[free], jac=lambda z: at(z)[1], bounds=(m.lower[free], m.upper[free]),
                                     method="trf", x_scale=scale, xtol=xtol, ftol=ftol, gtol=gtol,
                                     max_nfev=max_nfev)
    key = tuple(np.round(np.asarray(sol.x) / scale, 12))
    x = problem.full(x0, sol.x)
    if key in cache:
        r, J, out = cache[key]
    else:   # the last trial was rejected: scipy holds the residual and Jacobian at its solution
        r, J = sol.fun, sol.jac
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
