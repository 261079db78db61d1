"""The one result type of every fit (as scipy.optimize returns an ``OptimizeResult``)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .uncertainty import covariance


@dataclass
class FitResult:
    """Outcome of an algorithm on a :class:`~.problem.Problem`.

    ``x`` holds every knob (fixed ones included), ``free`` the indices that moved;
    ``jacobian`` and ``residual`` (least-squares objectives) are at ``x``; ``runs`` counts
    the model simulations the algorithm spent.
    """
    x: np.ndarray
    names: tuple[str, ...]
    free: np.ndarray
    cost: float
    runs: int
    wall_time_s: float = 0.0
    output: np.ndarray | None = None        # model output at x, [n, N_OUT]
    residual: np.ndarray | None = None      # weighted residual at x
    jacobian: np.ndarray | None = None      # d residual / d free knobs at x
    history: list[float] = field(default_factory=list)   # best cost per iteration or generation
    population: np.ndarray | None = None    # final population of a genetic search
    population_cost: np.ndarray | None = None

    def values(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.x)}

    def covariance(self, inflation: float = 1.0) -> np.ndarray:
        """Gauss-Newton covariance of the free knobs at ``x`` (:func:`.uncertainty.covariance`)."""
        return covariance(self.jacobian, self.residual, inflation)

    def std(self, inflation: float = 1.0) -> dict[str, float]:
        """Standard errors of the free knobs [their units], from :meth:`covariance`."""
        sd = np.sqrt(np.maximum(np.diag(self.covariance(inflation)), 0.0))
        return {self.names[i]: float(s) for i, s in zip(self.free, sd)}
