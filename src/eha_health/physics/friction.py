"""Dry friction with robust stick-slip (Karnopp 1985; Borello & Dalla Vedova 2012).

While the jack is at rest it stays stuck as long as the active force (all forces
but friction, at zero velocity) is within the static friction F_s. Once moving,
the dynamic friction F_d (optionally Stribeck-shaped) opposes the velocity; a
velocity reversal inside a step stops the jack cleanly (v = 0) and the stick
test is applied again, so there is no chattering around v = 0.
"""
import math

from numba import njit



@njit(cache=True, error_model="numpy")
def sliding_friction(f_s, f_d, v_stribeck, v):
    """Magnitude of the friction force while sliding [N] (Stribeck curve if v_stribeck > 0)."""
    if v_stribeck > 0.0:
        r = v / v_stribeck
        return f_d + (f_s - f_d) * math.exp(-r * r)
    return f_d


@njit(cache=True, error_model="numpy")
def _slide(v_old, sgn, f0, b, f_max, f_ext, c, m, f_fric, dt):
    """Velocity after one sliding step; linear terms implicit, hydraulic force saturated.

    m v' = clip(f0 - b v, -f_max, f_max) + f_ext - c v - sgn f_fric
    """
    v = (m * v_old + dt * (f0 + f_ext - sgn * f_fric)) / (m + dt * (b + c))
    fh = f0 - b * v
    if fh > f_max:
        v = (m * v_old + dt * (f_max + f_ext - sgn * f_fric)) / (m + dt * c)
    elif fh < -f_max:
        v = (m * v_old + dt * (-f_max + f_ext - sgn * f_fric)) / (m + dt * c)
    return v


@njit(cache=True, error_model="numpy")
def stick_slip_velocity(v_old, f0, b, f_max, f_ext, c, m, f_s, f_d, v_stribeck, dt):
    """New velocity [m/s] of a mass under stick-slip dry friction.

    The driving force is ``clip(f0 - b v, +/- f_max)`` [N] (jack: b > 0 is the
    incompressible valve law, implicit; b = 0 with a pressure state), ``f_ext``
    the other external forces [N], ``c`` viscous friction [N s/m], ``m`` mass [kg],
    ``f_s``/``f_d`` static/dynamic friction [N], ``v_stribeck`` [m/s] (0: none).
    """
    if v_old != 0.0:
        sgn = 1.0 if v_old > 0.0 else -1.0
        v = _slide(v_old, sgn, f0, b, f_max, f_ext, c, m, sliding_friction(f_s, f_d, v_stribeck, v_old), dt)
        if v * sgn > 0.0:
            return v
        # reversal inside the step: stop here, then test for sticking
    f_act = min(max(f0, -f_max), f_max) + f_ext
    if abs(f_act) <= f_s:
        return 0.0
    sgn = 1.0 if f_act > 0.0 else -1.0
    v = _slide(0.0, sgn, f0, b, f_max, f_ext, c, m, sliding_friction(f_s, f_d, v_stribeck, 0.0), dt)
    return v if v * sgn > 0.0 else 0.0
