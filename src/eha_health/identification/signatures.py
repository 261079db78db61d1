"""Fault signatures of the FDI response (paper Sec. IV) and the coarse detector (IV.D).

Features, each on the segment where its fault shows best:

* GM  -- position overshoot on the 10 mm step (falls as the torque motor weakens, Fig. 4)
* FSJ -- peak and plateau of the differential pressure P12 during the ramp (Fig. 5)
* BKL -- motion start delay, velocity peak and breakaway current peak during the
  ramp (the surface starts later and then jumps, Figs. 6-7)

The detector's thresholds come from single-fault simulations at 20 % damage: a
threshold sits at ``margin`` (0.8) of the way from the healthy value to the 20 %
value, "slightly smaller than the one calculated in those simulations".
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..physics.model import simulate
from ..physics.faults import Faults
from ..physics.params import ModelParams
from ..signals.response import Response
from ..physics.sequence import FDISequence

#: Surface displacement [m] that counts as "motion has started" during the ramp.
MOTION_THRESHOLD = 5e-5


@dataclass(frozen=True)
class Signatures:
    """Signature values of one response (SI units)."""
    overshoot: float          # m, max position on the step minus the step level
    pressure_peak: float      # Pa, max P12 during the ramp
    pressure_plateau: float   # Pa, mean P12 over the last 40 % of the ramp
    motion_start: float       # s, first time the surface passes MOTION_THRESHOLD
    velocity_peak: float      # m/s, max surface velocity during the ramp
    current_peak: float       # A, max servovalve current during the ramp
    current_peak_time: float  # s, when it occurs

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def signatures(r: Response, sequence: FDISequence | None = None) -> Signatures:
    """Compute the signature features of a response to the FDI sequence."""
    seq = sequence or FDISequence()
    t = r.t
    ramp, step = seq.mask("ramp", t), seq.mask("step", t)
    if ramp.sum() < 10 or step.sum() < 10:
        raise ValueError("response does not cover the ramp and step segments of the FDI sequence")
    t0, t1 = seq.segments()["ramp"]
    plateau = ramp & (t >= t0 + 0.6 * (t1 - t0))
    moved = np.flatnonzero(ramp & (r.position > MOTION_THRESHOLD))
    i_peak = np.flatnonzero(ramp)[np.argmax(r.current[ramp])]
    return Signatures(
        overshoot=float(r.position[step].max() - seq.step_level),
        pressure_peak=float(r.pressure[ramp].max()),
        pressure_plateau=float(r.pressure[plateau].mean()),
        motion_start=float(t[moved[0]]) if moved.size else float(t1),
        velocity_peak=float(r.velocity[ramp].max()),
        current_peak=float(r.current[i_peak]),
        current_peak_time=float(t[i_peak]),
    )


#: Feature that flags each fault, and the direction in which damage moves it.
DETECTOR_FEATURES = {"gm": ("overshoot", -1.0), "fsj": ("pressure_plateau", +1.0),
                     "bkl": ("velocity_peak", +1.0)}


@dataclass
class Detector:
    """Coarse fault detector: which faults are present, from signature thresholds."""
    healthy: Signatures
    at_level: dict[str, Signatures]   # single fault at ``level``
    level: float
    margin: float

    @classmethod
    def build(cls, params: ModelParams | None = None, level: float = 0.2, margin: float = 0.8,
              kind: str = "reference") -> "Detector":
        """Thresholds from healthy and single-fault simulations at ``level`` damage."""
        healthy = signatures(simulate(kind, Faults(), params=params))
        at = {}
        for fault in DETECTOR_FEATURES:
            at[fault] = signatures(simulate(kind, Faults(**{f"k_{fault}": level}), params=params))
        return cls(healthy, at, level, margin)

    def thresholds(self) -> dict[str, float]:
        out = {}
        for fault, (feat, _) in DETECTOR_FEATURES.items():
            h, d = getattr(self.healthy, feat), getattr(self.at_level[fault], feat)
            out[fault] = h + self.margin * (d - h)
        return out

    def scores(self, sig: Signatures) -> dict[str, float]:
        """Each feature's shift from healthy in units of its shift at ``level`` damage."""
        out = {}
        for fault, (feat, _) in DETECTOR_FEATURES.items():
            h, d = getattr(self.healthy, feat), getattr(self.at_level[fault], feat)
            out[fault] = (getattr(sig, feat) - h) / (d - h)
        return out

    def detect(self, sig: Signatures) -> dict[str, bool]:
        """``{'gm': bool, 'fsj': bool, 'bkl': bool}``: fault present beyond the threshold."""
        return {f: s >= self.margin for f, s in self.scores(sig).items()}

    def coarse_estimate(self, sig: Signatures) -> Faults:
        """Rough fault coefficients: linear in the score, clipped to [0, 1] (a start point)."""
        sc = self.scores(sig)
        k = {f: float(np.clip(sc[f] * self.level, 0.0, 1.0)) for f in sc}
        return Faults(k["gm"], k["fsj"], k["bkl"])
