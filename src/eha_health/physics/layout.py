"""Flat layouts shared by the Python side and the compiled kernels.

The numba kernels read one float64 parameter vector ``p`` and one state
vector ``s``; the names below are their indices. Python builds ``p`` from
typed dataclasses (:mod:`eha_health.physics.params`), so the kernels never see a
magic number and never depend on Python objects.

Adding a parameter: append a name to ``P_NAMES`` and an index constant with
the same position (``tests/test_params.py`` checks they agree).
"""

P_NAMES = (
    # integration
    "dt", "steps_per_sample", "model",
    # controller (servo-amplifier)
    "kp", "ki", "kd", "gas", "i_max", "hyst", "i_bias",
    # torque motor
    "gm",
    # reference first stage: armature + flapper-nozzle + feedback wire
    "j_a", "b_a", "k_a", "r_n", "r_w", "k_w", "d_n", "x_f0", "d_0",
    "cd_0", "cd_n", "rho", "clog", "a_s",
    # monitor first stage: second-order system
    "omega_fs", "zeta_fs", "tau_sp", "k_sv",
    # spool and fluid-dynamic block
    "xs_max", "p_s", "p_r", "k_q", "g_p", "c_l",
    # jack
    "area", "m_j", "c_v", "f_s", "f_d", "x_max",
    # jack-to-surface linkage (backlash) and surface with its load
    "k_link", "c_link", "backlash", "m_u", "k_aero", "c_aero", "f_load",
    # optional effects
    "comp_on", "beta", "v0", "delay_steps", "x_bias", "x_gain",
    "stribeck_on", "v_stribeck",
    # monitor spool rate limit (pilot-flow saturation)
    "vs_max",
    # surface hinge-bearing friction
    "f_hinge",
    # extend/retract flow-gain asymmetry of the valve-jack fluid block
    "flow_asym",
    # vibration-rectified valve null shift: switch, current per mean |acceleration|, averaging time,
    # velocity filter ahead of the acceleration
    "vib_on", "vib_gain", "vib_tau", "vib_filter",
    # recording chain of the command: the actuator receives (recorded - offset) / gain
    "cmd_offset", "cmd_gain",
)

# --- parameter indices (keep in the order of P_NAMES) ---
P_DT, P_NSUB, P_MODEL = 0, 1, 2
P_KP, P_KI, P_KD, P_GAS, P_IMAX, P_HYST, P_IBIAS = 3, 4, 5, 6, 7, 8, 9
P_GM = 10
(P_JA, P_BA, P_KA, P_RN, P_RW, P_KW, P_DN, P_XF0, P_D0,
 P_CD0, P_CDN, P_RHO, P_CLOG, P_AS) = range(11, 25)
P_OMFS, P_ZFS, P_TAUSP, P_KSV = 25, 26, 27, 28
P_XSMAX, P_PS, P_PR, P_KQ, P_GP, P_CL = 29, 30, 31, 32, 33, 34
P_AREA, P_MJ, P_CV, P_FS, P_FD, P_XMAX = 35, 36, 37, 38, 39, 40
P_KLINK, P_CLINK, P_BKL, P_MU, P_KAERO, P_CAERO, P_FLOAD = range(41, 48)
P_COMP, P_BETA, P_V0, P_DELAY, P_XBIAS, P_XGAIN = range(48, 54)
P_STRIB, P_VSTRIB = 54, 55
P_VSMAX = 56
P_FHINGE = 57
P_FASYM = 58
P_VIBON, P_VIBGAIN, P_VIBTAU, P_VIBFILT = 59, 60, 61, 62
P_CMDOFF, P_CMDGAIN = 63, 64
N_P = len(P_NAMES)

MODEL_REFERENCE = 0.0
MODEL_MONITOR = 1.0

S_NAMES = (
    "t", "xs", "theta", "omega", "q", "y", "yd", "xj", "vj", "xu", "vu",
    "p12", "integ", "e_prev", "i_h", "d_idx", "i_v", "x_meas", "v_meas", "a_vib", "v_filt",
)
(S_T, S_XS, S_TH, S_OM, S_Q, S_Y, S_YD, S_XJ, S_VJ, S_XU, S_VU,
 S_P12, S_INT, S_EPREV, S_IH, S_DIDX, S_IV, S_XM, S_VM, S_AVIB, S_VF) = range(21)
N_S = len(S_NAMES)

# Columns the kernel writes, one row per output sample.
OUT_NAMES = ("command", "position", "velocity", "pressure", "current", "spool", "jack_position")
O_CMD, O_POS, O_VEL, O_P12, O_CUR, O_XS, O_XJ = range(7)
N_OUT = len(OUT_NAMES)
