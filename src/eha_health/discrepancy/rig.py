"""A measured rig that is not the paper's EHA: calibrate the monitor to it, then run the loop.

A test rig (e.g. an MTS servo-hydraulic press driving a specimen) has the
monitor's structure -- proportional position loop, servovalve, jack -- but its
own sizes, no aerodynamic surface, and often only command and position (plus a
load cell). :func:`rig_params` reshapes the monitor accordingly: no hinge
stiffness, bearing friction, backlash, seal friction or velocity feedback, the
measured force applied as the external load (``Record.load``). The nominal
parameters that size the loop are then fitted (:data:`RIG_KNOBS`) on the first
``fit_fraction`` of the record, and the discrepancy loop adds what is missing;
both are judged on the held-out rest.
"""
from __future__ import annotations

import numpy as np

from ..identification.knobs import Knob
from ..identification.record import Record
from ..physics.params import ModelParams, load
from ..signals import frequency
from .candidates import CANDIDATES, COMMAND_CHAIN, STRUCTURAL
from .loop import quantile_segments, run_loop
from .report import DiscrepancyReport
from .settings import DEFAULT_MAX_EFFECTS, Settings

#: Nominal parameters calibrated to a rig (start values: the shipped monitor).
RIG_KNOBS = (
    Knob("loop_gain", "A/m", 0.05, 1000.0, 12.0,
         apply=lambda p, v: p.updated("controller", kp=v), doc="proportional gain of the position loop"),
    Knob("valve_time_constant", "s", 2e-4, 0.05, 3.7e-3,
         apply=lambda p, v: p.updated("first_stage", spool_time_constant=v), doc="spool loop time constant"),
    Knob("pressure_gain", "Pa/m", 1e10, 1e14, 1.36e12,
         apply=lambda p, v: p.updated("hydraulics", pressure_gain=v), doc="blocked-load pressure gain G_P"),
    Knob("viscous", "N s/m", 0.0, 1e5, 3000.0,
         apply=lambda p, v: p.updated("jack", viscous=v), doc="jack viscous friction"),
)

#: Candidates that make sense without the aerodynamic surface and its link, or for a loop whose
#: gain and spool time constant are calibrated (RIG_KNOBS) and which has no velocity feedback, and
#: the loop structure a rig's frequency response may ask for (candidates.STRUCTURAL). The recorded
#: command's offset and scale are left out too: without a hinge spring or backlash the offset is
#: the position's recording offset (no simulation needed), and the scale has not been tried on a
#: rig record (each would add its screens to the 60 s record's budget).
RIG_CANDIDATES = tuple(c for c in CANDIDATES if c.name not in ("load_stiffness", "mount_compliance",
                                                             "controller_gain", "velocity_feedback",
                                                             "valve_response", *COMMAND_CHAIN)) + STRUCTURAL


def rig_params(base: ModelParams | None = None, dt: float = 1e-4) -> ModelParams:
    """The monitor reshaped for a rig: the load is measured, not modelled. ``dt`` [s]."""
    p = base if base is not None else load("monitor")
    p = p.updated("surface", hinge_stiffness=0.0, hinge_friction=0.0, external_force=0.0)
    p = p.updated("linkage", backlash=0.0)
    p = p.updated("jack", static_friction=0.0, dynamic_friction=0.0)
    p = p.updated("controller", gas=0.0)
    return p.updated("integration", dt=dt)


def rig_record(response, zero_samples: int = 2000) -> Record:
    """Record of an imported rig run: its measured channels, the load tared on the first samples."""
    rec = Record.from_response(response)
    if response.load is not None:
        n = min(zero_samples, len(rec) // 10)
        rec.load = np.asarray(response.load, float) - float(np.mean(response.load[:n]))
    return rec


def analyse_rig(response, max_effects: int = DEFAULT_MAX_EFFECTS, fit_fraction: float = 0.7, progress=None,
                grid: int = 12) -> DiscrepancyReport:
    """Calibrate :data:`RIG_KNOBS` on the first ``fit_fraction``, run the loop, predict the rest.

    The report's ``before`` is the calibrated nominal model, ``after`` the model with
    the selected effects; both fitted on the fit part only (``final_fit='fit'``), so
    ``rms_held_out`` is a true prediction error.
    """
    rec = rig_record(response)
    # a rig record is long (one run ~0.1 s): a coarser grid and one local fit per candidate
    settings = Settings(fit_fraction=fit_fraction, grid=grid, scan=6, starts=1, max_nfev=20, rest_noise=True,
                        frequency_evidence=True)
    x0 = np.array([k.typical for k in RIG_KNOBS])
    rep = run_loop(rec, rig_params(), RIG_KNOBS, x0, quantile_segments(rec), RIG_CANDIDATES, max_effects,
                   settings, None, "fit", progress)
    if "position" in rep.measured:
        # both models are fitted on the fit part only: over the whole record this is their prediction
        rep.frequency_response = frequency.compare(
            rec.command, rep.measured["position"],
            {"before": rep.fitted_before["position"], "after": rep.fitted_after["position"]}, rec.sample_rate)
    return rep

