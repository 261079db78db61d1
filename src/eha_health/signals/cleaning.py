"""What a recording carries that no actuator model explains, taken out before a fit.

The data checks (:mod:`.datachecks`) name it; this module acts on it, channel by channel, against
a model output of the record (the diagnosis it starts from):

* **samples with no information** -- one-sample spikes (:func:`~.datachecks.spikes`), samples
  pinned at a transducer's range while the model goes beyond it (:func:`~.datachecks.clipped`, on a
  channel with measurable noise and from the share the data check names) and runs a logger froze
  (:func:`~.datachecks.frozen`) -- are *excluded*: weight 0 in every fit, and
  filled with the model's value so that the residual statistics, the noise estimate and the
  kinematic evidence do not see them;
* **periodic interference** -- a line of the residual spectrum above twice the command's band
  (mains hum, a pump's ripple) holding >= 30 % of its power and *stationary* (the same amplitude
  and phase on both halves of the record, as a pick-up is and a limit cycle of the actuator is
  not) -- is fitted as a sinusoid (frequency refined within one spectral bin) and *removed*.

Measured (one noisy FDI test at faults (0.3, 0.4, 0.3), seed 777; ``tools/unlisted_effects.py``):
five 1 mm spikes, position frozen for 25 ms every 0.5 s and a 10 um, 60 Hz hum on the position
each read "structured residual that no candidate effect explains" before.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .channels import UNITS
from .datachecks import CLIPPED_SHARE, clipped, command_band, frozen, noisy, quantisation_step, spikes
from .residuals import noise_level, spectrum_peak

#: A residual line holding this share of the power, above twice the command's band, is interference.
LINE_SHARE = 0.3
#: Halves of the record whose fitted amplitudes differ by more than this factor, or phases by more
#: than :data:`PHASE_RAD`, are not one stationary interference.
AMPLITUDE_FACTOR = 1.5
PHASE_RAD = 0.5


@dataclass
class Cleaned:
    """The recording cleaned: ``channels`` with the excluded samples filled from the model and the
    interference removed; ``excluded``: channel -> mask of the samples with no information;
    ``removed``: channel -> (frequency [Hz], amplitude [channel unit]) of the interference taken
    out; ``lines``: one per finding, for the report."""
    channels: dict[str, np.ndarray]
    excluded: dict[str, np.ndarray] = field(default_factory=dict)
    removed: dict[str, tuple[float, float]] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        return bool(self.excluded or self.removed)


def _sinusoid(t: np.ndarray, r: np.ndarray, f: float) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (a, b) of r ~ a sin(2 pi f t) + b cos(2 pi f t) (with an offset), and the fit."""
    A = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
    c = np.linalg.lstsq(A, r, rcond=None)[0]
    return c[:2], A[:, :2] @ c[:2]


def interference(t: np.ndarray, residual: np.ndarray, command: np.ndarray, rate: float) -> tuple[float, np.ndarray] | None:
    """The stationary periodic interference in ``residual`` (model - recording) as (frequency [Hz],
    its fitted waveform in the residual), or None."""
    f0, share = spectrum_peak(residual, rate)
    if share < LINE_SHARE or f0 <= 2.0 * command_band(command, rate):
        return None
    r = np.asarray(residual, float) - np.mean(residual)
    bin_hz = rate / len(r)
    # the FFT's line falls on its bin grid; the fit wants the frequency itself
    grid = f0 + np.linspace(-bin_hz, bin_hz, 41)
    f = float(grid[np.argmax([np.hypot(*_sinusoid(t, r, g)[0]) for g in grid])])
    half = len(r) // 2
    (a1, b1), _ = _sinusoid(t[:half], r[:half], f)
    (a2, b2), _ = _sinusoid(t[half:], r[half:], f)
    m1, m2 = np.hypot(a1, b1), np.hypot(a2, b2)
    dphi = abs(np.angle(np.exp(1j * (np.arctan2(b1, a1) - np.arctan2(b2, a2)))))
    if min(m1, m2) <= 0 or max(m1, m2) / min(m1, m2) > AMPLITUDE_FACTOR or dphi > PHASE_RAD:
        return None
    return f, _sinusoid(t, r, f)[1]


def clean(t: np.ndarray, channels: dict[str, np.ndarray], model: dict[str, np.ndarray], command: np.ndarray,
          rate: float) -> Cleaned:
    """``channels`` (recorded, SI) cleaned against ``model`` (the same channels of a model output)."""
    out = Cleaned(dict(channels))
    for c, y in channels.items():
        y, m = np.asarray(y, float), np.asarray(model[c], float)
        unit = UNITS.get(c, "")
        sd, q = noise_level(y), quantisation_step(y)
        cl = clipped(y, m, max(q, 2.0 * sd))
        # (the noise off the pinned samples: a channel clipped most of the time reads 0 over all of them)
        if not noisy(y, noise_level(y, cl)) or np.mean(cl) < CLIPPED_SHARE:
            # as the data check names it: a noise-free plateau at the model's overshoot is not a range
            cl = np.zeros(len(y), bool)
        parts = {"spikes": np.zeros(len(y), bool), "clipped": cl, "frozen": frozen(y, m, sd, q) & ~cl}
        parts["spikes"][spikes(y, m, sd, q)] = True
        bad = parts["spikes"] | parts["clipped"] | parts["frozen"]
        if bad.any():
            y = np.where(bad, m, y)
            out.excluded[c] = bad
            what = ", ".join(f"{int(v.sum())} {k}" for k, v in parts.items() if v.any())
            out.lines.append(f"{c}: {int(bad.sum())} sample(s) excluded from the fit ({what}): no information "
                             f"about the actuator")
        found = interference(t, m - y, command, rate)
        if found is not None:
            f, wave = found
            y = y + wave               # the residual model - y held -interference: y + wave is y without it
            amp = float(np.sqrt(2.0) * np.std(wave))
            out.removed[c] = (f, amp)
            out.lines.append(f"{c}: periodic interference at {f:.2f} Hz, amplitude {amp:.3g} {unit}, removed "
                             f"before the fit (stationary over the record: not the actuator)")
        out.channels[c] = y
    return out
