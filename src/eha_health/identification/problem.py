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

import copy
import threading
from dataclasses import dataclass

import numpy as np

from ..physics.faults import FAULT_NAMES, Faults
from ..physics.layout import N_OUT
from ..physics.model import simulate_packed
from ..physics.packing import pack
from ..physics.params import ModelParams
from .knobs import Knob
from .record import Record


#: The rate at which the monitor takes the controller to update its command when the record does not
#: say (:attr:`Record.command_rate` None) [Hz]: the reference's and the shipped monitor's 1 kHz. The
#: kernel holds the command over each output sample; a logger may sample slower than the controller
#: runs. A record below this rate is simulated at the smallest integer multiple of its rate at or
#: above the command rate, the command (and load, preamble) interpolated between the recorded samples
#: (:func:`_upsampled`), and read back at the record's samples. Measured at (0.3, 0.4, 0.3), a 1 kHz
#: run recorded at 500 Hz: the command held over the 2 ms samples, the diagnosis K_BKL 0.016 off and
#: the discrepancy loop "unexplained"; interpolated, within 0.003 and "no significant missing effect".
#: A controller that does run at the record's rate is the other way round: ``diagnose`` tries both.
COMMAND_RATE_HZ = 1000.0


def oversampling(rate: float, command_rate: float | None, dt: float) -> int:
    """How many simulated samples per recorded one: the smallest integer m with ``rate * m`` at or
    above ``command_rate`` (default :data:`COMMAND_RATE_HZ`) whose period the integration step
    ``dt`` divides; 1 when the record is as fast (or no such m <= twice that exists)."""
    command_rate = COMMAND_RATE_HZ if command_rate is None else command_rate
    if not command_rate > rate * (1 + 1e-9):
        return 1
    m0 = int(np.ceil(command_rate / rate - 1e-9))
    for m in range(m0, 2 * m0 + 1):
        n = 1.0 / (rate * m * dt)
        if abs(n - round(n)) < 1e-6:
            return m
    return 1


#: A change from one sample to the next more than this many times both neighbouring changes is a
#: jump (a step of the command), held rather than interpolated: a step a 500 Hz record shows at a
#: sample was, for all the record can tell, at that sample (interpolated, half of the FDI test's
#: 10 mm step came 1 ms early: a 1.5 MPa pressure difference after it).
JUMP_RATIO = 3.0


def _upsampled(x: np.ndarray, m: int) -> np.ndarray:
    """``x`` at ``m`` times its rate: linear between samples, held over a jump (:data:`JUMP_RATIO`)
    and after the last sample."""
    fine = np.interp(np.arange(len(x) * m) / m, np.arange(len(x)), x)
    d = np.abs(np.diff(x))
    if len(d) > 2:
        near = np.maximum(np.concatenate([[0.0], d[:-1]]), np.concatenate([d[1:], [0.0]]))
        for k in np.flatnonzero((d > JUMP_RATIO * near) & (d > 0)):
            fine[k * m + 1:(k + 1) * m] = x[k]
    return fine


#: Guards every KnobModel's run counter (one lock: the counts are cheap, the runs are not under it).
_RUNS_LOCK = threading.Lock()


