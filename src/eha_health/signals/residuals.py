"""Residual analysis after a fit: is what is left noise, or structure the model lacks?

Per measured channel (and per test segment): RMS, bias (mean), lag-1
autocorrelation, the Ljung-Box statistic over ``lags`` lags (whiteness), the
dominant frequency of the residual spectrum and the share of power there, and
the channel's noise level estimated from the measured data alone: white noise of
standard deviation sigma gives second differences of variance 6 sigma^2, while a
smooth signal sampled at 1 kHz barely contributes, so

    sigma_hat = 1.4826 MAD(diff2(y)) / sqrt(6)                       [channel unit]

A rig's noise is often not white: electrical interference common to the logger's
channels is coloured, and second differences see only its high-frequency part.
Where the record holds rest periods (the command still for a second or more),
:func:`rest_noise_level` measures the channel's whole-band fluctuation there, and
the larger of the two estimates is the noise.

A channel is *structured* when its residual is both larger than noise and the
model's known floor allow (``rms > factor * sqrt(sigma_hat^2 + floor^2)``) and
not white (Ljung-Box p < ``alpha``); otherwise it is *explained by noise*.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats

from .channels import UNITS


def noise_level(y: np.ndarray, exclude: np.ndarray | None = None) -> float:
    """White-noise standard deviation of a sampled channel, from its second differences (those
    touching a sample of the mask ``exclude`` left out)."""
    d2 = np.diff(np.asarray(y, float), 2)
    if exclude is not None:
        ex = np.asarray(exclude, bool)
        d2 = d2[~(ex[:-2] | ex[1:-1] | ex[2:])]
    if len(d2) < 10:
        return 0.0
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def rest_noise_level(y: np.ndarray, command: np.ndarray, rate: float, min_rest_s: float = 1.0,
                     settle_s: float = 0.5, still: float = 0.015) -> float:
    """Standard deviation of ``y`` [its unit] where the command rests, or 0 without such periods.

    Rest: the command's standard deviation over 0.2 s windows is below ``still`` times its
    standard deviation over the record; each rest run loses its first ``settle_s`` [s] (the
    response settles) and counts if at least ``min_rest_s`` [s] remain. Per run, ``y`` about its
    linear trend; pooled over the runs.
    """
    y, u = np.asarray(y, float), np.asarray(command, float)
    w = max(int(round(0.2 * rate)), 2)
    if len(u) < 2 * w or np.std(u) <= 0:
        return 0.0
    c = np.cumsum(np.concatenate([[0.0], u]))
    c2 = np.cumsum(np.concatenate([[0.0], u * u]))
    m = (c[w:] - c[:-w]) / w
    sd = np.sqrt(np.maximum((c2[w:] - c2[:-w]) / w - m * m, 0.0))
    # every sample of a still window rests
    quiet = np.convolve((sd < still * np.std(u)).astype(float), np.ones(w))[:len(u)] > 0.5
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(int), [0]])))
    ss, n = 0.0, 0
    skip, need = int(round(settle_s * rate)), int(round(min_rest_s * rate))
    for a, b in zip(edges[::2], edges[1::2]):
        a += skip if a > 0 else 0      # a record that starts at rest has nothing to settle from
        if b - a < need:
            continue
        seg = y[a:b]
        k = np.arange(len(seg))
        seg = seg - np.polyval(np.polyfit(k, seg, 1), k)
        ss, n = ss + float(seg @ seg), n + len(seg)
    return float(np.sqrt(ss / n)) if n else 0.0


def ljung_box(r: np.ndarray, lags: int) -> tuple[float, float, np.ndarray]:
    """Ljung-Box Q over lags 1..``lags``, its chi-square p-value, and the autocorrelations."""
    x = np.asarray(r, float) - np.mean(r)
    n = len(x)
    v = float(x @ x)
    if v <= 0 or n <= lags + 1:
        return 0.0, 1.0, np.zeros(lags)
    rho = np.array([float(x[:-k] @ x[k:]) / v for k in range(1, lags + 1)])
    q = float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, lags + 1))))
    return q, float(stats.chi2.sf(q, lags)), rho


def spectrum_peak(r: np.ndarray, rate: float) -> tuple[float, float]:
    """Dominant frequency [Hz] of the residual and its share of the (detrended) power."""
    x = np.asarray(r, float) - np.mean(r)
    if len(x) < 16 or not np.any(x):
        return 0.0, 0.0
    p = np.abs(np.fft.rfft(x * np.hanning(len(x)))) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / rate)
    p[0] = 0.0
    k = int(np.argmax(p))
    band = p[max(k - 2, 0):k + 3].sum()
    return float(f[k]), float(band / p.sum()) if p.sum() > 0 else 0.0


@dataclass
class ChannelResidual:
    channel: str
    unit: str
    rms: float
    bias: float
    noise_sd: float              # estimated from the measured channel itself
    floor: float                 # the model's known residual floor on this channel
    lag1: float
    ljung_box_q: float
    ljung_box_p: float
    peak_hz: float
    peak_share: float
    segments: dict[str, dict[str, float]]
    structured: bool
    evidence: str


@dataclass
class ResidualAnalysis:
    """Per-channel residual statistics and the overall verdict."""
    channels: dict[str, ChannelResidual]
    verdict: str                 # 'noise' or 'structured'
    evidence: list[str] = field(default_factory=list)

    @property
    def structured(self) -> bool:
        return self.verdict == "structured"

    def as_dict(self) -> dict:
        return {"verdict": self.verdict, "evidence": self.evidence,
                "channels": {k: asdict(v) for k, v in self.channels.items()}}


def analyse(t: np.ndarray, measured: dict[str, np.ndarray], fitted: dict[str, np.ndarray],
            segments: dict[str, np.ndarray] | None = None, floor: dict[str, float] | None = None,
            lags: int = 20, factor: float = 1.5, alpha: float = 0.01,
            noise: dict[str, float] | None = None) -> ResidualAnalysis:
    """Analyse ``fitted - measured`` per channel (SI arrays on the time base ``t`` [s]).

    ``segments`` maps a segment name to a boolean sample mask; ``floor`` gives the
    residual RMS the model leaves even on data without missing effects (its own
    model-form error, per channel; 0 when unknown); ``noise`` a per-channel noise level
    measured elsewhere (e.g. :func:`rest_noise_level`), used where it exceeds the
    second-difference estimate.
    """
    rate = 1.0 / float(np.median(np.diff(t)))
    floor = floor or {}
    out, evidence = {}, []
    for c, y in measured.items():
        r = np.asarray(fitted[c], float) - np.asarray(y, float)
        rms = float(np.sqrt(np.mean(r ** 2)))
        sd = max(noise_level(y), float((noise or {}).get(c, 0.0)))
        fl = float(floor.get(c, 0.0))
        q, p, rho = ljung_box(r, lags)
        f_pk, share = spectrum_peak(r, rate)
        segs = {name: {"rms": float(np.sqrt(np.mean(r[m] ** 2))), "bias": float(np.mean(r[m]))}
                for name, m in (segments or {}).items() if m.any()}
        allowed = factor * float(np.hypot(sd, fl))
        big = rms > allowed
        coloured = p < alpha
        structured = big and coloured
        unit = UNITS.get(c, "")
        worst = max(segs, key=lambda s: segs[s]["rms"]) if segs else "-"
        ev = (f"{c}: residual RMS {rms:.3g} {unit} vs noise {sd:.3g} {unit} and floor {fl:.3g} {unit} "
              f"({'above' if big else 'within'} x{factor:g}); Ljung-Box p={p:.2g} "
              f"({'coloured' if coloured else 'white'}); lag-1 autocorrelation {rho[0] if len(rho) else 0:+.2f}; "
              f"peak {f_pk:.1f} Hz ({100 * share:.0f} % of power); largest on segment {worst}")
        out[c] = ChannelResidual(c, unit, rms, float(np.mean(r)), sd, fl, float(rho[0]) if len(rho) else 0.0,
                                 q, p, f_pk, share, segs, structured, ev)
        if structured:
            evidence.append(ev)
    verdict = "structured" if evidence else "noise"
    if not evidence:
        evidence = ["every channel's residual is within its noise and model floor, or white"]
    return ResidualAnalysis(out, verdict, evidence)
