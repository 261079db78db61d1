"""Servo-amplifier: PID position loop, velocity feedback GAS, saturation, hysteresis.

    i_cmd = Kp e + Ki \\int e dt + Kd de/dt - GAS v_meas,   e = x_cmd - x_meas   [A]

saturated at +/- i_max, then passed through a play (backlash-type) hysteresis
of total width ``hyst`` [A]; the valve null bias is added last. Paper Sec. III.A.
With the vibration null shift on, the null moves by ``vib_gain <|a|>`` [A], where
``<|a|>`` [m/s^2] is the jack's mean absolute acceleration (state ``a_vib``, see
:func:`vibration_level_step`).
"""
from numba import njit

from .layout import (P_GAS, P_HYST, P_IBIAS, P_IMAX, P_KD, P_KI, P_KP, P_VIBFILT, P_VIBGAIN, P_VIBON,
                     P_VIBTAU, S_AVIB, S_EPREV, S_IH, S_INT, S_VF)


@njit(cache=True, error_model="numpy")
def servo_amplifier(p, s, x_cmd, x_meas, v_meas, dt):
    """One fine step of the controller; returns the valve current [A]."""
    e = x_cmd - x_meas
    s[S_INT] += e * dt
    de = (e - s[S_EPREV]) / dt
    s[S_EPREV] = e
    i = p[P_KP] * e + p[P_KI] * s[S_INT] + p[P_KD] * de - p[P_GAS] * v_meas
    i_max = p[P_IMAX]
    if i > i_max:
        i = i_max
    elif i < -i_max:
        i = -i_max
    # play operator: the output follows only once the input leaves the band
    half = 0.5 * p[P_HYST]
    ih = s[S_IH]
    if i > ih + half:
        ih = i - half
    elif i < ih - half:
        ih = i + half
    s[S_IH] = ih
    return ih + p[P_IBIAS] + p[P_VIBON] * p[P_VIBGAIN] * s[S_AVIB]


@njit(cache=True, error_model="numpy")
def vibration_level_step(p, s, v, dt):
    """Mean |acceleration| of the jack [m/s^2], given its new velocity ``v`` [m/s].

    The acceleration is that of the velocity seen through a first-order filter of
    time constant ``vib_filter`` [s] (the valve body feels the structure's vibration,
    not the fine-step detail of impacts), then averaged: tau d<|a|>/dt = |a| - <|a|>.
    """
    if p[P_VIBON] > 0.0:
        dv = dt / (p[P_VIBFILT] + dt) * (v - s[S_VF])
        s[S_VF] += dv
        s[S_AVIB] += dt / max(p[P_VIBTAU], dt) * (abs(dv) / dt - s[S_AVIB])
