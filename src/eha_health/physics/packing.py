"""Packing: a parameter set plus fault coefficients -> the flat vector the kernels read.

Fault coefficients map to physics here, and only here:

* ``K_GM``  torque-motor gain ``GM * (1 - gm_loss * K_GM)`` (gm_loss = 0.5)
* ``K_FSJ`` jack dry friction ``F * (1 + friction_gain * K_FSJ)`` (static and
  dynamic, ratio kept: worn seals raise both, paper Fig. 5)
* ``K_BKL`` jack-to-surface backlash ``b0 + backlash * K_BKL`` [m, total play]
"""
from __future__ import annotations

import numpy as np

from . import layout as L
from .faults import Faults
from .params import ModelParams


def effective(params: ModelParams, faults: Faults) -> dict[str, float]:
    """Physical values after the faults are applied (GM or static gain, friction, backlash)."""
    lim = params.fault_limits
    if faults.k_gm * lim.gm_loss >= 1.0:
        raise ValueError(f"fault coefficient k_gm={faults.k_gm} removes all torque-motor gain "
                         f"(must be < {1.0 / lim.gm_loss:g})")
    gscale = 1.0 - lim.gm_loss * faults.k_gm
    fscale = 1.0 + lim.friction_gain * faults.k_fsj
    return {
        "gm": params.torque_motor.gm * gscale,
        "k_sv": params.first_stage.static_gain * gscale,
        "f_s": params.jack.static_friction * fscale,
        "f_d": params.jack.dynamic_friction * fscale,
        "backlash": params.linkage.backlash + lim.backlash * faults.k_bkl,
    }


def pack(params: ModelParams, faults: Faults = Faults()) -> np.ndarray:
    """Flat float64 parameter vector for the kernels (indices in :mod:`layout`)."""
    p = np.zeros(L.N_P)
    ig, c, fn, fs2 = params.integration, params.controller, params.flapper_nozzle, params.first_stage
    h, j, lk, s, e = params.hydraulics, params.jack, params.linkage, params.surface, params.effects
    eff = effective(params, faults)
    nsub = params.integration.dt * params.integration.sample_rate
    nsub = round(1.0 / nsub)
    if abs(nsub * ig.dt * ig.sample_rate - 1.0) > 1e-9:
        raise ValueError(f"integration.dt={ig.dt} s must divide the sample period 1/{ig.sample_rate} s exactly")
    if h.supply_pressure <= h.return_pressure:
        raise ValueError("hydraulics.supply_pressure must exceed hydraulics.return_pressure")
    if j.dynamic_friction > j.static_friction:
        raise ValueError("jack.dynamic_friction must not exceed jack.static_friction")
    p[L.P_DT], p[L.P_NSUB] = ig.dt, nsub
    p[L.P_MODEL] = L.MODEL_REFERENCE if params.kind == "reference" else L.MODEL_MONITOR
    p[L.P_KP], p[L.P_KI], p[L.P_KD], p[L.P_GAS] = c.kp, c.ki, c.kd, c.gas
    p[L.P_IMAX], p[L.P_HYST], p[L.P_IBIAS] = c.i_max, c.hysteresis, c.null_bias
    p[L.P_GM] = eff["gm"]
    p[L.P_JA], p[L.P_BA], p[L.P_KA] = fn.inertia, fn.damping, fn.stiffness
    p[L.P_RN], p[L.P_RW], p[L.P_KW] = fn.nozzle_arm, fn.wire_arm, fn.wire_stiffness
    p[L.P_DN], p[L.P_XF0], p[L.P_D0] = fn.nozzle_diameter, fn.null_gap, fn.orifice_diameter
    p[L.P_CD0], p[L.P_CDN], p[L.P_RHO] = fn.cd_orifice, fn.cd_nozzle, fn.oil_density
    p[L.P_CLOG], p[L.P_AS] = fn.clogging, fn.spool_end_area
    p[L.P_OMFS], p[L.P_ZFS], p[L.P_TAUSP] = fs2.natural_frequency, fs2.damping_ratio, fs2.spool_time_constant
    p[L.P_KSV], p[L.P_VSMAX] = eff["k_sv"], fs2.spool_rate_limit
    p[L.P_XSMAX], p[L.P_PS], p[L.P_PR] = h.spool_stroke, h.supply_pressure, h.return_pressure
    p[L.P_KQ], p[L.P_GP], p[L.P_CL] = h.flow_gain, h.pressure_gain, h.leakage
    p[L.P_FASYM] = h.flow_asymmetry
    p[L.P_AREA], p[L.P_MJ], p[L.P_CV] = j.area, j.mass, j.viscous
    p[L.P_FS], p[L.P_FD], p[L.P_XMAX] = eff["f_s"], eff["f_d"], j.stroke
    p[L.P_KLINK], p[L.P_CLINK], p[L.P_BKL] = lk.stiffness, lk.damping, eff["backlash"]
    p[L.P_MU], p[L.P_KAERO], p[L.P_CAERO], p[L.P_FLOAD] = s.mass, s.hinge_stiffness, s.damping, s.external_force
    p[L.P_FHINGE] = s.hinge_friction
    if e.compressibility.enabled:
        p[L.P_COMP], p[L.P_BETA], p[L.P_V0] = 1.0, e.compressibility.bulk_modulus, e.compressibility.chamber_volume
    if e.sensor_delay.enabled:
        p[L.P_DELAY] = e.sensor_delay.delay / ig.dt   # fractional: interpolated in the kernel
    p[L.P_XGAIN] = 1.0
    if e.sensor_calibration.enabled:
        p[L.P_XBIAS], p[L.P_XGAIN] = e.sensor_calibration.bias, 1.0 + e.sensor_calibration.gain_error
    p[L.P_CMDGAIN] = 1.0
    if e.command_calibration.enabled:
        p[L.P_CMDOFF], p[L.P_CMDGAIN] = e.command_calibration.offset, 1.0 + e.command_calibration.gain_error
    if e.stribeck.enabled:
        p[L.P_STRIB], p[L.P_VSTRIB] = 1.0, e.stribeck.velocity
    if e.vibration_null_shift.enabled:
        v = e.vibration_null_shift
        p[L.P_VIBON], p[L.P_VIBGAIN], p[L.P_VIBTAU] = 1.0, v.gain, v.time_constant
        p[L.P_VIBFILT] = v.velocity_filter
    return p
