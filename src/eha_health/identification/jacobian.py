"""The one finite-difference Jacobian: every perturbed point in one parallel batch."""
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


def jacobian(problem: Problem, x: np.ndarray, scale: float = 1.0):
    """Residual, forward-difference Jacobian over the free knobs and output at ``x``.

    Steps are each knob's :attr:`~.knobs.Knob.step` times ``scale``. Returns ``(r, J, out)``.
    """
    m = problem.model
    X, h = fd_points(x, problem.free, m.steps[problem.free] * scale, m.upper)
    outs = m.run(X)
    rs = [np.nan_to_num(problem.objective(o), nan=BLOWUP, posinf=BLOWUP, neginf=-BLOWUP) for o in outs]
    J = np.column_stack([(rs[j + 1] - rs[0]) / h[j] for j in range(len(h))]) if len(h) else \
        np.zeros((len(rs[0]), 0))
    return rs[0], J, outs[0]
