"""Checks of a recorded channel that no model refit explains: quantisation, clipping, interference.

* quantisation: the channel takes values on a grid of step q (an ADC or a coarse encoder);
  its error is uniform, standard deviation q / sqrt(12), and is named when that reaches a
  quarter of the channel's noise;
* clipping: many samples pinned at the channel's extreme value, far more than at the level next
  to it (a transducer or amplifier at its range) -- they carry no information about the actuator;
* periodic interference: a narrow peak of the residual spectrum (5 bins around the largest
  line hold >= ``share`` of its power) above the command's band (mains hum, a pump's
  ripple), named with its frequency.
"""
from __future__ import annotations

import numpy as np

from .residuals import spectrum_peak


def quantisation_step(y: np.ndarray) -> float:
    """The grid step [channel unit] the samples lie on, or 0 when they do not lie on one."""
    u = np.unique(np.asarray(y, float))
    if len(u) < 3 or len(u) > 0.5 * len(y):
        return 0.0
    d = np.diff(u)
    q = float(np.min(d))
    if q <= 0 or np.any(np.abs(d / q - np.round(d / q)) > 0.05):
        return 0.0
    return q


def clipped_share(y: np.ndarray, min_run: int = 3, factor: float = 3.0) -> float:
    """Share of samples pinned at the channel's max or min: at least ``min_run`` of them, and
    ``factor`` times as many as at the next level inward (a smooth or quantised peak dwells
    about as long on its top level as on the one below it; a clipped one far longer)."""
    y = np.asarray(y, float)
    u, counts = np.unique(y, return_counts=True)
    if len(u) < 3:
        return 0.0
    pinned = 0
    for ext, nb in ((counts[-1], counts[-2]), (counts[0], counts[1])):
        if ext >= min_run and ext >= factor * nb:
            pinned += ext
    return float(pinned / len(y))


def command_band(command: np.ndarray, rate: float, power: float = 0.99) -> float:
    """Frequency [Hz] below which ``power`` of the (detrended) command's power lies."""
    x = np.asarray(command, float) - np.mean(command)
    p = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / rate)
    c = np.cumsum(p) / max(p.sum(), 1e-300)
    return float(f[min(int(np.searchsorted(c, power)), len(f) - 1)])


def check_channel(name: str, y: np.ndarray, residual: np.ndarray, noise_sd: float, command: np.ndarray,
                  rate: float, share: float = 0.3) -> list[str]:
    """One line per finding on the recorded channel ``y`` (its fit ``residual``, ``noise_sd``)."""
    out = []
    q = quantisation_step(y)
    if q > 0 and q / np.sqrt(12.0) >= 0.25 * noise_sd:
        out.append(f"{name}: quantised in steps of {q:.3g} (error {q / np.sqrt(12.0):.3g} rms against noise "
                   f"{noise_sd:.3g})")
    c = clipped_share(y)
    if c >= 0.005:
        out.append(f"{name}: {100 * c:.1f} % of the samples pinned at the channel's extreme value (clipping at "
                   f"the transducer's range?)")
    f_pk, s = spectrum_peak(residual, rate)
    band = command_band(command, rate)
    if s >= share and f_pk > 2.0 * band:
        out.append(f"{name}: periodic interference at {f_pk:.1f} Hz ({100 * s:.0f} % of the residual power), "
                   f"above the command's band ({band:.1f} Hz)")
    return out
