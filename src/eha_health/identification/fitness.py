"""Fitness functions: how well a monitor response matches the measured one.

* ``lsq`` (default): normalised least squares over every measured channel and
  the whole test; each channel's difference is divided by a physical scale
  (``CHANNEL_SCALES``), so one scale of error weighs one unit; the pressure
  while the jack holds after the step and the return weighs less (``SEGMENT_WEIGHTS``).
* ``paper``: the paper's functions (Sec. V). Per fault, the absolute difference
  of one feature on its segment: FSJ the P12 peak during the ramp, GM the
  position peak on the step, BKL the velocity peak during the ramp. The GA's
  combined function sums the three (each relative to the measured value:
  "proportional scaling") and adds the squared position difference over the
  double-frequency sine (relative to the sine's own energy).

A :class:`Measured` holds the data the fitness compares against; the monitor
responses arrive as kernel output arrays ``[n, N_OUT]`` (or batches of them).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..physics.layout import O_CUR, O_P12, O_POS, O_VEL, O_XS
from ..signals.response import Response
from ..physics.sequence import FDISequence

#: Residual scale per channel [SI]: a difference of one scale weighs one unit.
CHANNEL_SCALES = {"position": 1e-4, "velocity": 5e-3, "pressure": 5e5, "current": 5e-4, "spool": 2e-5}
CHANNEL_COLUMNS = {"position": O_POS, "velocity": O_VEL, "pressure": O_P12, "current": O_CUR, "spool": O_XS}
#: Channels the default fitness uses (what a rig measures; the spool is rarely instrumented).
FIT_CHANNELS = ("position", "velocity", "pressure", "current")
#: Velocity weighs little: it repeats the position's information, and at backlash impacts
#: its spikes depend on contact details no monitor model gets right (measured: with
#: weight 1 the sine-segment velocity mismatch biased K_FSJ by 0.04 at K_GM = K_BKL = 1;
#: with 0.05 every coefficient of the single and combined cases is within 0.003).
CHANNEL_WEIGHTS = {"position": 1.0, "velocity": 0.05, "pressure": 1.0, "current": 1.0, "spool": 1.0}
#: Extra weight of one channel on one test segment (multiplies ``CHANNEL_WEIGHTS``). While the jack
#: holds after the step and the return, P12 rests wherever in the friction band the jack last stuck:
#: a micrometre of sticking point moves it by the valve's pressure gain, so the monitor's model
#: mismatch there, not the friction level, drives that part of the residual. Measured with the
#: Gauss-Newton bias at the true coefficients (clean reference runs, 9 paper + 6 random cases):
#: weight 1 -> K_FSJ bias up to 0.0069 (rms 0.0028); 0.1 -> up to 0.0020 (rms 0.0009); GM and BKL
#: unchanged. The ramp keeps full weight: its pressure peak is the breakaway, the friction itself.
SEGMENT_WEIGHTS = {("pressure", "step"): 0.1, ("pressure", "return"): 0.1}
#: Length of the blocks the residual is averaged over before squaring [s]. Backlash impacts and
#: stick-slip jumps put sub-millisecond spikes in pressure and current whose exact timing the
#: monitor cannot match; squared sample by sample, their misalignment dominates the cost and
#: makes it rough in the coefficients. Block means keep everything slower than ~50 Hz (the
#: sine runs at 2.5-4 Hz) and drop those spikes.
BLOCK_S = 0.01


@dataclass
class Measured:
    """Measured response prepared for fitting: channels, command and segment masks."""
    response: Response
    sequence: FDISequence
    channels: tuple[str, ...]

    @classmethod
    def from_response(cls, r: Response, sequence: FDISequence | None = None,
                      channels: tuple[str, ...] = FIT_CHANNELS) -> "Measured":
        seq = sequence or FDISequence()
        check_window(r, seq)
        for c in channels:
            if c not in CHANNEL_COLUMNS:
                raise ValueError(f"unknown channel {c!r}; known: {sorted(CHANNEL_COLUMNS)}")
        return cls(r, seq, tuple(channels))

    @property
    def command(self) -> np.ndarray:
        return self.response.command

    @property
    def t(self) -> np.ndarray:
        return self.response.t

    def mask(self, segment: str) -> np.ndarray:
        return self.sequence.mask(segment, self.t)


def check_window(r: Response, seq: FDISequence) -> None:
    """Raise ``ValueError`` if the record cannot be a run of ``seq`` at a usable rate."""
    t = r.t
    if len(t) < 100:
        raise ValueError(f"window too short: {len(t)} samples")
    dt = np.diff(t)
    if (dt <= 0).any():
        raise ValueError("time axis is not strictly increasing")
    rate = 1.0 / float(np.median(dt))
    if np.max(np.abs(dt - 1.0 / rate)) > 0.01 / rate:
        raise ValueError(f"samples are not uniformly spaced (median rate {rate:.1f} Hz): gaps or jitter")
    if abs(t[0]) > 0.5 / rate:
        raise ValueError(f"record starts at t={t[0]:g} s: the test window must start at t=0")
    if t[-1] + 1.0 / rate < seq.duration - 1e-9:
        raise ValueError(f"record covers {t[-1] + 1.0 / rate:.3f} s but the FDI sequence lasts {seq.duration:g} s")
    for c in ("command", "position", "velocity", "pressure", "current"):
        v = getattr(r, c)
        if not np.isfinite(v).all():
            raise ValueError(f"channel {c} has NaN or inf samples")


class LsqFitness:
    """Normalised least squares; ``residuals`` is what least-squares solvers take."""
    name = "lsq"

    def __init__(self, meas: Measured):
        self.meas = meas
        n = len(meas.t)
        self._cols = [CHANNEL_COLUMNS[c] for c in meas.channels]
        w = np.array([CHANNEL_WEIGHTS[c] / CHANNEL_SCALES[c] for c in meas.channels]) / np.sqrt(n)
        self._w = np.tile(w, (n, 1))              # [n, channels]: per sample and channel
        for (c, seg), v in SEGMENT_WEIGHTS.items():
            if c in meas.channels:
                self._w[meas.mask(seg), meas.channels.index(c)] *= v
        m = max(1, int(round(BLOCK_S * meas.response.sample_rate)))
        self._starts = np.arange(0, n, m)
        counts = np.diff(np.append(self._starts, n))
        self._block = (1.0 / np.sqrt(counts))[:, None]    # mean x sqrt(count): a smooth residual keeps its sum of squares
        self._y = np.column_stack([getattr(meas.response, c) for c in meas.channels])

    def residuals(self, out: np.ndarray) -> np.ndarray:
        """Weighted, block-averaged residual vector of one monitor output ``[n, N_OUT]``."""
        d = (out[:, self._cols] - self._y) * self._w
        return (np.add.reduceat(d, self._starts, axis=0) * self._block).ravel()

    def cost(self, out: np.ndarray) -> float:
        r = self.residuals(out)
        return float(r @ r)

    def costs(self, outs: np.ndarray) -> np.ndarray:
        d = (outs[:, :, self._cols] - self._y[None]) * self._w[None]
        d = np.add.reduceat(d, self._starts, axis=1) * self._block[None]
        return np.einsum("bnc,bnc->b", d, d)


class PaperFitness:
    """The paper's per-fault feature fitnesses and the GA's combined function."""
    name = "paper"

    def __init__(self, meas: Measured):
        self.meas = meas
        self.ramp, self.step, self.sine = meas.mask("ramp"), meas.mask("step"), meas.mask("sine")
        r = meas.response
        self.f_meas = np.array([r.pressure[self.ramp].max(), r.position[self.step].max(),
                                r.velocity[self.ramp].max()])
        self.x_sine = r.position[self.sine]
        self.sine_energy = float(np.sum(self.x_sine ** 2))

    def features(self, out: np.ndarray) -> np.ndarray:
        """[P12 peak on the ramp, position peak on the step, velocity peak on the ramp]."""
        return np.array([out[self.ramp, O_P12].max(), out[self.step, O_POS].max(), out[self.ramp, O_VEL].max()])

    def fsj(self, out) -> float:
        return abs(out[self.ramp, O_P12].max() - self.f_meas[0])

    def gm(self, out) -> float:
        return abs(out[self.step, O_POS].max() - self.f_meas[1])

    def bkl(self, out) -> float:
        return abs(out[self.ramp, O_VEL].max() - self.f_meas[2])

    def cost(self, out: np.ndarray) -> float:
        rel = np.abs(self.features(out) - self.f_meas) / np.abs(self.f_meas)
        sine = np.sum((out[self.sine, O_POS] - self.x_sine) ** 2) / self.sine_energy
        return float(rel.sum() + sine)

    def costs(self, outs: np.ndarray) -> np.ndarray:
        return np.array([self.cost(o) for o in outs])


FITNESSES = {"lsq": LsqFitness, "paper": PaperFitness}


def make_fitness(name: str, meas: Measured):
    if name not in FITNESSES:
        raise ValueError(f"unknown fitness {name!r}; choose from {', '.join(FITNESSES)}")
    return FITNESSES[name](meas)
