"""Where an unexplained residual structure lives, and which base knobs it is likely to bias.

When no candidate explains a structured residual, the fit that made it may be biased. Per
structured channel the report names the segments where the residual is largest. For the bias,
each segment s of the record is fitted alone, linearised at the fit: the base-knob shift that
would absorb that segment's residual is

    dk_s = -(J_s^T J_s)^+ J_s^T r_s

(J_s, r_s: the rows of the fit's Jacobian and residual on segment s). At the fit the segments'
pulls balance; a knob whose segment shifts disagree by much more than its standard error is
being pulled by the structure one way on one segment and the other way on another -- it is the
knob the missing mechanism is likely to bias.
"""
from __future__ import annotations

import numpy as np

from ..identification.residual import Residual
from ..identification.result import FitResult
from ..signals.residuals import ResidualAnalysis


def segment_shifts(res: Residual, fit: FitResult, segments: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Linearised base-knob shift ``dk_s`` that each segment's residual alone asks for."""
    nc = len(res.channels)
    out = {}
    for name, m in (segments or {}).items():
        idx = np.flatnonzero(np.asarray(m, bool)[res.mask])
        if len(idx) < 10:
            continue
        rows = (idx[:, None] * nc + np.arange(nc)).ravel()
        dk, *_ = np.linalg.lstsq(fit.jacobian[rows], -fit.residual[rows], rcond=None)
        out[name] = dk
    return out


def locate(res: Residual, fit: FitResult, analysis: ResidualAnalysis, segments: dict[str, np.ndarray],
           n_base: int, spread_factor: float = 3.0) -> dict:
    """Channels and segments of the structure, and the knobs it is likely to bias (dict for the report)."""
    where = []
    for c, ch in analysis.channels.items():
        if not ch.structured:
            continue
        worst = sorted(ch.segments.items(), key=lambda kv: -kv[1]["rms"])[:2]
        excess = float(np.sqrt(max(ch.rms ** 2 - ch.noise_sd ** 2 - ch.floor ** 2, 0.0)))
        where.append(f"{c} (excess {excess:.3g} {ch.unit} over noise and floor; largest on "
                     + ", ".join(f"{s} {v['rms']:.3g}" for s, v in worst) + ")")
    shifts = segment_shifts(res, fit, segments)
    sd = fit.std()
    names = [fit.names[i] for i in fit.free]
    spread, bias = {}, []
    for j, n in enumerate(names[:n_base]):
        v = np.array([dk[j] for dk in shifts.values()])
        if not len(v):
            continue
        spread[n] = {s: float(dk[j]) for s, dk in shifts.items()}
        rng = float(v.max() - v.min())
        if rng > spread_factor * max(sd.get(n, 0.0), 1e-300):
            bias.append(f"{n} likely biased: the segments alone would move it by {v.min():+.3g} to {v.max():+.3g} "
                        f"(standard error {sd.get(n, float('nan')):.2g})")
    return {"where": where or ["no single channel above its noise and floor"],
            "bias": bias or ["no base knob pulled apart by the segments beyond its standard error"],
            "segment_shifts": spread}
