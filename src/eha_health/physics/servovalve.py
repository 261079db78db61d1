"""Two-stage flapper-nozzle servovalve and its fluid-dynamic block.

Reference first stage (physics, after Merritt, *Hydraulic Control Systems*, ch. 5):

* armature/flapper rotation theta [rad], flapper at the nozzles x_f = r theta::

      J_a theta'' = GM i - K_a theta - B_a theta'
                    - K_w (r+b) [(r+b) theta + x_s]      (feedback wire)
                    - r A_n (p_A - p_B)                  (nozzle jets on the flapper)

* nozzle bridge, quasi-static (the control chambers are tiny): each side is a
  fixed orifice from the pilot supply in series with a nozzle curtain of area
  pi d_n (x_f0 -/+ x_f); the chamber delivers the flow q to the spool end::

      a_0 sqrt(P_pilot - p) - a_n sqrt(p - P_r) = q            (closed form below)

* massless spool, driven by that flow and held by the feedback wire::

      A_s x_s' = q,     A_s (p_A - p_B) = K_w [(r+b) theta + x_s]

  so the valve is third order (theta, theta', x_s). Filter clogging lowers the
  pilot supply: P_pilot = P_r + (P_s - P_r)(1 - clog).

Monitor first stage (paper Sec. III.B): a second-order system driving an
integrating spool::

      y'' = w^2 (K_sv i - x_s - y) - 2 z w y',     x_s' = sat(y / tau_sp, v_max)

where v_max stands for the pilot-flow saturation of the real first stage.

Fluid-dynamic block (linearised theory, Jacazio & Borello 1987), saturated at the
supply differential pressure and with piston-seal leakage C_l::

      P12 = sat( G_P x_s - (G_P / K_q)(A v + C_l P12) ),  |P12| <= P_s - P_r
"""
import math

from numba import njit

from .layout import (P_AS, P_BA, P_CD0, P_CDN, P_CL, P_CLOG, P_D0, P_DN, P_GM, P_GP, P_JA,
                     P_KA, P_KQ, P_KSV, P_KW, P_OMFS, P_PR, P_PS, P_RHO, P_RN, P_RW, P_TAUSP, P_VSMAX,
                     P_XF0, P_XSMAX, P_ZFS, S_OM, S_Q, S_TH, S_XS, S_Y, S_YD)


@njit(cache=True, error_model="numpy")
def bridge_pressure(q, a0, an, p_pilot, p_r):
    """Chamber pressure [Pa] of one bridge arm delivering flow q [m^3/s], and dp/dq.

    Solves a0 sqrt(P - p) - an sqrt(p - P_r) = q exactly. With D = P - P_r,
    u = sqrt((P - p)/D), w = sqrt((p - P_r)/D), u^2 + w^2 = 1, c = q/sqrt(D):
    u = (a0 c + an S)/R^2, S = sqrt(R^2 - c^2), R^2 = a0^2 + an^2; p = P - D u^2.
    """
    d = p_pilot - p_r
    sd = math.sqrt(d)
    r2 = a0 * a0 + an * an
    c = q / sd
    c2 = c * c
    if c2 >= r2:  # flow beyond what the arm can pass: chamber at a pressure bound
        return (p_r if c > 0.0 else p_pilot), -1e-3 * d / (math.sqrt(r2) * sd)
    big_s = math.sqrt(r2 - c2)
    u = (a0 * c + an * big_s) / r2
    if u <= 0.0:
        return p_pilot, -1e-3 * d / (math.sqrt(r2) * sd)
    if a0 * big_s - an * c <= 0.0:  # w <= 0: chamber drained to return
        return p_r, -1e-3 * d / (math.sqrt(r2) * sd)
    p = p_pilot - d * u * u
    dpdq = -2.0 * sd * u * (a0 - an * c / big_s) / r2
    return p, dpdq


