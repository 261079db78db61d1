"""The monitor model with fitted knobs: fault coefficients, nominal parameters, added effects.

A :class:`Knob` is one scalar a fit may move: its unit, bounds, a typical
magnitude (the probe of a signature and the scale of the search), the value at
which its mechanism is absent, and how it changes a :class:`ModelParams`.
An :class:`AugmentedModel` is a base parameter set plus a list of knobs; it packs
a knob vector into the kernels' parameter vector and simulates batches of them
on all cores. :func:`fit` is bounded least squares (trust-region reflective)
over any subset of the knobs, on any subset of the samples, with the Jacobian
from one parallel batch of finite differences.

A :class:`Record` is what was measured: the command, the channels a rig has
(any of position, velocity, pressure, current) and, optionally, a measured
external load force. Nothing here imports ROS.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from .fitness import CHANNEL_COLUMNS, CHANNEL_SCALES, CHANNEL_WEIGHTS
from ..physics.model import simulate_packed
from ..physics.faults import Faults
from ..physics.params import ModelParams
from ..physics.packing import pack
from ..signals.response import Response

MEASURABLE = ("position", "velocity", "pressure", "current")


@dataclass(frozen=True)
class Knob:
    """One fitted scalar of the monitor model.

    ``apply(params, value)`` returns the changed parameter set; a fault
    coefficient has ``fault`` set instead (``'k_gm'``, ``'k_fsj'`` or ``'k_bkl'``).
    """
    name: str
    unit: str
    lo: float
    hi: float
    typical: float
    off: float = 0.0
    apply: Callable[[ModelParams, float], ModelParams] | None = None
    fault: str | None = None
    doc: str = ""

    @property
    def step(self) -> float:
        """Finite-difference step of the Jacobian (a fiftieth of the typical magnitude)."""
        return 2e-3 if self.fault else 0.02 * abs(self.typical)


FAULT_KNOBS = (
    Knob("k_gm", "-", 0.0, 1.5, 0.1, 0.0, fault="k_gm", doc="torque-motor demagnetisation"),
    Knob("k_fsj", "-", 0.0, 1.5, 0.1, 0.0, fault="k_fsj", doc="jack static-friction rise"),
    Knob("k_bkl", "-", 0.0, 1.5, 0.1, 0.0, fault="k_bkl", doc="linkage backlash"),
)


@dataclass
class Record:
    """Measured data to fit: SI channels on a uniform time base, optional load force [N]."""
    t: np.ndarray
    command: np.ndarray
    channels: dict[str, np.ndarray]
    load: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @classmethod
    def from_response(cls, r: Response, channels: tuple[str, ...] | None = None) -> "Record":
        """Take the measured channels of ``r`` (those given, or every all-finite one)."""
        t = np.asarray(r.t, float)
        if len(t) < 100:
            raise ValueError(f"window too short: {len(t)} samples (need >= 100)")
        dt = np.diff(t)
        if (dt <= 0).any():
            raise ValueError("time axis is not strictly increasing")
        if np.max(np.abs(dt - np.median(dt))) > 0.01 * np.median(dt):
            raise ValueError("samples are not uniformly spaced: gaps or jitter")
        if not np.isfinite(r.command).all():
            raise ValueError("channel command has NaN or inf samples")
        names = channels or tuple(c for c in MEASURABLE if np.isfinite(getattr(r, c)).all())
        chans = {}
        for c in names:
            if c not in MEASURABLE:
                raise ValueError(f"unknown channel {c!r}; known: {', '.join(MEASURABLE)}")
            v = np.asarray(getattr(r, c), float)
            if not np.isfinite(v).all():
                raise ValueError(f"channel {c} has NaN or inf samples")
            chans[c] = v
        if not chans:
            raise ValueError("no measured channel: need at least one of " + ", ".join(MEASURABLE))
        load = getattr(r, "load", None)
        if load is not None and not np.isfinite(load).all():
            raise ValueError("channel load has NaN or inf samples")
        return cls(t, np.asarray(r.command, float), chans, load, dict(r.meta))

    @property
    def sample_rate(self) -> float:
        return 1.0 / float(np.median(np.diff(self.t)))

    def __len__(self) -> int:
        return len(self.t)


class AugmentedModel:
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

    def off(self) -> np.ndarray:
        """The knob vector of the base model (every mechanism absent, faults 0)."""
        return np.array([k.off for k in self.knobs])

    def params_at(self, x) -> tuple[ModelParams, Faults]:
        p, f = self.base, {"k_gm": 0.0, "k_fsj": 0.0, "k_bkl": 0.0}
        for k, v in zip(self.knobs, np.asarray(x, float)):
            if k.fault:
                f[k.fault] = max(float(v), 0.0)
            else:
                p = k.apply(p, float(v))
        return p, Faults(**f)

    def packed(self, x) -> np.ndarray:
        return pack(*self.params_at(x))

    def run(self, X) -> np.ndarray:
        """Outputs ``[len(X), n, N_OUT]`` of the knob vectors ``X`` (rows), in parallel."""
        X = np.atleast_2d(np.asarray(X, float))
        self.runs += len(X)
        return simulate_packed(np.stack([self.packed(x) for x in X]), self.record.command, self.record.load)

    def extended(self, extra: tuple[Knob, ...]) -> "AugmentedModel":
        return AugmentedModel(self.base, self.knobs + tuple(extra), self.record)


class Residual:
    """Weighted residual of model outputs against a record, on a sample mask.

    Each channel difference is divided by its scale (``fitness.CHANNEL_SCALES``,
    times the channel weight) and by sqrt(samples): the squared norm is a mean
    square in scale units, comparable between masks of different length.
    """

    def __init__(self, record: Record, mask: np.ndarray | None = None, weights: dict | None = None):
        self.record = record
        self.mask = np.ones(len(record), bool) if mask is None else np.asarray(mask, bool)
        self.n = int(self.mask.sum())
        if self.n < 10:
            raise ValueError(f"residual mask holds {self.n} samples (need >= 10)")
        self.channels = tuple(record.channels)
        self.cols = [CHANNEL_COLUMNS[c] for c in self.channels]
        wt = weights or {}
        self.w = np.array([wt.get(c, CHANNEL_WEIGHTS[c] / CHANNEL_SCALES[c]) for c in self.channels]) / np.sqrt(self.n)
        self.y = np.column_stack([record.channels[c][self.mask] for c in self.channels])

    def __call__(self, out: np.ndarray) -> np.ndarray:
        return ((out[self.mask][:, self.cols] - self.y) * self.w).ravel()

    def rss(self, out: np.ndarray) -> float:
        r = self(out)
        return float(r @ r)

    def rms(self, out: np.ndarray) -> dict[str, float]:
        """Unweighted RMS of each channel [SI] on the mask."""
        d = out[self.mask][:, self.cols] - self.y
        return {c: float(np.sqrt(np.mean(d[:, i] ** 2))) for i, c in enumerate(self.channels)}


@dataclass
class Fit:
    """Result of :func:`fit`."""
    x: np.ndarray                 # all knob values (fixed ones included)
    names: tuple[str, ...]
    free: np.ndarray              # indices of the knobs that were fitted
    rss: float                    # weighted residual norm^2 on the fit mask
    jacobian: np.ndarray          # d residual / d free knobs at x
    residual: np.ndarray          # weighted residual at x
    output: np.ndarray            # model output at x, [n, N_OUT]
    runs: int

    def values(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.x)}

    def std(self, inflation: float = 1.0) -> dict[str, float]:
        """Gauss-Newton standard errors of the free knobs, s^2 (J'J)^-1 times ``inflation``."""
        J, r = self.jacobian, self.residual
        dof = max(len(r) - J.shape[1], 1)
        cov = np.linalg.pinv(J.T @ J) * float(r @ r) / dof * inflation
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        return {self.names[i]: float(s) for i, s in zip(self.free, sd)}


def _fd_rows(model: AugmentedModel, x: np.ndarray, free: np.ndarray):
    steps = np.array([model.knobs[i].step for i in free])
    steps = np.where(x[free] + steps <= model.upper[free], steps, -steps)
    X = np.repeat(x[None], len(free) + 1, axis=0)
    for j, i in enumerate(free):
        X[j + 1, i] += steps[j]
    return X, steps


def fit(model: AugmentedModel, residual: Residual, x0, free=None, max_nfev: int = 40) -> Fit:
    """Bounded least squares of ``residual`` over the ``free`` knobs (default all), from ``x0``."""
    x0 = np.clip(np.asarray(x0, float), model.lower, model.upper)
    free = np.arange(len(x0)) if free is None else np.asarray(free, int)
    runs0 = model.runs
    cache: dict = {}

    def full(z):
        x = x0.copy()
        x[free] = z
        return x

    scale = np.array([abs(model.knobs[i].typical) for i in free])

    def batch(z):
        # keyed relative to each knob's magnitude (a leakage of 5e-12 must not round to 0)
        key = tuple(np.round(np.asarray(z) / scale, 12))
        if key not in cache:
            cache.clear()
            X, steps = _fd_rows(model, full(z), free)
            outs = model.run(X)
            # a model that blows up somewhere in the bounds must read as a bad point, not NaN
            rs = [np.nan_to_num(residual(o), nan=1e6, posinf=1e6, neginf=-1e6) for o in outs]
            J = np.column_stack([(rs[j + 1] - rs[0]) / steps[j] for j in range(len(free))])
            cache[key] = (rs[0], J, outs[0])
        return cache[key]

    if len(free):
        start = batch(x0[free])
        with warnings.catch_warnings():
            # on a rough cost (stick-slip) TRF's trust-region arithmetic can divide by zero; the
            # outcome is checked below, so its RuntimeWarnings are noise on the user's terminal
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = least_squares(lambda z: batch(z)[0], x0[free], jac=lambda z: batch(z)[1],
                                bounds=(model.lower[free], model.upper[free]), method="trf", x_scale=scale,
                                xtol=1e-8, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
        r0, J, out = batch(sol.x)
        x = full(sol.x)
        if float(r0 @ r0) > float(start[0] @ start[0]):   # never hand back worse than the start
            (r0, J, out), x = start, x0.copy()
    else:
        x = x0
        out = model.run(x0)[0]
        r0, J = residual(out), np.zeros((residual.n * len(residual.channels), 0))
    return Fit(x, model.names, free, float(r0 @ r0), J, r0, out, model.runs - runs0)
