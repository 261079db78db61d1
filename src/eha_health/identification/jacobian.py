"""The one finite-difference Jacobian: every perturbed point in one parallel batch (with the base
point, or after it when a fit evaluates trial points first)."""
from __future__ import annotations

import numpy as np

from .problem import Problem

#: A model that blows up somewhere inside the bounds must read as a bad point, not NaN.
BLOWUP = 1e6


def fd_points(x: np.ndarray, free: np.ndarray, steps: np.ndarray, upper: np.ndarray):
    """Rows ``x`` and ``x + h_j e_j`` for each free knob j (a backward step where the forward one
    would cross the upper bound), and the signed steps ``h``."""
    h = np.where(x[free] + steps <= upper[free], steps, -steps)
    X = np.repeat(np.asarray(x, float)[None], len(free) + 1, axis=0)
    for j, i in enumerate(free):
        X[j + 1, i] += h[j]
    return X, h


def residual(problem: Problem, x: np.ndarray):
    """Residual, output and simulation (:meth:`~.problem.KnobModel.simulate`) at ``x``: one model
    run, a trial point of a fit, whose Jacobian is needed only if the solver accepts it
    (:func:`jacobian_at`)."""
    m = problem.model
    x = np.asarray(x, float)[None]
    sim = m.simulate(x)
    out = m.recorded(x, sim.copy())[0]      # (recorded works in place: the simulation is kept)
    return _finite(problem.objective(out)), out, sim[0]


def jacobian_at(problem: Problem, x: np.ndarray, r: np.ndarray, sim: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """The forward-difference Jacobian at ``x`` whose residual ``r`` and simulation ``sim`` are
    known (:func:`residual`): the perturbed rows only, one batch, a measurement-chain knob's row on
    ``sim`` -- the same numbers as :func:`jacobian` (a row simulates alike alone or in a batch)."""
    m = problem.model
    X, h = fd_points(x, problem.free, m.steps[problem.free] * scale, m.upper)
    outs = m.run(X[1:], known=(x, sim)) if len(h) else []
    return _differences(r, [_finite(problem.objective(o)) for o in outs], h)


def _finite(r: np.ndarray) -> np.ndarray:
    return np.nan_to_num(r, nan=BLOWUP, posinf=BLOWUP, neginf=-BLOWUP)


def _differences(r: np.ndarray, rs: list[np.ndarray], h: np.ndarray) -> np.ndarray:
    """Forward differences ``(rs[j] - r) / h[j]`` as columns (none without free knobs)."""
    return np.column_stack([(rj - r) / hj for rj, hj in zip(rs, h)]) if len(h) else np.zeros((len(r), 0))


def jacobian(problem: Problem, x: np.ndarray, scale: float = 1.0):
    """Residual, forward-difference Jacobian over the free knobs and output at ``x``.

    Steps are each knob's :attr:`~.knobs.Knob.step` times ``scale``. Returns ``(r, J, out)``.
    """
    m = problem.model
    X, h = fd_points(x, problem.free, m.steps[problem.free] * scale, m.upper)
    outs = m.run(X)
    rs = [_finite(problem.objective(o)) for o in outs]
    return rs[0], _differences(rs[0], rs[1:], h), outs[0]
