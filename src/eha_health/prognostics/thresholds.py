"""Failure thresholds from the physics (CLI: ``eha-health thresholds``).

For each fault f the threshold is the smallest K_f (the other faults at 0) at which the
reference EHA, simulated noise-free on the FDI sequence, breaks any requirement of
``data/prognostics.yaml``: ``metric(simulate(K_f)) > limit``. K is scanned on
``scan_points`` values in (0, search_max], then the first crossing is bisected to
``tolerance``. A fault that breaks no requirement below ``search_max`` keeps the default
threshold (K = 1, the limit by definition of the coefficients); so does every fault
when no requirement is set. A requirement lowers the threshold, never raises it above the
default: a limit that breaks at K 1.49 would otherwise give 1.49 where a slightly looser one,
never broken, gives 1 (an independent probe, 2026-11-29: loosening a limit must not lower the
threshold).

Metrics (all on the noise-free reference response, SI):

* ``step_rise_time`` [s]: time from the step command to the first crossing of 90 % of
  the step level (linear interpolation between samples).
* ``sine_peak_error`` [m]: max |position - command| over the sine segment.
* ``ramp_pressure`` [Pa]: mean |P12| over the ramp after its first 0.2 s (the friction
  the jack must overcome, divided by its area).
"""
from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

import numpy as np

from eha_health import FDISequence, Faults, simulate

from ..physics.faults import FAULT_KEYS
from .config import PrognosticsError, Settings, load_settings

#: Short fault names (gm, fsj, bkl): :data:`eha_health.physics.faults.FAULT_KEYS`.
FAULTS = FAULT_KEYS


def _step_rise_time(r, seq: FDISequence) -> float:
    m = seq.mask("step", r.t)
    t, x = r.t[m], r.position[m]
    target = 0.9 * seq.step_level
    above = np.nonzero(x >= target)[0]
    if not len(above):
        return float(seq.return_time - seq.step_time) * 10.0   # never reached: far beyond any limit
    i = above[0]
    if i == 0:
        return float(t[0] - seq.step_time)
    frac = (target - x[i - 1]) / (x[i] - x[i - 1])
    return float(t[i - 1] + frac * (t[i] - t[i - 1]) - seq.step_time)


def _sine_peak_error(r, seq: FDISequence) -> float:
    m = seq.mask("sine", r.t)
    return float(np.max(np.abs(r.position[m] - r.command[m])))


def _ramp_pressure(r, seq: FDISequence) -> float:
    m = seq.mask("ramp", r.t) & (r.t >= 0.2)
    return float(np.mean(np.abs(r.pressure[m])))


#: metric name -> (unit, function(response, sequence) -> value)
METRICS = {
    "step_rise_time": ("s", _step_rise_time),
    "sine_peak_error": ("m", _sine_peak_error),
    "ramp_pressure": ("Pa", _ramp_pressure),
}


@dataclass(frozen=True)
class Threshold:
    """Failure threshold of one fault and where it comes from."""
    fault: str              # gm, fsj or bkl
    k: float                # threshold on the fault coefficient
    requirement: str | None  # the requirement that breaks first (None: default)
    metric: str | None
    limit: float | None     # the requirement's limit [SI unit of the metric]
    unit: str | None
    healthy_value: float | None  # the metric at K = 0 [SI]

    def as_dict(self) -> dict:
        return asdict(self)


def _metrics_at(fault: str, k: float, requirements, seq: FDISequence) -> dict[str, float]:
    r = simulate(kind="reference", faults=Faults(**{f"k_{fault}": float(k)}), sequence=seq)
    return {q.name: METRICS[q.metric][1](r, seq) for q in requirements}


def _broken(values: dict[str, float], requirements) -> list:
    return [q for q in requirements if values[q.name] > q.limit]


@functools.lru_cache(maxsize=8)
def _thresholds(requirements: tuple, ts) -> tuple:
    seq = FDISequence()
    out = []
    for fault in FAULTS:
        if not requirements:
            out.append(Threshold(fault, ts.default, None, None, None, None, None))
            continue
        healthy = _metrics_at(fault, 0.0, requirements, seq)
        broken0 = _broken(healthy, requirements)
        if broken0:
            names = ", ".join(q.name for q in broken0)
            raise PrognosticsError(f"the healthy reference EHA already breaks requirement(s) {names}: "
                                   f"no threshold (loosen their limits in the settings)")
        lo, hi, hit = 0.0, None, None
        for k in np.linspace(0.0, ts.search_max, ts.scan_points + 1)[1:]:
            b = _broken(_metrics_at(fault, k, requirements, seq), requirements)
            if b:
                hi, hit = float(k), b
                break
            lo = float(k)
        if hi is None or lo >= ts.default:      # nothing breaks below the default limit
            out.append(Threshold(fault, ts.default, None, None, None, None, None))
            continue
        while hi - lo > ts.tolerance:
            mid = 0.5 * (lo + hi)
            b = _broken(_metrics_at(fault, mid, requirements, seq), requirements)
            if b:
                hi, hit = mid, b
            else:
                lo = mid
        q = hit[0]
        if round(hi, 6) >= ts.default:
            out.append(Threshold(fault, ts.default, None, None, None, None, None))
            continue
        out.append(Threshold(fault, round(hi, 6), q.name, q.metric, q.limit, METRICS[q.metric][0],
                             healthy[q.name]))
    return tuple(out)


def failure_thresholds(settings: Settings | None = None) -> dict[str, Threshold]:
    """Threshold per fault (``gm``, ``fsj``, ``bkl``), computed with the reference model.

    Cached per requirement set in the process (about 1 s the first time).
    """
    s = settings or load_settings()
    return {t.fault: t for t in _thresholds(tuple(s.requirements), s.thresholds)}


def threshold_values(settings: Settings | None = None) -> dict[str, float]:
    """``{fault: K threshold}``."""
    return {f: t.k for f, t in failure_thresholds(settings).items()}
