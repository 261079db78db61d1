"""Checks of a recorded channel that no model refit explains: quantisation, clipping, interference,
spikes, polarity.

* quantisation: the channel takes values on a grid of step q (an ADC or a coarse encoder);
  its error is uniform, standard deviation q / sqrt(12), and is named when that reaches a
  quarter of the channel's noise;
* clipping: many samples pinned at the channel's extreme value, far more than at the level next
  to it (a transducer or amplifier at its range), where the fitted model goes beyond it (where the
  model dwells there too, it is the actuator's own limit, e.g. the servo current's saturation) --
  they carry no information about the actuator;
* periodic interference: a narrow peak of the residual spectrum (5 bins around the largest
  line hold >= ``share`` of its power) above the command's band (mains hum, a pump's
  ripple), named with its frequency;
* frozen samples: runs of >= 10 equal values while the fitted model moves by more than 5 noise
  standard deviations and 3 quantisation steps (a logger repeating its last value);
* spikes: isolated one-sample outliers the model does not have (acquisition glitches): a second
  difference d2[n] = y[n] - (y[n-1] + y[n+1]) / 2 beyond 10 robust standard deviations, 5x the
  noise, 3 quantisation steps and 2 % of the channel's range, with the single-sample pattern
  d2[n -+ 1] = -d2[n] / 2 (a quantised channel toggles a level for one sample, and a noise-free
  simulated one shows sub-percent one-sample features of the physics: measured, 7.6e-5 A of
  current with oil compressibility);
* polarity: the recording anticorrelated with the model (correlation < -0.5; the healthy monitor
  against the reference at faults and effects up to their limits: >= 0.70 on every channel,
  measured on 40 runs): a sign inverted in the acquisition, which no scale candidate (+/-30 %)
  spans;
* one chamber's pressure: the jack's differential pressure P12 = P1 - P2 changes sign as the
  motion reverses, while a chamber's P1 = (Ps + P12) / 2 (or P2 = (Ps - P12) / 2, symmetric valve)
  stays positive around half the supply Ps: a recorded "P12" that stays around Ps / 2 while the
  model's changes sign is one chamber's pressure, which no offset or scale candidate spans.
"""
from __future__ import annotations

import numpy as np

from .residuals import noise_level, spectrum_peak


def quantisation_step(y: np.ndarray) -> float:
    """The grid step [channel unit] the samples lie on, or 0 when they do not lie on one."""
    u = np.unique(np.asarray(y, float))
    if len(u) < 3 or len(u) > 0.5 * len(y):
        return 0.0
    d = np.diff(u)
    q = float(np.min(d))
    if q <= 0 or np.any(np.abs(d / q - np.round(d / q)) > 0.05):
        return 0.0
    return q


def clipped(y: np.ndarray, model: np.ndarray | None = None, margin: float = 0.0, min_run: int = 3,
            factor: float = 3.0) -> np.ndarray:
    """Mask of the samples pinned at the channel's max or min: at least ``min_run`` of them, and
    ``factor`` times as many as at the next level inward (a smooth or quantised peak dwells
    about as long on its top level as on the one below it; a clipped one far longer). Given the
    fitted ``model`` of the channel, a side counts only where the model goes beyond the pinned
    level by more than ``margin`` on at least half of its pinned samples."""
    y = np.asarray(y, float)
    out = np.zeros(len(y), bool)
    u, counts = np.unique(y, return_counts=True)
    if len(u) < 3:
        return out
    for level, ext, nb, sign in ((u[-1], counts[-1], counts[-2], 1.0), (u[0], counts[0], counts[1], -1.0)):
        if ext >= min_run and ext >= factor * nb:
            at = y == level
            if model is not None and np.mean(sign * (np.asarray(model, float)[at] - level) > margin) < 0.5:
                continue
            out |= at
    return out


#: Noise (1 sd) over a channel's range below which the channel is taken as noise-free (a simulation).
MEASURABLE_NOISE = 1e-4
#: Share of a channel's samples pinned at an extreme from which it is named (and set aside) as clipped.
CLIPPED_SHARE = 0.005


