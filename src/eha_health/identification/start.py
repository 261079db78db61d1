"""Start point of a fit from the response's signatures, by inverting tabulated monitor runs.

Each fault moves one signature almost alone (measured on the monitor, ``eha-health signatures``):

* K_FSJ -- the P12 plateau during the ramp (linear in K_FSJ; K_GM and K_BKL move it < 0.1 %)
* K_GM  -- the position overshoot on the step (monotone falling up to K_GM ~ 1.3; K_FSJ and K_BKL
  move it ~ 2 %)
* K_BKL -- the velocity peak during the ramp, which also falls with K_GM: a table over
  (K_GM, K_BKL), read at the K_GM found first.

The tables are monitor runs at fixed levels (one parallel batch of 85 runs, ~0.4 s, built once
per parameter set); a measured signature is read back by monotone linear interpolation. The
shipped monitor's tables ship as ``data/start_table.json`` (keyed by a hash of the packed
parameters, the sequence and the levels; ``tools/start_table.py`` re-writes it, a test checks it
against a fresh build), so a one-shot ``diagnose`` does not pay the batch. The estimate is
only a start: the local fit finishes it, and the global guard of :func:`~.diagnose.diagnose`
catches a start in the wrong basin.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from importlib import resources

import numpy as np

from ..physics.faults import FAULT_UPPER, Faults
from ..physics.model import response_from_rows, simulate_batch
from ..physics.packing import pack
from ..physics.params import ModelParams
from ..physics.sequence import FDISequence
from ..signals.response import Response
from .signatures import Signatures, signatures

#: Levels of the tables [-]: single faults for K_FSJ and K_GM, a grid for (K_GM, K_BKL).
FSJ_LEVELS = (0.0, 0.5, 1.0, 1.5)
GM_LEVELS = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5)
GRID_GM = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
GRID_BKL = (0.0, 0.1, 0.2, 0.3, 0.4, 0.6, 0.8, 1.0, 1.25, 1.5)
#: The shipped monitor's tables (package data).
SHIPPED = "start_table.json"


def table_key(params: ModelParams, sequence: FDISequence) -> str:
    """What the tables depend on: the packed parameters, the sequence and the levels (sha256)."""
    h = hashlib.sha256(pack(params).tobytes())
    h.update(repr((sequence, FSJ_LEVELS, GM_LEVELS, GRID_GM, GRID_BKL)).encode())
    return h.hexdigest()


def _invert(levels, values, v: float) -> float:
    """Level at which the tabulated ``values`` reach ``v``, linear between levels, clipped to the table.

    The values are made monotone (running max of the rising sequence) so a flat or noisy
    stretch of the table reads as its first level."""
    lv = np.asarray(levels, float)
    y = np.asarray(values, float)
    sign = 1.0 if y[-1] >= y[0] else -1.0
    y = np.maximum.accumulate(sign * y)
    keep = np.concatenate([[True], np.diff(y) > 0])
    if keep.sum() < 2:
        return float(lv[0])
    return float(np.interp(sign * v, y[keep], lv[keep]))


@dataclass
class StartTable:
    """Signature tables of the monitor model and their inversion (see the module docstring)."""
    fsj_plateau: np.ndarray      # Pa, P12 plateau at each FSJ_LEVELS (others 0)
    gm_overshoot: np.ndarray     # m, step overshoot at each GM_LEVELS (others 0)
    bkl_velocity: np.ndarray     # m/s, ramp velocity peak [len(GRID_GM), len(GRID_BKL)]

    @classmethod
    def build(cls, params: ModelParams, sequence: FDISequence | None = None) -> "StartTable":
        """One parallel batch of monitor runs (4 + 11 + 70) over the tables' levels."""
        seq = sequence or FDISequence()
        rate = params.integration.sample_rate
        t = seq.times(rate)
        # the signatures read the ramp and the step: the runs stop at the step's end (the model is
        # causal: the same samples as the whole test's runs)
        t = t[:int(np.flatnonzero(seq.mask("step", t))[-1]) + 1]
        faults = [Faults(0.0, k, 0.0) for k in FSJ_LEVELS] + [Faults(k, 0.0, 0.0) for k in GM_LEVELS]
        faults += [Faults(g, 0.0, b) for g in GRID_GM for b in GRID_BKL]
        outs = simulate_batch(params, faults, seq.command(t))
        sig = [signatures(response_from_rows(t, o), seq) for o in outs]
        n1, n2 = len(FSJ_LEVELS), len(FSJ_LEVELS) + len(GM_LEVELS)
        return cls(np.array([s.pressure_plateau for s in sig[:n1]]),
                   np.array([s.overshoot for s in sig[n1:n2]]),
                   np.array([s.velocity_peak for s in sig[n2:]]).reshape(len(GRID_GM), len(GRID_BKL)))

    def as_dict(self) -> dict:
        return {"fsj_plateau": self.fsj_plateau.tolist(), "gm_overshoot": self.gm_overshoot.tolist(),
                "bkl_velocity": self.bkl_velocity.tolist()}

    @classmethod
    def shipped(cls, params: ModelParams, sequence: FDISequence) -> "StartTable | None":
        """The shipped tables if they were built for ``params`` and ``sequence``, else None."""
        try:
            data = json.loads((resources.files("eha_health") / "data" / SHIPPED).read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(data, dict) or data.get("key") != table_key(params, sequence):
            return None
        return cls(*(np.asarray(data[k], float) for k in ("fsj_plateau", "gm_overshoot", "bkl_velocity")))

    def estimate(self, sig: Signatures) -> Faults:
        """(K_GM, K_FSJ, K_BKL) whose tabulated signatures match ``sig`` (each within [0, FAULT_UPPER])."""
        fsj = _invert(FSJ_LEVELS, self.fsj_plateau, sig.pressure_plateau)
        gm = _invert(GM_LEVELS, self.gm_overshoot, sig.overshoot)
        # the velocity-peak curve over K_BKL at this K_GM: linear between the grid's K_GM rows
        row = np.array([np.interp(gm, GRID_GM, self.bkl_velocity[:, j]) for j in range(len(GRID_BKL))])
        bkl = _invert(GRID_BKL, row, sig.velocity_peak)
        return Faults(*(float(np.clip(v, 0.0, FAULT_UPPER)) for v in (gm, fsj, bkl)))

    def estimate_response(self, response: Response, sequence: FDISequence | None = None) -> Faults:
        return self.estimate(signatures(response, sequence))
