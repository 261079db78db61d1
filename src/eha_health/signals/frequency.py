"""Empirical frequency response of a record: position over command, measured and modelled.

A rig driven by a broadband command (a chirp, a sweep, random motion) is read by
a control engineer as a frequency response: gain and phase of position over
command against frequency. The H1 estimate

    H1(f) = P_cy(f) / P_cc(f),   coherence  g2(f) = |P_cy|^2 / (P_cc P_yy)

(Welch cross- and auto-spectra, Hann windows, 50 % overlap) is taken for the
measured position and for a model's position driven by the same command, and
compared over frequency bands where the command carries power and the measured
coherence is high. A model whose gain is low or whose phase lags at the top of
the band shows it here even when the time-domain residual is dominated by an
offset.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.signal import csd, welch


@dataclass(frozen=True)
class FrequencyResponse:
    """H1 estimate y/u on the kept frequencies."""
    f: np.ndarray            # Hz
    H: np.ndarray            # complex gain y/u [-]
    coherence: np.ndarray    # [-]


def _segment(n: int) -> int:
    """Welch segment: a power of two, at most 4096 samples, at least 8 segments in the record."""
    return int(2 ** min(12, int(np.log2(max(n // 8, 2)))))


def _check(u, y) -> tuple[np.ndarray, np.ndarray]:
    u, y = np.asarray(u, float), np.asarray(y, float)
    if u.shape != y.shape or u.ndim != 1:
        raise ValueError(f"frequency response: command and output must be 1-D of one length, got {u.shape}, {y.shape}")
    if len(u) < 256:
        raise ValueError(f"frequency response: record too short ({len(u)} samples, need >= 256)")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise ValueError("frequency response: command or output holds NaN or inf")
    return u, y


def estimate(u, y, fs: float, min_coherence: float = 0.9, min_power: float = 1e-3,
             nperseg: int | None = None) -> FrequencyResponse:
    """H1 of ``y`` over ``u`` sampled at ``fs`` [Hz], where u has power and the coherence is high.

    ``min_power``: keep bins whose command power is at least this share of its peak;
    ``min_coherence``: and whose coherence is at least this.
    """
    u, y = _check(u, y)
    return _estimate(u, y, fs, nperseg or _segment(len(u)), min_coherence, min_power)[0]


def _estimate(u, y, fs: float, n: int, min_coherence: float, min_power: float):
    """The kept response, the kept-bin mask and the command's power on every Welch bin."""
    f, Puy = csd(u, y, fs=fs, nperseg=n)
    _, Puu = welch(u, fs=fs, nperseg=n)
    _, Pyy = welch(y, fs=fs, nperseg=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        H = Puy / Puu
        coh = np.abs(Puy) ** 2 / (Puu * Pyy)
    keep = (f > 0) & (Puu >= min_power * Puu.max()) & np.isfinite(coh) & (coh >= min_coherence)
    return FrequencyResponse(f[keep], H[keep], coh[keep]), keep, Puu


def _model_h(u, ym, fs: float, n: int, keep, Puu) -> np.ndarray:
    """H1 of a model's output ``ym`` over ``u`` on the measured response's kept bins."""
    return csd(u, _check(u, ym)[1], fs=fs, nperseg=n)[1][keep] / Puu[keep]


def compare(command, measured, models: dict[str, np.ndarray], fs: float, n_bands: int = 8,
            min_coherence: float = 0.9) -> list[dict]:
    """Gain and phase of the measured and of each model's output over the command, per band.

    Bands split the range of frequencies kept for the measured response (command power
    and coherence) into ``n_bands`` equal widths. Per band: the mean gain and mean phase (unwrapped along
    frequency) of each source, and of each model the mean bin-by-bin gain ratio and phase
    difference to the measured response (averaging complex values instead would shrink
    the gain of a band whose phase turns, e.g. under a delay). Returns one dict per non-empty band:
    ``f_lo, f_hi`` [Hz], ``gain`` and ``phase_deg`` per source (``measured`` and the
    keys of ``models``), and ``gain_ratio`` / ``phase_error_deg`` of each model against
    the measured response.
    """
    u, y = _check(command, measured)
    n = _segment(len(u))
    meas, keep, Puu = _estimate(u, y, fs, n, min_coherence, 1e-3)
    if len(meas.f) == 0:
        return []
    # the models on the same bins (their own coherence is not a criterion: no noise)
    Hm = {name: _model_h(u, ym, fs, n, keep, Puu) for name, ym in models.items()}
    # phases unwrapped along the whole kept range: a band high up can be more than half a turn off
    ph = {"measured": np.unwrap(np.angle(meas.H))}
    err = {}
    for name, H in Hm.items():
        ph[name] = np.unwrap(np.angle(H))
        err[name] = np.unwrap(np.angle(H / meas.H))
    gains = {"measured": np.abs(meas.H), **{k: np.abs(H) for k, H in Hm.items()}}
    edges = np.linspace(meas.f[0], meas.f[-1], n_bands + 1)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (meas.f >= lo) & ((meas.f < hi) | (hi == edges[-1]))
        if not sel.any():
            continue
        row = {"f_lo": float(lo), "f_hi": float(hi),
               "gain": {k: float(np.mean(g[sel])) for k, g in gains.items()},
               "phase_deg": {k: float(np.degrees(np.mean(p[sel]))) for k, p in ph.items()},
               "gain_ratio": {k: float(np.mean(gains[k][sel] / gains["measured"][sel])) for k in Hm},
               "phase_error_deg": {k: float(np.degrees(np.mean(e[sel]))) for k, e in err.items()}}
        out.append(row)
    return out


@dataclass(frozen=True)
class ResponseError:
    """A model's H1 against the measured one on the measured response's kept bins.

    ``rel`` = (H_model - H_meas) / H_meas per bin; ``sigma`` = the relative standard error of the
    measured complex H1, sqrt((1 - g2) / (n_d g2)) with n_d the Welch segment count (Bendat &
    Piersol, Random Data, 4th ed., sec. 9.2: each of gain and phase has half this variance).
    """
    f: np.ndarray          # Hz
    rel: np.ndarray        # complex relative error [-]
    sigma: np.ndarray      # relative standard error of the measured H1 [-]

    @property
    def power(self) -> float:
        """Mean squared relative error over the bins [-]."""
        return float(np.mean(np.abs(self.rel) ** 2)) if len(self.f) else 0.0

    @property
    def noise_power(self) -> float:
        """What the estimate's own scatter gives to :attr:`power` when the model is right [-]."""
        return float(np.mean(self.sigma ** 2)) if len(self.f) else 0.0

    def significant(self, factor: float = 4.0) -> bool:
        """The error is structure: its power exceeds ``factor`` times the estimate's scatter."""
        return bool(len(self.f)) and self.power > factor * self.noise_power


def response_errors(command, measured, fs: float, min_coherence: float = 0.9) -> Callable[[np.ndarray], ResponseError]:
    """The :class:`ResponseError` of a model output against ``measured``'s response over ``command``
    (sampled at ``fs`` [Hz]) on the bins where the command has power and the measured coherence is
    high: the measured side is estimated once, each model output costs one cross-spectrum."""
    u, y = _check(command, measured)
    n = _segment(len(u))
    meas, keep, Puu = _estimate(u, y, fs, n, min_coherence, 1e-3)
    segments = max((len(u) - n // 2) // (n // 2), 1)     # Welch's count, Hann windows at 50 % overlap
    g2 = meas.coherence
    sigma = np.sqrt((1.0 - g2) / (segments * g2))
    return lambda model: ResponseError(meas.f, _model_h(u, model, fs, n, keep, Puu) / meas.H - 1.0, sigma)


def response_error(command, measured, model, fs: float, min_coherence: float = 0.9) -> ResponseError:
    """:class:`ResponseError` of one ``model`` output (see :func:`response_errors`)."""
    return response_errors(command, measured, fs, min_coherence)(model)
