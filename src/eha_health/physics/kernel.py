"""The compiled simulation loop: all blocks composed at the fine step.

One fine step (dt), in causal order::

    controller(x_cmd, x_meas, v_meas) -> i  -> first stage -> x_s
    -> link force -> jack (P12, x_j) -> surface (x_u) -> transducer (x_meas)

The command is held over each output sample (zero-order hold, as a digital
command at the sample rate). ``run`` works on an explicit state vector so a
caller can advance the model chunk by chunk (the ROS plant node does); the
outputs of sample k are the values at t_k, before the command cmd[k] acts.
"""
import numpy as np
from numba import njit, prange

from .controller import servo_amplifier, vibration_level_step
from .jack import jack_step
from .layout import (N_OUT, N_S, O_CMD, O_CUR, O_P12, O_POS, O_VEL, O_XJ, O_XS, P_CMDGAIN, P_CMDOFF,
                     P_DELAY, P_DT, P_MODEL, P_NSUB, P_XBIAS, S_IV, S_P12, S_VJ, S_VM, S_XJ, S_XM, S_XS)
from .linkage import link_force, surface_step
from .sensors import transducer_step
from .servovalve import first_stage_monitor, first_stage_reference


@njit(cache=True, error_model="numpy")
def init_state(p, s, dbuf):
    """At rest at the origin, healthy null: the state every test run starts from."""
    s[:] = 0.0
    dbuf[:, :] = 0.0
    s[S_XM] = p[P_XBIAS]


@njit(cache=True, error_model="numpy")
def run(p, s, cmd, load, noise, dbuf, out):
    """Advance ``len(cmd)`` output samples; writes ``out[k, :]`` (see layout.OUT_NAMES).

    ``load`` is a measured external force on the surface per sample [N], opposing
    +x like ``f_load`` and held over the sample (a rig's load cell), or empty for none.
    ``noise`` is the electrical current noise per fine step for this chunk
    (length len(cmd) * steps_per_sample), or empty for none.
    """
    nsub = int(p[P_NSUB])
    dt = p[P_DT]
    reference = p[P_MODEL] == 0.0
    has_noise = noise.shape[0] > 0
    has_load = load.shape[0] > 0
    for k in range(cmd.shape[0]):
        out[k, O_CMD] = cmd[k]
        out[k, O_POS] = s[S_XM]
        out[k, O_VEL] = s[S_VM]
        out[k, O_P12] = s[S_P12]
        out[k, O_CUR] = s[S_IV]
        out[k, O_XS] = s[S_XS]
        out[k, O_XJ] = s[S_XJ]
        # the command the actuator receives; cmd is the recorded one (output column O_CMD)
        x_cmd = (cmd[k] - p[P_CMDOFF]) / p[P_CMDGAIN]
        f_ext = load[k] if has_load else 0.0
        for j in range(nsub):
            # GAS acts on the jack velocity (rate of the actuator's own transducer): an inner loop
            # that damps the jack across the backlash gap, where the surface reading is blind
            i_v = servo_amplifier(p, s, x_cmd, s[S_XM], s[S_VJ], dt)
            if has_noise:
                i_v += noise[k * nsub + j]
            s[S_IV] = i_v
            if reference:
                xs = first_stage_reference(p, s, i_v, dt)
            else:
                xs = first_stage_monitor(p, s, i_v, dt)
            f_link = link_force(p, s)
            jack_step(p, s, xs, -f_link, dt)
            vibration_level_step(p, s, s[S_VJ], dt)
            surface_step(p, s, f_link - f_ext, dt)
            transducer_step(p, s, dbuf)


@njit(cache=True, nogil=True, error_model="numpy")
def run_one(p, cmd, load, out):
    """Simulate one parameter row ``p`` from rest on the calling thread (the GIL released)."""
    s = np.zeros(N_S)
    dbuf = np.zeros((int(p[P_DELAY]) + 2, 2))
    init_state(p, s, dbuf)
    run(p, s, cmd, load, np.zeros(0), dbuf, out)


@njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def run_batch(P, cmd, load, out):
    """Simulate every parameter row of ``P`` from rest, in parallel; ``out[b]`` per row."""
    empty = np.zeros(0)
    for b in prange(P.shape[0]):
        s = np.zeros(N_S)
        dbuf = np.zeros((int(P[b, P_DELAY]) + 2, 2))
        init_state(P[b], s, dbuf)
        run(P[b], s, cmd, load, empty, dbuf, out[b])


def new_output(n: int) -> np.ndarray:
    return np.zeros((n, N_OUT))