@njit(cache=True, error_model="numpy")
def first_stage_reference(p, s, current, dt):
    """Advance armature, nozzle bridge and spool one step; returns spool position [m]."""
    th, om, xs, q = s[S_TH], s[S_OM], s[S_XS], s[S_Q]
    rn, rw, kw, x0 = p[P_RN], p[P_RW], p[P_KW], p[P_XF0]
    a_s, xs_max = p[P_AS], p[P_XSMAX]
    k_or = math.sqrt(2.0 / p[P_RHO])
    a0 = p[P_CD0] * 0.25 * math.pi * p[P_D0] * p[P_D0] * k_or
    an_unit = p[P_CDN] * math.pi * p[P_DN] * k_or
    xf = rn * th
    an_a = an_unit * max(x0 - xf, 0.0)
    an_b = an_unit * max(x0 + xf, 0.0)
    p_r = p[P_PR]
    p_pilot = p_r + (p[P_PS] - p_r) * (1.0 - p[P_CLOG])
    f_wire = kw * (rw * th + xs)

    # spool force balance A_s (pA - pB) = F_wire: one Newton step per time step,
    # warm-started at the previous flow (q changes little over dt)
    pa, dpa = bridge_pressure(q, a0, an_a, p_pilot, p_r)
    pb, dpb = bridge_pressure(-q, a0, an_b, p_pilot, p_r)
    g = a_s * (pa - pb) - f_wire
    dg = a_s * (dpa + dpb)
    q_new = q - g / dg
    xs_new = xs + dt * q_new / a_s
    # the spool hits its stroke limit: the stop takes the force, no more flow
    if xs_new > xs_max:
        xs_new = xs_max
        q_new = 0.0 if q_new > 0.0 else q_new
    elif xs_new < -xs_max:
        xs_new = -xs_max
        q_new = 0.0 if q_new < 0.0 else q_new
    # bridge pressures at the new flow (first order in the Newton correction)
    dq = q_new - q
    dp_ab = (pa + dpa * dq) - (pb - dpb * dq)

    a_n = 0.25 * math.pi * p[P_DN] * p[P_DN]
    torque = (p[P_GM] * current - p[P_KA] * th - p[P_BA] * om
              - kw * rw * (rw * th + xs_new) - rn * a_n * dp_ab)
    om = om + dt * torque / p[P_JA]
    th = th + dt * om
    # the flapper cannot pass the nozzles
    th_max = 0.999 * x0 / rn
    if th > th_max:
        th = th_max
        om = min(om, 0.0)
    elif th < -th_max:
        th = -th_max
        om = max(om, 0.0)
    s[S_TH], s[S_OM], s[S_XS], s[S_Q] = th, om, xs_new, q_new
    return xs_new


@njit(cache=True, error_model="numpy")
def first_stage_monitor(p, s, current, dt):
    """Second-order first stage plus integrating spool; returns spool position [m]."""
    w, z = p[P_OMFS], p[P_ZFS]
    y, yd, xs = s[S_Y], s[S_YD], s[S_XS]
    u = p[P_KSV] * current - xs
    yd = yd + dt * (w * w * (u - y) - 2.0 * z * w * yd)
    y = y + dt * yd
    v = y / p[P_TAUSP]
    v_max = p[P_VSMAX]
    if v > v_max:
        v = v_max
    elif v < -v_max:
        v = -v_max
    xs = xs + dt * v
    xs_max = p[P_XSMAX]
    if xs > xs_max:
        xs = xs_max
    elif xs < -xs_max:
        xs = -xs_max
    s[S_Y], s[S_YD], s[S_XS] = y, yd, xs
    return xs


@njit(cache=True, error_model="numpy")
def load_pressure_law(p, xs):
    """Incompressible fluid block as P12 = P0 - R_q Q_jack: returns (P0 [Pa], R_q [Pa s/m^3])."""
    gp, kq = p[P_GP], p[P_KQ]
    denom = 1.0 + gp * p[P_CL] / kq
    return gp * xs / denom, gp / (kq * denom)


@njit(cache=True, error_model="numpy")
def chamber_pressure_step(p, p12, xs, q_jack, k_comp, dt):
    """Compressible chambers: dP12/dt = k (K_q x_s - (K_q/G_P + C_l) P12 - Q_jack), implicit."""
    kq = p[P_KQ]
    kc = kq / p[P_GP] + p[P_CL]
    return (p12 + dt * k_comp * (kq * xs - q_jack)) / (1.0 + dt * k_comp * kc)