def noisy(y: np.ndarray, noise_sd: float) -> bool:
    """Does the channel carry measurable noise (``noise_sd`` >= :data:`MEASURABLE_NOISE` of its range)?"""
    return len(y) > 1 and noise_sd >= MEASURABLE_NOISE * float(np.ptp(y))


def frozen(y: np.ndarray, model: np.ndarray, noise_sd: float, step: float = 0.0, min_run: int = 10) -> np.ndarray:
    """Mask of the samples in runs of at least ``min_run`` identical values while the fitted
    ``model`` moves by more than max(5 ``noise_sd``, 3 ``step``) within the run: a logger that
    repeated its last value (a dropout, a stalled buffer). A noisy channel never repeats a value
    that long; at rest, or on a quantised slow ramp, the model does not move that much. A channel
    without measurable noise (:func:`noisy`: a noise-free simulation) is not
    judged: it repeats values on its physical plateaus -- a saturated current, the zero pressure of
    a backlash free play -- where a model that differs in detail moves (measured: noise / range
    0.5-1.4e-5 on the shipped noise-free bags, >= 1.6e-4 with the default sensor noise)."""
    y, m = np.asarray(y, float), np.asarray(model, float)
    out = np.zeros(len(y), bool)
    if len(y) < min_run or not noisy(y, noise_sd):
        return out
    starts = np.flatnonzero(np.concatenate([[True], np.diff(y) != 0]))
    ends = np.append(starts[1:], len(y))
    moves = max(5.0 * noise_sd, 3.0 * step)
    for a, b in zip(starts, ends):
        if b - a >= min_run and np.ptp(m[a:b]) > moves:
            out[a:b] = True
    return out


def spikes(y: np.ndarray, model: np.ndarray, noise_sd: float, step: float = 0.0, sigmas: float = 10.0,
           range_share: float = 0.02) -> np.ndarray:
    """Indices of isolated one-sample spikes of ``y`` that the fitted ``model`` does not have
    (``step``: the channel's quantisation step, 0 if none)."""
    y, m = np.asarray(y, float), np.asarray(model, float)
    if len(y) < 5:
        return np.zeros(0, int)
    d2 = y[1:-1] - 0.5 * (y[:-2] + y[2:])
    m2 = m[1:-1] - 0.5 * (m[:-2] + m[2:])
    robust = noise_level(y) * np.sqrt(1.5)     # d2 of white noise of sd s has sd s sqrt(1.5)
    big = np.abs(d2) > max(sigmas * robust, 5.0 * noise_sd, 3.0 * step, range_share * float(np.ptp(y)), 1e-300)
    big &= np.abs(m2) < np.abs(d2) / 3.0
    i = np.flatnonzero(big[1:-1]) + 1          # interior of d2: both neighbours exist
    lone = (np.abs(d2[i - 1] + 0.5 * d2[i]) < 0.2 * np.abs(d2[i])) & \
           (np.abs(d2[i + 1] + 0.5 * d2[i]) < 0.2 * np.abs(d2[i]))
    return i[lone] + 1


def single_chamber(y: np.ndarray, model: np.ndarray, supply_pa: float) -> str | None:
    """The finding when the recorded differential pressure ``y`` [Pa] is one chamber's, else None.

    Named when the model's P12 changes sign (2nd / 98th percentiles beyond -+2 % of the supply
    ``supply_pa``, 20x the default pressure noise; the healthy monitor on the FDI test: -+5.5 %)
    while the recording stays positive (2nd percentile above 10 % of the supply) with its median
    within 30-70 % of it: P1 or P2 = (Ps +- P12) / 2.
    """
    y, model = np.asarray(y, float), np.asarray(model, float)
    if not (len(y) and supply_pa > 0 and np.isfinite(y).all() and np.isfinite(model).all()):
        return None
    m_lo, m_hi = np.percentile(model, [2, 98])
    y_lo, y_med, y_hi = np.percentile(y, [2, 50, 98])
    if m_lo < -0.02 * supply_pa and m_hi > 0.02 * supply_pa and y_lo > 0.1 * supply_pa \
            and 0.3 * supply_pa <= y_med <= 0.7 * supply_pa:
        return (f"stays within {y_lo / 1e6:.2f}-{y_hi / 1e6:.2f} MPa around half the supply "
                f"({supply_pa / 2e6:.2f} MPa) where the model's differential pressure changes sign "
                f"({m_lo / 1e6:.2f} to {m_hi / 1e6:.2f} MPa): one chamber's pressure (P1 or P2) recorded as "
                f"the differential P12 = P1 - P2?")
    return None


