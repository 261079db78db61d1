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

A segment says nothing of a knob it does not determine: where the knob's standard error from
that segment alone, ``s_j = sigma_s / |e_j|`` (``e_j`` the knob's column of J_s less its
projection on the other columns, ``sigma_s^2 = |r_s|^2 / (m_s - k)``), exceeds the knob's range, the
linearised shift is the noise divided by a near-zero sensitivity (measured: K_BKL +2.2e8 on a
segment without a reversal) and the segment is listed as not determining it instead.
"""
from __future__ import annotations

import numpy as np

from ..identification.residual import Residual
from ..identification.result import FitResult
from ..signals.residuals import ResidualAnalysis


def segment_shifts(res: Residual, fit: FitResult, segments: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per segment: the linearised shift ``dk_s`` of the free knobs that its residual alone asks
    for, and the standard errors of the knobs fitted on that segment alone [knob units]."""
    nc = len(res.channels)
    out = {}
    for name, m in (segments or {}).items():
        idx = np.flatnonzero(np.asarray(m, bool)[res.mask])
        if len(idx) < 10:
            continue
        rows = (idx[:, None] * nc + np.arange(nc)).ravel()
        J, r = fit.jacobian[rows], fit.residual[rows]
        dk, *_ = np.linalg.lstsq(J, -r, rcond=None)
        sigma = float(np.sqrt(r @ r / max(len(r) - J.shape[1], 1)))
        se = np.empty(J.shape[1])
        for j in range(J.shape[1]):
            other = np.delete(J, j, axis=1)
            e = J[:, j] - other @ np.linalg.lstsq(other, J[:, j], rcond=None)[0] if other.shape[1] else J[:, j]
            ne = float(np.linalg.norm(e))
            se[j] = sigma / ne if ne > 0 else np.inf
        out[name] = (dk, se)
    return out


def locate(res: Residual, fit: FitResult, analysis: ResidualAnalysis, segments: dict[str, np.ndarray],
           n_base: int, spread_factor: float = 3.0, spans: dict[str, float] | None = None) -> dict:
    """Channels and segments of the structure, and the knobs it is likely to bias (dict for the report).

    ``spans``: each base knob's range ``hi - lo`` [its unit]; a segment whose own standard error of
    the knob exceeds it does not determine the knob (``undetermined``)."""
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
    spread, bias, undetermined = {}, [], {}
    for j, n in enumerate(names[:n_base]):
        span = (spans or {}).get(n, np.inf)
        own = {s: float(dk[j]) for s, (dk, se) in shifts.items() if se[j] <= span and np.isfinite(dk[j])}
        if len(own) < len(shifts):
            undetermined[n] = [s for s in shifts if s not in own]
        v = np.array(list(own.values()))
        if not len(v):
            continue
        spread[n] = own
        rng = float(v.max() - v.min())
        if rng > spread_factor * max(sd.get(n, 0.0), 1e-300):
            bias.append(f"{n} likely biased: the segments alone would move it by {v.min():+.3g} to {v.max():+.3g} "
                        f"(standard error {sd.get(n, float('nan')):.2g})")
    return {"where": where or ["no single channel above its noise and floor"],
            "bias": bias or ["no base knob pulled apart by the segments beyond its standard error"],
            "segment_shifts": spread, "undetermined": undetermined}