class KnobModel:
    """Base monitor parameters plus knobs; simulates knob vectors against a record (at a multiple of
    its rate when the command is updated faster: :func:`oversampling`)."""

    def __init__(self, base: ModelParams, knobs: tuple[Knob, ...], record: Record):
        names = [k.name for k in knobs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate knob names in {names}")
        rate = record.sample_rate
        self.oversample = oversampling(rate, record.command_rate, base.integration.dt)
        sim_rate = rate * self.oversample
        if abs(sim_rate - base.integration.sample_rate) > 1e-6 * sim_rate:
            base = base.updated("integration", sample_rate=round(sim_rate, 6))
        self.base = base
        self.knobs = tuple(knobs)
        self.record = record
        self.horizon = None         # simulate only the first samples (:meth:`until`); None: all
        self._runs = [0]            # shared with the views of :meth:`until`

    @property
    def runs(self) -> int:
        """Simulations run (this model and its :meth:`until` views together)."""
        return self._runs[0]

    @runs.setter
    def runs(self, value: int) -> None:
        self._runs[0] = int(value)

    def until(self, n: int | None) -> "KnobModel":
        """A view of this model that simulates only the record's first ``n`` samples (the rows after
        them are NaN), counting its runs with this model's. The kernel is causal, so those samples
        are the whole run's to the bit: an objective that reads no later sample (the FDI stage
        objectives read the ramp, 1.0 s of the 3.5 s test, or the ramp and the step, 1.5 s) costs
        that fraction of a run. The model itself when ``n`` is None or the whole record, or when it
        has measurement-chain knobs (they act on the whole recorded output: a skew reads later samples)."""
        if n is None or int(n) >= len(self.record) or any(k.recording for k in self.knobs):
            return self
        n = int(n)
        if n < 1:
            raise ValueError(f"horizon must be at least 1 sample, got {n}")
        view = copy.copy(self)
        view.horizon = n
        return view

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

    def run(self, X, count: bool = True, known: tuple | None = None) -> np.ndarray:
        """Outputs ``[len(X), n, N_OUT]`` of the knob vectors ``X`` (rows), in parallel.

        Rows that differ only in measurement-chain knobs share one simulation (``runs`` counts
        simulations, unless ``count`` is False: a data check, not part of a fit): such a knob's
        Jacobian column or grid scan costs no model run. ``known``: ``(x, simulation)`` of a point
        simulated before (:meth:`simulate`), which rows with its model parameters reuse.
        """
        X = np.atleast_2d(np.asarray(X, float))
        return self.recorded(X, self.simulate(X, count, known))

    def simulate(self, X, count: bool = True, known: tuple | None = None) -> np.ndarray:
        """The model's outputs at the knob vectors ``X`` before their measurement-chain knobs act
        (:meth:`recorded`), one simulation per distinct parameter set (see :meth:`run`)."""
        X = np.atleast_2d(np.asarray(X, float))
        P = np.stack([self.packed(x) for x in X])
        P_u, inverse = np.unique(P, axis=0, return_inverse=True)
        new = np.ones(len(P_u), bool)
        if known is not None:
            new &= ~np.all(P_u == self.packed(known[0]), axis=1)
        if count:
            with _RUNS_LOCK:     # independent fits of one model may run in threads (evidence._refit)
                self.runs += int(new.sum())
        cmd, load, n0 = self.record.command, self.record.load, 0
        if self.record.preroll is not None:
            n0 = len(self.record.preroll)
            cmd = np.concatenate([self.record.preroll, cmd])
            load = None if load is None else np.concatenate([np.zeros(n0), load])
        m = self.oversample
        if m > 1:
            cmd, load = _upsampled(cmd, m), None if load is None else _upsampled(load, m)
        sims = np.empty((len(P_u), len(self.record), N_OUT))
        h = len(self.record) if self.horizon is None else self.horizon
        if h < len(self.record):
            # (upsampled whole, then cut: the interpolation up to the horizon is the whole run's)
            end = (n0 + h) * m
            cmd, load = cmd[:end], None if load is None else load[:end]
            sims[:, h:] = np.nan
        if new.any():
            sims[new, :h] = simulate_packed(P_u[new], cmd, load)[:, n0 * m::m]
        if not new.all():
            sims[~new] = known[1]
        return sims[np.ravel(inverse)]

    def recorded(self, X, sims: np.ndarray) -> np.ndarray:
        """``sims`` (:meth:`simulate` of ``X``) through the measurement-chain knobs of each row, in
        place (returned)."""
        rec = [(i, k) for i, k in enumerate(self.knobs) if k.recording]
        if rec:
            rate = self.record.sample_rate
            for b, x in enumerate(np.atleast_2d(np.asarray(X, float))):
                for i, k in rec:
                    if x[i] != k.off:
                        sims[b] = k.output(sims[b], float(x[i]), rate)
        return sims

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
