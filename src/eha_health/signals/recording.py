"""Measurement-chain effects: what a recording chain does to a signal after the actuator made it.

They act on the recorded output, not in the loop (the controller never sees them), so applying
one needs no new simulation. For a channel y(t) sampled at ``rate`` [Hz]:

* offset   y + b                                   [channel unit]
* scale    (1 + e) y                               [-]
* skew     y(t - d), d > 0 late, sub-sample by linear interpolation, ends held   [s]
* lag      first-order sensor, tau dy_m/dt = y - y_m, exact for a sample-held input,
           y_m(0) = y(0)                           [s]

All four are linear in y, so their order in a chain does not matter (up to the ends).
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

#: The measurement-chain effects, each ``f(y, value, rate) -> y_recorded``, and their units
#: relative to the channel's (``"channel"``: the channel's own unit).
KINDS = ("offset", "scale", "skew", "lag")
UNIT = {"offset": "channel", "scale": "-", "skew": "s", "lag": "s"}


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
    """``y`` through a first-order sensor of time constant ``tau`` [s]."""
    if tau <= 0.0:
        return y
    a = float(np.exp(-1.0 / (rate * tau)))
    out, _ = lfilter([1.0 - a], [1.0, -a], y, zi=[a * y[0]])
    return out


APPLY = {"offset": offset, "scale": scale, "skew": skew, "lag": lag}


def undo(kind: str, y: np.ndarray, value: float, rate: float) -> np.ndarray:
    """The signal before the effect ``kind`` of size ``value`` (the recording corrected). The lag's
    inverse is the discrete filter's exact inverse, which raises white noise by sqrt((1+a)/(1-a))."""
    if kind == "offset":
        return y - value
    if kind == "scale":
        return y / (1.0 + value)
    if kind == "skew":
        return skew(y, -value, rate)
    if value <= 0.0:
        return y
    a = float(np.exp(-1.0 / (rate * value)))
    return np.concatenate([y[:1], (y[1:] - a * y[:-1]) / (1.0 - a)])

