"""Calibrate the monitor model's first stage on the healthy reference response.

As one would calibrate a monitor on a healthy unit: the monitor's own nominal
parameters (:data:`FIRST_STAGE_KNOBS`: first-stage natural frequency and damping, spool
time constant, static current-to-spool gain and spool rate limit) are fitted by bounded
least squares on the engine (:func:`~.local.least_squares`) so that its response to the
FDI sequence matches the healthy reference, channel by channel (position, pressure,
current, spool; each normalised by a physical scale), from a few physically spread
starts. The fitted set is written to ``data/monitor.yaml`` and used by identification.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..physics.faults import Faults
from ..physics.model import simulate
from ..physics.params import ModelParams, load
from ..physics.sequence import FDISequence
from ..signals.response import Response
from .knobs import Knob
from .local import least_squares
from .problem import KnobModel, Problem
from .record import Record
from .residual import CHANNEL_SCALES, Residual

CALIBRATION_CHANNELS = ("position", "pressure", "current", "spool")
#: Pressure weighs less: while the jack is stuck P12 rests anywhere in the friction band,
#: depending on history, so it is a noisy calibration target.
CALIBRATION_WEIGHTS = {"position": 1.0, "pressure": 0.3, "current": 1.0, "spool": 1.0}
#: Starting points of the first three knobs (natural frequency [rad/s], damping ratio, spool
#: time constant [s]); the cost is multimodal in them.
START_POINTS = ((3000.0, 0.7, 3e-3), (1200.0, 0.5, 2e-3), (500.0, 1.0, 5e-4), (6000.0, 1.0, 4e-3))
#: Iterations of each start's least-squares fit.
MAX_NFEV = 200


def _first_stage_knob(field: str, unit: str, lo: float, hi: float, nominal: float, doc: str) -> Knob:
    # fitted as the logarithm of the value: the response depends on these parameters by ratios
    # (a 10 % change of a time constant matters alike at any size), and a log keeps them positive.
    # The response is smooth in them (no stick-slip event moves with them): a fine step, 0.1 %.
    return Knob(f"ln_{field}", f"ln({unit})", math.log(lo), math.log(hi), 1.0, math.log(nominal),
                apply=lambda p, v: p.updated("first_stage", **{field: math.exp(v)}), doc=doc, step_share=1e-3)


FIRST_STAGE_KNOBS = (
    _first_stage_knob("natural_frequency", "rad/s", 100.0, 1e5, 3000.0, "first-stage natural frequency"),
    _first_stage_knob("damping_ratio", "-", 0.02, 10.0, 0.7, "first-stage damping ratio"),
    _first_stage_knob("spool_time_constant", "s", 1e-5, 0.1, 3e-3, "spool position-loop time constant"),
    _first_stage_knob("static_gain", "m/A", 1e-3, 1.0, 0.0625, "static spool position per unit current"),
    _first_stage_knob("spool_rate_limit", "m/s", 1e-3, 10.0, 0.07, "spool speed limit"),
)
FIRST_STAGE_FIELDS = tuple(k.name.removeprefix("ln_") for k in FIRST_STAGE_KNOBS)


@dataclass
class CalibrationResult:
    params: ModelParams               # calibrated monitor parameter set
    values: dict[str, float]          # fitted first-stage values
    rms_before: dict[str, float]      # per-channel RMS monitor - reference, SI units
    rms_after: dict[str, float]
    evaluations: int
    wall_time_s: float


def calibrate(reference: Response | None = None, monitor: ModelParams | None = None,
              sequence: FDISequence | None = None, verbose: bool = False) -> CalibrationResult:
    """Fit the monitor first stage to ``reference`` (default: the healthy reference model)."""
    t0 = time.perf_counter()
    seq = sequence or FDISequence()
    ref = reference if reference is not None else simulate("reference", Faults(), sequence=seq)
    mon = monitor if monitor is not None else load("monitor")
    record = Record.from_response(ref, CALIBRATION_CHANNELS)
    model = KnobModel(mon, FIRST_STAGE_KNOBS, record)
    residual = Residual(record, weights={c: CALIBRATION_WEIGHTS[c] / CHANNEL_SCALES[c] for c in CALIBRATION_CHANNELS})
    problem = Problem(model, residual)
    x_given = problem.clip(np.log([getattr(mon.first_stage, f) for f in FIRST_STAGE_FIELDS]))
    best = None
    for w, z, tau in START_POINTS:
        fit = least_squares(problem, np.concatenate([np.log([w, z, tau]), x_given[3:]]), ftol=1e-8, gtol=1e-8,
                            max_nfev=MAX_NFEV)
        if verbose:
            print(f"  start w={w:g} rad/s z={z:g} tau={tau:g} s -> cost {fit.cost:.4g}")
        if best is None or fit.cost < best.cost:
            best = fit
    before = residual.rms(model.run(x_given)[0])
    fitted = model.params_at(best.x)[0]
    vals = {f: float(getattr(fitted.first_stage, f)) for f in FIRST_STAGE_FIELDS}
    return CalibrationResult(fitted, vals, before, residual.rms(best.output), model.runs, time.perf_counter() - t0)


def write_monitor_yaml(result: CalibrationResult, path: str | Path) -> None:
    """Write the calibrated first stage as a monitor override file."""
    data = {"integration": {"dt": result.params.integration.dt},
            "first_stage": {k: float(f"{v:.6g}") for k, v in result.values.items()}}
    header = ("# Monitor-model overrides on params.yaml, written by `eha-health calibrate`:\n"
              "# first stage fitted to the healthy reference response (see docs/model.md).\n")
    Path(path).write_text(header + yaml.safe_dump(data, sort_keys=False))
