"""The problem a fit solves: the monitor model with knobs, a measured record, an objective.

A :class:`KnobModel` is a base parameter set plus a list of :class:`~.knobs.Knob`; it packs
a knob vector into the kernels' parameter vector and simulates batches of them on all
cores against the record's command (and measured load), counting the runs. A
:class:`Problem` adds the objective (a :class:`~.residual.Residual`, or the paper's
fitness) and which knobs move. The algorithms (:mod:`.local`, :mod:`.sequential`,
:mod:`.genetic`) take a Problem and return a :class:`~.result.FitResult`, as pymoo splits
problem and algorithm and scipy returns one result object.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..physics.faults import FAULT_NAMES, Faults
from ..physics.model import simulate_packed
from ..physics.packing import pack
from ..physics.params import ModelParams
from .knobs import Knob
from .record import Record


class KnobModel:
    """Base monitor parameters plus knobs; simulates knob vectors against a record."""

    def __init__(self, base: ModelParams, knobs: tuple[Knob, ...], record: Record):
        names = [k.name for k in knobs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate knob names in {names}")
        rate = record.sample_rate
        if abs(rate - base.integration.sample_rate) > 1e-6 * rate:
            base = base.updated("integration", sample_rate=round(rate, 6))
        self.base = base
        self.knobs = tuple(knobs)
        self.record = record
        self.runs = 0

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.knobs)

    @property
    def lower(self) -> np.ndarray:
        return np.array([k.lo for k in self.knobs])

    @property
    def upper(self) -> np.ndarray:
        return np.array([k.hi for k in self.knobs])

    @property
    def typical(self) -> np.ndarray:
        return np.array([abs(k.typical) for k in self.knobs])

    @property
    def steps(self) -> np.ndarray:
        """Finite-difference step of each knob [its unit]."""
        return np.array([k.step for k in self.knobs])

    def off(self) -> np.ndarray:
        """The knob vector of the base model (every mechanism absent, faults 0)."""
        return np.array([k.off for k in self.knobs])

    def params_at(self, x) -> tuple[ModelParams, Faults]:
        p, f = self.base, dict.fromkeys(FAULT_NAMES, 0.0)
        for k, v in zip(self.knobs, np.asarray(x, float)):
            if k.fault:
                f[k.fault] = max(float(v), 0.0)
            elif not k.recording:
                p = k.apply(p, float(v))
        return p, Faults(**f)

    def packed(self, x) -> np.ndarray:
        return pack(*self.params_at(x))

    def run(self, X, count: bool = True) -> np.ndarray:
        """Outputs ``[len(X), n, N_OUT]`` of the knob vectors ``X`` (rows), in parallel.

        Rows that differ only in measurement-chain knobs share one simulation (``runs`` counts
        simulations, unless ``count`` is False: a data check, not part of a fit): such a knob's
        Jacobian column or grid scan costs no model run.
        """
        X = np.atleast_2d(np.asarray(X, float))
        P = np.stack([self.packed(x) for x in X])
        P_u, inverse = np.unique(P, axis=0, return_inverse=True)
        self.runs += len(P_u) if count else 0
        cmd, load, n0 = self.record.command, self.record.load, 0
        if self.record.preroll is not None:
            n0 = len(self.record.preroll)
            cmd = np.concatenate([self.record.preroll, cmd])
            load = None if load is None else np.concatenate([np.zeros(n0), load])
        outs = simulate_packed(P_u, cmd, load)[np.ravel(inverse), n0:]
        rec = [(i, k) for i, k in enumerate(self.knobs) if k.recording]
        if rec:
            rate = self.record.sample_rate
            for b, x in enumerate(X):
                for i, k in rec:
                    if x[i] != k.off:
                        outs[b] = k.output(outs[b], float(x[i]), rate)
        return outs

    def extended(self, extra: tuple[Knob, ...]) -> "KnobModel":
        """The same base and record with further knobs (an added effect)."""
        return KnobModel(self.base, self.knobs + tuple(extra), self.record)


@dataclass
class Problem:
    """A fit: ``model`` (its knobs, bounds and scales, the record), the ``objective`` to minimise
    (anything with ``cost(out)`` and ``costs(outs)``; a least-squares method needs a
    :class:`~.residual.Residual`), and the indices of the ``free`` knobs (default all)."""
    model: KnobModel
    objective: object
    free: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.model.knobs)
        self.free = np.arange(n) if self.free is None else np.asarray(self.free, int)

    def full(self, x0: np.ndarray, z) -> np.ndarray:
        """``x0`` with the free knobs set to ``z``."""
        x = np.array(x0, float)
        x[self.free] = z
        return x

    def clip(self, x) -> np.ndarray:
        return np.clip(np.asarray(x, float), self.model.lower, self.model.upper)

    def cost_at(self, x) -> tuple[float, np.ndarray]:
        """Objective and output at one knob vector (one model run)."""
        out = self.model.run(x)[0]
        return float(self.objective.cost(out)), out

    def costs(self, X) -> np.ndarray:
        """Objective of each row of ``X`` (one parallel batch)."""
        return self.objective.costs(self.model.run(X))
