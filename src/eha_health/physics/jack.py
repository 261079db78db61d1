"""Hydraulic jack: inertia, viscous and dry friction, leakage, end-of-travel stops.

    m_j x_j'' = A P12 - c x_j' - F_dry + F_ext,    |x_j| <= stroke

Without compressibility (paper's model) P12 comes algebraically from the fluid
block, P12 = P0(x_s) - R_q A x_j', whose R_q A^2 term is a very stiff damper:
it is integrated implicitly. With compressibility P12 is a state:

    dP12/dt = (2 beta / V0) (K_q x_s - (K_q/G_P + C_l) P12 - A x_j')

An asymmetric valve or jack (unequal metering edges, single-rod piston) is
lumped as the block seeing x_s (1 + a sign x_s), a = hydraulics.flow_asymmetry.
"""
from numba import njit

from .friction import stick_slip_velocity
from .layout import (P_AREA, P_BETA, P_COMP, P_CV, P_FASYM, P_FD, P_FS, P_MJ, P_PR, P_PS, P_STRIB,
                     P_V0, P_VSTRIB, P_XMAX, S_P12, S_VJ, S_XJ)
from .servovalve import chamber_pressure_step, load_pressure_law


@njit(cache=True, error_model="numpy")
def jack_step(p, s, xs, f_ext, dt):
    """Advance jack velocity, position and P12 one step given the spool position."""
    # unequal metering edges (or piston areas): extend and retract see different gains
    xs = xs * (1.0 + p[P_FASYM]) if xs > 0.0 else xs * (1.0 - p[P_FASYM])
    area = p[P_AREA]
    p_max = p[P_PS] - p[P_PR]
    v_old = s[S_VJ]
    v_s = p[P_VSTRIB] if p[P_STRIB] > 0.0 else 0.0
    fric = (p[P_FS], p[P_FD], v_s)
    if p[P_COMP] > 0.0:
        k_comp = 2.0 * p[P_BETA] / p[P_V0]
        p12 = chamber_pressure_step(p, s[S_P12], xs, area * v_old, k_comp, dt)
        p12 = min(max(p12, -p_max), p_max)
        v = stick_slip_velocity(v_old, area * p12, 0.0, area * p_max, f_ext, p[P_CV], p[P_MJ],
                                fric[0], fric[1], fric[2], dt)
    else:
        p0, r_q = load_pressure_law(p, xs)
        b = r_q * area * area
        v = stick_slip_velocity(v_old, area * p0, b, area * p_max, f_ext, p[P_CV], p[P_MJ],
                                fric[0], fric[1], fric[2], dt)
        p12 = min(max(p0 - r_q * area * v, -p_max), p_max)
    x = s[S_XJ] + dt * v
    x_max = p[P_XMAX]
    if x > x_max:
        x = x_max
        v = min(v, 0.0)
    elif x < -x_max:
        x = -x_max
        v = max(v, 0.0)
    s[S_XJ], s[S_VJ], s[S_P12] = x, v, p12
