"""Python face of the two actuator models: a resumable ``Plant`` and ``simulate``.

>>> from eha_health import simulate, Faults
>>> r = simulate(faults=Faults(k_gm=0.4))              # reference model, FDI sequence
>>> m = simulate(kind="monitor", faults=Faults(k_fsj=0.6))

The reference model (physics flapper-nozzle first stage) plays the real actuator;
the monitor model (second-order first stage, calibrated) is what identification
fits. Both share every other block and accept the same optional effects.
"""
from __future__ import annotations

import threading

import numba
import numpy as np

from ..signals.response import Response
from . import kernel
from .faults import Faults
from .layout import N_OUT, N_S, O_CMD, O_CUR, O_P12, O_POS, O_VEL, O_XJ, O_XS, P_NSUB
from .packing import pack
from .params import ModelParams, load
from .sensors import acquisition, delay_buffer
from .sequence import FDISequence


class Plant:
    """A model instance that advances chunk by chunk from rest.

    Parameters
    ----------
    params : ModelParams, optional
        Parameter set (default: the shipped set of ``kind``).
    faults : Faults
        Fault coefficients.
    seed : int, optional
        Seed of the electrical and acquisition noise (required when enabled).
    kind : {'reference', 'monitor'}
        Which default parameter set to load when ``params`` is None.
    """

    def __init__(self, params: ModelParams | None = None, faults: Faults = Faults(),
                 seed: int | None = None, kind: str = "reference"):
        self.params = params if params is not None else load(kind)
        self.faults = faults
        self.p = pack(self.params, faults)
        self.seed = seed
        eff = self.params.effects
        needs_seed = eff.sensor_noise.enabled or eff.command_noise.enabled
        if needs_seed and seed is None:
            raise ValueError("noise is enabled (sensor_noise or command_noise): pass a seed")
        ss = np.random.SeedSequence(seed if seed is not None else 0)
        # separate streams so the draws do not depend on how the run is chunked
        self._rng_cmd, self._rng_acq = (np.random.default_rng(s) for s in ss.spawn(2))
        self.reset()

    @property
    def sample_rate(self) -> float:
        return self.params.integration.sample_rate

    @property
    def steps_per_sample(self) -> int:
        return int(self.p[P_NSUB])

    def reset(self) -> None:
        self.state = np.zeros(N_S)
        self.dbuf = delay_buffer(self.p)
        kernel.init_state(self.p, self.state, self.dbuf)
        self.samples = 0

    def step(self, command: np.ndarray) -> np.ndarray:
        """Advance ``len(command)`` samples (command [m], zero-order hold); returns raw rows.

        Rows follow ``layout.OUT_NAMES``: the values at each sample instant,
        after acquisition noise and quantisation when those effects are on.
        """
        cmd = np.ascontiguousarray(command, dtype=float)
        if cmd.ndim != 1:
            raise ValueError("command must be a 1-D array of positions [m]")
        if not np.isfinite(cmd).all():
            raise ValueError("command contains NaN or inf")
        eff = self.params.effects
        if eff.command_noise.enabled:
            noise = self._rng_cmd.normal(0.0, eff.command_noise.sigma, len(cmd) * self.steps_per_sample)
        else:
            noise = np.zeros(0)
        out = kernel.new_output(len(cmd))
        kernel.run(self.p, self.state, cmd, np.zeros(0), noise, self.dbuf, out)
        self.samples += len(cmd)
        return acquisition(out, eff, self._rng_acq)


def response_from_rows(t: np.ndarray, out: np.ndarray, meta: dict | None = None) -> Response:
    return Response(t=t, command=out[:, O_CMD].copy(), position=out[:, O_POS].copy(),
                    velocity=out[:, O_VEL].copy(), pressure=out[:, O_P12].copy(),
                    current=out[:, O_CUR].copy(), spool=out[:, O_XS].copy(),
                    jack_position=out[:, O_XJ].copy(), meta=meta or {})


def simulate(kind: str = "reference", faults: Faults = Faults(), params: ModelParams | None = None,
             sequence: FDISequence | None = None, seed: int | None = None) -> Response:
    """Simulate one FDI test (or ``sequence``) and return the sampled response."""
    plant = Plant(params, faults, seed, kind)
    seq = sequence or FDISequence()
    t = seq.times(plant.sample_rate)
    out = plant.step(seq.command(t))
    meta = {"model": plant.params.kind, "faults": faults.as_tuple(), "seed": seed}
    return response_from_rows(t, out, meta)


def simulate_batch(params: ModelParams, faults: list[Faults], command: np.ndarray) -> np.ndarray:
    """Simulate many fault sets of one model in parallel (all cores), noise-free.

    Returns an array ``[len(faults), len(command), N_OUT]``.
    """
    return simulate_packed(np.stack([pack(params, f) for f in faults]), command)


#: numba's built-in "workqueue" threading layer (used where neither OpenMP nor TBB is installed)
#: terminates the process when two threads launch a parallel batch at once; OpenMP and TBB do not.
_LAUNCH = threading.Lock()
_SAFE_LAYERS = ("omp", "tbb")
_layer_safe: bool | None = None


def _threadsafe_layer() -> bool:
    """Whether parallel batches may be launched from several threads at once (known after the first)."""
    global _layer_safe
    if _layer_safe is None:
        try:
            _layer_safe = numba.threading_layer() in _SAFE_LAYERS
        except ValueError:          # no parallel batch has run yet: the layer is not chosen
            return False
    return _layer_safe


def simulate_packed(P: np.ndarray, command: np.ndarray, load: np.ndarray | None = None) -> np.ndarray:
    """Simulate packed parameter rows ``P`` (see :func:`params.pack`) in parallel, noise-free.

    ``load`` is an optional measured external force per sample [N] (opposing +x).
    Returns an array ``[len(P), len(command), N_OUT]``.
    """
    cmd = np.ascontiguousarray(command, dtype=float)
    ld = np.zeros(0) if load is None else np.ascontiguousarray(load, dtype=float)
    if len(ld) and len(ld) != len(cmd):
        raise ValueError(f"load has {len(ld)} samples but the command has {len(cmd)}")
    out = np.zeros((len(P), len(cmd), N_OUT))
    P = np.ascontiguousarray(P, dtype=float)
    if len(P) == 1:
        # one run on the calling thread: a parallel launch of one row would hold the other cores
        kernel.run_one(P[0], cmd, ld, out[0])
    elif _threadsafe_layer():
        kernel.run_batch(P, cmd, ld, out)
    else:
        with _LAUNCH:
            kernel.run_batch(P, cmd, ld, out)
    return out
