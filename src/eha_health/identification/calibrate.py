"""Calibrate the monitor model's first stage on the healthy reference response.

As one would calibrate a monitor on a healthy unit: the monitor's own nominal
parameters (first-stage natural frequency and damping, spool time constant and
static current-to-spool gain) are fitted by least squares so that its response
to the FDI sequence matches the healthy reference, channel by channel
(position, pressure, current, spool; each normalised by a physical scale). The
fitted set is written to ``data/monitor.yaml`` and used by identification.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml
from scipy.optimize import least_squares

from .fitness import CHANNEL_SCALES
from ..physics.model import Plant, response_from_rows, simulate
from ..physics.faults import Faults
from ..physics.params import ModelParams, load
from ..signals.response import Response
from ..physics.sequence import FDISequence

CALIBRATION_CHANNELS = ("position", "pressure", "current", "spool")
#: Pressure weighs less: while the jack is stuck P12 rests anywhere in the friction band,
#: depending on history, so it is a noisy calibration target.
CALIBRATION_WEIGHTS = {"position": 1.0, "pressure": 0.3, "current": 1.0, "spool": 1.0}
#: Starting points (natural frequency [rad/s], damping ratio, spool time constant [s]).
START_POINTS = ((3000.0, 0.7, 3e-3), (1200.0, 0.5, 2e-3), (500.0, 1.0, 5e-4), (6000.0, 1.0, 4e-3))
FIRST_STAGE_FIELDS = ("natural_frequency", "damping_ratio", "spool_time_constant", "static_gain",
                      "spool_rate_limit")


@dataclass
class CalibrationResult:
    params: ModelParams               # calibrated monitor parameter set
    values: dict[str, float]          # fitted first-stage values
    rms_before: dict[str, float]      # per-channel RMS monitor - reference, SI units
    rms_after: dict[str, float]
    evaluations: int
    wall_time_s: float


def channel_rms(a: Response, b: Response, channels=CALIBRATION_CHANNELS) -> dict[str, float]:
    """Per-channel RMS difference of two responses on the same time base [SI units]."""
    return {c: float(np.sqrt(np.mean((getattr(a, c) - getattr(b, c)) ** 2))) for c in channels}


def _with_first_stage(mon: ModelParams, x: np.ndarray) -> ModelParams:
    vals = dict(zip(FIRST_STAGE_FIELDS, np.exp(x)))
    return replace(mon, first_stage=replace(mon.first_stage, **vals))


def calibrate(reference: Response | None = None, monitor: ModelParams | None = None,
              sequence: FDISequence | None = None, verbose: bool = False) -> CalibrationResult:
    """Fit the monitor first stage to ``reference`` (default: the healthy reference model)."""
    t0 = time.perf_counter()
    seq = sequence or FDISequence()
    ref = reference if reference is not None else simulate("reference", Faults(), sequence=seq)
    mon = monitor if monitor is not None else load("monitor")
    cmd = ref.command
    n_eval = 0

    def residuals(x):
        nonlocal n_eval
        n_eval += 1
        r = response_from_rows(ref.t, Plant(_with_first_stage(mon, x), Faults()).step(cmd))
        res = [CALIBRATION_WEIGHTS[c] * (getattr(r, c) - getattr(ref, c)) / CHANNEL_SCALES[c]
               for c in CALIBRATION_CHANNELS]
        return np.concatenate(res) / np.sqrt(len(cmd))

    x_given = np.log([getattr(mon.first_stage, f) for f in FIRST_STAGE_FIELDS])
    before = _with_first_stage(mon, x_given)
    # the cost is multimodal in (w, z, tau): a few physically spread starts, keep the best
    best = None
    for w, z, tau in START_POINTS:
        x0 = x_given.copy()
        x0[:3] = np.log([w, z, tau])
        sol = least_squares(residuals, x0, diff_step=1e-3, max_nfev=200)
        if verbose:
            print(f"  start w={w:g} rad/s z={z:g} tau={tau:g} s -> cost {sol.cost:.4g}")
        if best is None or sol.cost < best.cost:
            best = sol
    fitted = _with_first_stage(mon, best.x)
    rb = channel_rms(simulate(params=before, sequence=seq), ref)
    ra = channel_rms(simulate(params=fitted, sequence=seq), ref)
    vals = {f: float(getattr(fitted.first_stage, f)) for f in FIRST_STAGE_FIELDS}
    return CalibrationResult(fitted, vals, rb, ra, n_eval, time.perf_counter() - t0)


def write_monitor_yaml(result: CalibrationResult, path: str | Path) -> None:
    """Write the calibrated first stage as a monitor override file."""
    data = {"integration": {"dt": result.params.integration.dt},
            "first_stage": {k: float(f"{v:.6g}") for k, v in result.values.items()}}
    header = ("# Monitor-model overrides on params.yaml, written by `eha-health calibrate`:\n"
              "# first stage fitted to the healthy reference response (see docs/model.md).\n")
    Path(path).write_text(header + yaml.safe_dump(data, sort_keys=False))
