"""Jack-to-surface linkage with backlash, and the surface with its aerodynamic load.

Link force on the surface (the jack feels its reaction), dead band of total play b::

    d = x_j - x_u,   delta = d - sign(d) b/2 if |d| > b/2 else 0
    F_link = k delta + c (v_j - v_u)   in contact (never pulling across an open gap)

Surface (user) reduced to the jack axis, elastic hinge moment, damping and
hinge-bearing dry friction F_h (stick-slip, as the jack's)::

    m_u x_u'' = F_link - K_aero x_u - c_aero x_u' - F_load - F_h

The bearing friction holds the surface still while the jack crosses the gap
(the classic kinematic backlash); without it a free surface inside the play
is bounced by the loop into a limit cycle.
"""
from numba import njit

from .friction import stick_slip_velocity
from .layout import (P_BKL, P_CAERO, P_CLINK, P_FHINGE, P_FLOAD, P_KAERO, P_KLINK, P_MU, S_VJ,
                     S_VU, S_XJ, S_XU)


@njit(cache=True, error_model="numpy")
def link_force(p, s):
    """Force the jack applies to the surface [N]."""
    d = s[S_XJ] - s[S_XU]
    dv = s[S_VJ] - s[S_VU]
    half = 0.5 * p[P_BKL]
    if half <= 0.0:
        return p[P_KLINK] * d + p[P_CLINK] * dv
    if d > half:
        return max(p[P_KLINK] * (d - half) + p[P_CLINK] * dv, 0.0)
    if d < -half:
        return min(p[P_KLINK] * (d + half) + p[P_CLINK] * dv, 0.0)
    return 0.0


@njit(cache=True, error_model="numpy")
def surface_step(p, s, f_link, dt):
    """Advance the surface one step (stick-slip velocity, then position)."""
    f_act = f_link - p[P_KAERO] * s[S_XU] - p[P_FLOAD]
    fh = p[P_FHINGE]
    v = stick_slip_velocity(s[S_VU], f_act, 0.0, 1e300, 0.0, p[P_CAERO], p[P_MU], fh, fh, 0.0, dt)
    s[S_VU] = v
    s[S_XU] += dt * v
