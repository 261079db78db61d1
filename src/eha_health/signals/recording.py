"""Measurement-chain effects: what a recording chain does to a signal after the actuator made it.

They act on the recorded output, not in the loop (the controller never sees them), so applying
one needs no new simulation. For a channel y(t) sampled at ``rate`` [Hz]:

* offset   y + b                                   [channel unit]
* scale    (1 + e) y                               [-]
* skew     y(t - d), d > 0 late, sub-sample by linear interpolation, ends held   [s]
* lag      first-order sensor, tau dy_m/dt = y - y_m, exact for an input linear between
           samples (first-order hold), y_m(0) = y(0)   [s]
* drift    y + r t, t from the record's first sample (a transducer zero that wanders with
           temperature, a charge amplifier's leak)   [channel unit / s]
* stretch  y((1 + e) t): the channel sampled on a time base (1 + e) faster than the command's
           (a logger clock or a stated sample rate off by e), sub-sample, ends held   [-]

All are linear in y, so their order in a chain does not matter (up to the ends).
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

#: The measurement-chain effects, each ``f(y, value, rate) -> y_recorded``, and their units
#: relative to the channel's (``"channel"``: the channel's own unit).
KINDS = ("offset", "scale", "skew", "lag", "drift")
UNIT = {"offset": "channel", "scale": "-", "skew": "s", "lag": "s", "drift": "channel/s", "stretch": "-"}


def offset(y: np.ndarray, b: float, rate: float) -> np.ndarray:
    return y + b


def scale(y: np.ndarray, e: float, rate: float) -> np.ndarray:
    return y * (1.0 + e)


def skew(y: np.ndarray, d: float, rate: float) -> np.ndarray:
    """``y`` recorded ``d`` [s] late (early for d < 0)."""
    if d == 0.0:
        return y
    k = np.arange(len(y), dtype=float)
    return np.interp(k - d * rate, k, y)


def lag(y: np.ndarray, tau: float, rate: float) -> np.ndarray:
    """``y`` through a first-order sensor of time constant ``tau`` [s]: the exact response to an
    input linear between samples (first-order hold), with h = 1 / (rate tau), a = exp(-h):
    y_m[n] = a y_m[n-1] + (1 - (1-a)/h) y[n] + ((1-a)/h - a) y[n-1]. A real transducer sees
    the continuous signal; feeding the sample through at once (y_m[n] = a y_m[n-1] + (1-a) y[n])
    is half a sample early, which at the FDI test's pressure steps was 10.5 % of the channel's
    range against a bilinear sensor (this form: 0.5 %), and so near a 0.5 ms skew that a
    lagged recording was named as skewed."""
    if tau <= 0.0:
        return y
    h = 1.0 / (rate * tau)
    a = float(np.exp(-h))
    b0, b1 = 1.0 - (1.0 - a) / h, (1.0 - a) / h - a
    return lfilter([b0, b1], [1.0, -a], y - y[0]) + y[0]


def drift(y: np.ndarray, r: float, rate: float) -> np.ndarray:
    """``y`` + r t [channel unit], t [s] from the first sample."""
    return y + r * (np.arange(len(y)) / rate)


def stretch(y: np.ndarray, e: float, rate: float) -> np.ndarray:
    """``y`` sampled on a time base (1 + e) too fast: sample k holds y(k (1 + e) / rate)."""
    if e == 0.0:
        return y
    k = np.arange(len(y), dtype=float)
    return np.interp(k * (1.0 + e), k, y)


APPLY = {"offset": offset, "scale": scale, "skew": skew, "lag": lag, "drift": drift, "stretch": stretch}


def undo(kind: str, y: np.ndarray, value: float, rate: float) -> np.ndarray:
    """The signal before the effect ``kind`` of size ``value`` (the recording corrected).

    The lag's exact inverse would have a pole near -1 (at 3 ms and 1 kHz: -0.9, white noise
    raised ~100x), so it is undone as a half-sample advance (linear interpolation) followed by
    the exact inverse of the sample-fed lag, x[n] = (z[n] - a z[n-1]) / (1 - a): white noise
    raised ~2x, the signal restored to ~1 % of its range except over a step's own sample."""
    if kind == "offset":
        return y - value
    if kind == "scale":
        return y / (1.0 + value)
    if kind == "skew":
        return skew(y, -value, rate)
    if kind == "drift":
        return drift(y, -value, rate)
    if kind == "stretch":
        k = np.arange(len(y), dtype=float)
        return np.interp(k / (1.0 + value), k, y)
    if value <= 0.0:
        return y
    a = float(np.exp(-1.0 / (rate * value)))
    z = skew(y, -0.5 / rate, rate)
    return np.concatenate([z[:1], (z[1:] - a * z[:-1]) / (1.0 - a)])
