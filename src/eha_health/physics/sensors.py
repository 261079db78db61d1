"""Position transducer on the surface (user) side, and the acquisition chain.

Inside the loop (compiled): a pure delay of ``delay_steps`` fine steps (ring
buffer, linear interpolation between steps so the delay is a smooth parameter) and a calibration error, x_meas = (1 + e) x_u + bias; the velocity
channel is the transducer's rate, v_meas = (1 + e) v_u, delayed alike.

Outside the loop (numpy, seeded): white acquisition noise and quantisation of
the recorded channels. They do not feed back into the controller.
"""
import numpy as np
from numba import njit

from .layout import (O_CUR, O_P12, O_POS, O_VEL, P_DELAY, P_XBIAS, P_XGAIN, S_DIDX, S_VM, S_VU,
                     S_XM, S_XU)


@njit(cache=True, error_model="numpy")
def transducer_step(p, s, dbuf):
    """Push the true surface motion into the delay line; update the measured values."""
    n = dbuf.shape[0]
    i = int(s[S_DIDX])
    dbuf[i, 0] = s[S_XU]
    dbuf[i, 1] = s[S_VU]
    d = p[P_DELAY]
    m = int(d)
    a = d - m
    j0 = (i - m) % n
    j1 = (i - m - 1) % n
    g = p[P_XGAIN]
    s[S_XM] = g * ((1.0 - a) * dbuf[j0, 0] + a * dbuf[j1, 0]) + p[P_XBIAS]
    s[S_VM] = g * ((1.0 - a) * dbuf[j0, 1] + a * dbuf[j1, 1])
    s[S_DIDX] = (i + 1) % n


def delay_buffer(p: np.ndarray) -> np.ndarray:
    """Ring buffer (rows: fine steps, cols: position, velocity) for a parameter vector."""
    return np.zeros((int(p[P_DELAY]) + 2, 2))


def acquisition(out: np.ndarray, effects, rng: np.random.Generator | None) -> np.ndarray:
    """Apply acquisition noise (needs ``rng``) and quantisation to kernel outputs, in place."""
    chans = ((O_POS, "position"), (O_VEL, "velocity"), (O_P12, "pressure"), (O_CUR, "current"))
    if effects.sensor_noise.enabled:
        if rng is None:
            raise ValueError("sensor noise is enabled: a seed is required")
        # one row of draws per sample, so the stream does not depend on how a run is chunked
        z = rng.standard_normal((out.shape[0], len(chans)))
        for j, (col, name) in enumerate(chans):
            out[:, col] += getattr(effects.sensor_noise, name) * z[:, j]
    if effects.quantization.enabled:
        for col, name in chans:
            q = getattr(effects.quantization, name)
            out[:, col] = np.round(out[:, col] / q) * q
    return out