#: Correlation with the model below which a recording's sign is taken to be inverted.
INVERTED_BELOW = -0.5


def inverted_sign(y: np.ndarray, model: np.ndarray) -> float | None:
    """The correlation of the recording ``y`` with the ``model``'s channel when it is below
    :data:`INVERTED_BELOW` (a sign inverted in the acquisition), else None (also for a constant
    or non-finite channel)."""
    y, model = np.asarray(y, float), np.asarray(model, float)
    if not (len(y) > 2 and np.isfinite(y).all() and np.isfinite(model).all()) or np.ptp(y) == 0 or np.ptp(model) == 0:
        return None
    r = float(np.corrcoef(y, model)[0, 1])
    return r if r < INVERTED_BELOW else None


def command_band(command: np.ndarray, rate: float, power: float = 0.99) -> float:
    """Frequency [Hz] below which ``power`` of the (detrended) command's power lies."""
    x = np.asarray(command, float) - np.mean(command)
    p = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / rate)
    c = np.cumsum(p) / max(p.sum(), 1e-300)
    return float(f[min(int(np.searchsorted(c, power)), len(f) - 1)])


def check_channel(name: str, y: np.ndarray, residual: np.ndarray, noise_sd: float, command: np.ndarray,
                  rate: float, share: float = 0.3) -> list[str]:
    """One line per finding on the recorded channel ``y``: ``residual`` is the fitted model's output
    minus ``y``, ``noise_sd`` the channel's noise [its unit]."""
    out = []
    y = np.asarray(y, float)
    model = y + np.asarray(residual, float)
    q = quantisation_step(y)
    if q > 0 and q / np.sqrt(12.0) >= 0.25 * noise_sd:
        out.append(f"{name}: quantised in steps of {q:.3g} (error {q / np.sqrt(12.0):.3g} rms against noise "
                   f"{noise_sd:.3g})")
    pinned = clipped(y, model, max(q, 2.0 * noise_sd))
    c = float(np.mean(pinned)) if len(y) else 0.0
    if c >= CLIPPED_SHARE:
        out.append(f"{name}: {100 * c:.1f} % of the samples pinned at the channel's extreme value while the model "
                   f"goes beyond it (clipping at the transducer's range?)")
    f_pk, s = spectrum_peak(residual, rate)
    band = command_band(command, rate)
    if s >= share and f_pk > 2.0 * band:
        out.append(f"{name}: periodic interference at {f_pk:.1f} Hz ({100 * s:.0f} % of the residual power), "
                   f"above the command's band ({band:.1f} Hz)")
    f = frozen(y, model, noise_sd, q) & ~pinned          # a clipped run is named as clipped
    if f.any():
        out.append(f"{name}: {int(f.sum())} sample(s) frozen in runs of >= 10 equal values while the model moves "
                   f"(a logger repeating its last value), first at sample {int(np.argmax(f))}")
    k = spikes(y, model, noise_sd, q)
    if len(k):
        out.append(f"{name}: {len(k)} isolated one-sample spike(s), largest {np.max(np.abs(residual[k])):.3g} "
                   f"from the model, first at sample {k[0]} (acquisition glitches: not motion)")
    r = inverted_sign(y, model)
    if r is not None:
        out.append(f"{name}: the recording is anticorrelated with the model (correlation {r:.2f}): "
                   f"a sign inverted in the acquisition?")
    return out
