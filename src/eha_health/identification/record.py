"""What was measured: a :class:`Record` to fit, and the checks every record passes.

A record is the command, the channels a rig measured (any of
:data:`~eha_health.signals.channels.MEASURED`) and, optionally, a measured external load
force [N]. :meth:`Record.from_response` is the one place a record is checked (length,
time axis, finite values); :func:`check_fdi` adds what an FDI test needs (it starts at
t = 0 and covers the sequence).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import fftconvolve

from ..physics.sequence import FDISequence
from ..signals.channels import MEASURED
from ..signals.datachecks import quantisation_step
from ..signals.residuals import noise_level
from ..signals.response import Response

#: Channels a record may hold: the measured ones, and the spool of a simulated response.
RECORDABLE = MEASURED + ("spool",)
MIN_SAMPLES = 100
#: [Hz] slowest sampling a record may have (the FDI test's 4 Hz sine and the loop's ~10 Hz
#: bandwidth need tens of samples per period)
MIN_RATE_HZ = 50.0


@dataclass
class Record:
    """Measured data to fit: SI channels on a uniform time base [s], optional load force [N]."""
    t: np.ndarray
    command: np.ndarray
    channels: dict[str, np.ndarray]
    load: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    #: command [m] simulated before t = 0 at the same rate, its outputs not compared: what led
    #: into the test when it did not start at rest (``FDISequence.preamble``); None: from rest
    preroll: np.ndarray | None = None
    #: channel -> mask of samples with no information about the actuator (spikes, clipped or
    #: frozen samples: :func:`~eha_health.signals.cleaning.clean`): weight 0 in every residual
    excluded: dict[str, np.ndarray] = field(default_factory=dict)
    #: [Hz] rate at which the actuator's controller updated the command, held between updates; None:
    #: not known, taken as :data:`~.problem.COMMAND_RATE_HZ` (a record sampled slower is simulated at
    #: a multiple of its rate, the command interpolated: :func:`~.problem.oversampling`)
    command_rate: float | None = None

    @classmethod
    def from_response(cls, r: Response, channels: tuple[str, ...] | None = None) -> "Record":
        """Take the measured channels of ``r`` (those given, or every all-finite one); ``ValueError``
        names the first problem."""
        t = np.asarray(r.t, float)
        if len(t) < MIN_SAMPLES:
            raise ValueError(f"window too short: {len(t)} samples (need >= {MIN_SAMPLES})")
        dt = np.diff(t)
        if (dt <= 0).any():
            raise ValueError("time axis is not strictly increasing")
        step = float(np.median(dt))
        rate = 1.0 / step
        off = np.abs(dt - step) > 0.01 * step
        if off.any():
            k = int(np.argmax(np.abs(dt - step)))
            raise ValueError(f"samples are not uniformly spaced (median rate {rate:.1f} Hz): gaps or jitter; "
                             f"{int(off.sum())} step(s) off the median "
                             f"{1e3 * step:.4g} ms, the largest {1e3 * dt[k]:.4g} ms at t = {t[k]:g} s "
                             f"(resample onto a uniform time base, or cut the record there)")
        if rate < MIN_RATE_HZ:
            raise ValueError(f"sample rate {rate:.3g} Hz is below {MIN_RATE_HZ:g} Hz, too slow for an actuator's "
                             f"dynamics: is the time column in milliseconds? (t must be in seconds)")
        if not np.isfinite(r.command).all():
            raise ValueError("channel command has NaN or inf samples")
        names = channels or tuple(c for c in MEASURED if np.isfinite(getattr(r, c)).all())
        chans = {}
        for c in names:
            if c not in RECORDABLE:
                raise ValueError(f"unknown channel {c!r}; known: {', '.join(RECORDABLE)}")
            v = np.asarray(getattr(r, c), float)
            bad = ~np.isfinite(v)
            if bad.all():
                raise ValueError(f"channel {c} is not in the record (no finite sample)")
            if bad.any():
                raise ValueError(f"channel {c} has {int(bad.sum())} NaN or inf samples, the first at "
                                 f"t = {t[int(np.argmax(bad))]:g} s")
            chans[c] = v
        if not chans:
            raise ValueError("no measured channel: need at least one of " + ", ".join(MEASURED))
        load = getattr(r, "load", None)
        if load is not None and not np.isfinite(load).all():
            raise ValueError("channel load has NaN or inf samples")
        return cls(t, np.asarray(r.command, float), chans, load, dict(r.meta))

    @property
    def sample_rate(self) -> float:
        """[Hz]"""
        return 1.0 / float(np.median(np.diff(self.t)))

    def __len__(self) -> int:
        return len(self.t)


#: A recorded command that matches the sequence from a later sample this many times better (in mean
#: square) than from t = 0, and there within this share of the sequence's RMS, is a test that starts
#: later in the record (a logger started before it) [-] -- when it starts at least LATER_START_MIN_S
#: [s] in: a few milliseconds is a skew of the command channel, which the discrepancy loop names
#: (command_skew), not a test in the wrong place
LATER_START_GAIN, LATER_START_MATCH, LATER_START_MIN_S = 10.0, 0.05, 0.02


#: A recorded command within this share of the sequence's RMS of it (RMS of the difference, from
#: t = 0) is the FDI sequence [-]. Measured: a recorded FDI command 0; the same 3 ms late 0.08, on a
#: clock 1 % fast 0.34; the MTS rig's chirp 1.02 (an unrelated signal of like size reads ~1.4)
FDI_COMMAND_MATCH = 0.5


def _sequence_command(t: np.ndarray, sequence: FDISequence) -> np.ndarray:
    """``sequence``'s command [m] sampled at the record's median rate from t = 0."""
    return sequence.command(sequence.times(1.0 / float(np.median(np.diff(t)))))


def command_mismatch(t: np.ndarray, command: np.ndarray, sequence: FDISequence) -> float:
    """RMS of (recorded command - ``sequence``'s command) from t = 0 over the sequence's length (the
    record's, if shorter), over the RMS of the sequence's command there [-]; inf where the command is
    not finite there."""
    u = _sequence_command(t, sequence)
    c = np.asarray(command, float)
    n = min(len(c), len(u))
    if not np.isfinite(c[:n]).all():
        return float("inf")
    return float(np.sqrt(np.mean((c[:n] - u[:n]) ** 2) / max(float(np.mean(u[:n] ** 2)), 1e-300)))


class LaterStart(ValueError):
    """The FDI test starts later in the record than t = 0 (the message says where, and what to do)."""


def later_start(t: np.ndarray, command: np.ndarray, sequence: FDISequence) -> tuple[int, float] | None:
    """``(k, err0)`` when the recorded ``command`` shows ``sequence`` starting at sample k > 0 rather
    than at the first (the best match over every start that leaves the whole sequence in the record,
    at sample resolution; the thresholds above), with its RMS mismatch from the first sample [m];
    else None."""
    rate = 1.0 / float(np.median(np.diff(t)))
    c = np.asarray(command, float)
    if len(c) <= round(sequence.duration * rate) or not np.isfinite(c).all():
        return None                     # (checked first: no sequence longer than the record is built)
    u = _sequence_command(t, sequence)
    n = len(u)
    # sum over the window of (c - u)^2 for every start k: sum c^2 (cumulative) - 2 c.u (correlation) + sum u^2
    c2 = np.concatenate([[0.0], np.cumsum(c * c)])
    sq = np.maximum(c2[n:] - c2[:-n] - 2 * fftconvolve(c, u[::-1], mode="valid") + float(u @ u), 0.0) / n
    k = int(np.argmin(sq))
    if (t[k] - t[0] >= LATER_START_MIN_S and sq[k] < (LATER_START_MATCH ** 2) * float(u @ u) / n
            and sq[k] * LATER_START_GAIN < sq[0]):
        return k, float(np.sqrt(sq[0]))
    return None


def check_fdi(record: Record, sequence: FDISequence) -> None:
    """Raise ``ValueError`` unless ``record`` can be a run of ``sequence``: it starts at t = 0 and
    lasts the whole sequence (:class:`LaterStart` when its command shows the test starting later)."""
    t, rate = record.t, record.sample_rate
    if abs(t[0]) > 0.5 / rate:
        raise ValueError(f"record starts at t={t[0]:g} s: the test window must start at t=0")
    if t[-1] + 1.0 / rate < sequence.duration - 1e-9:
        raise ValueError(f"record covers {t[-1] + 1.0 / rate:.3f} s but the FDI sequence lasts {sequence.duration:g} s")
    late = later_start(t, record.command, sequence)
    if late is not None:
        start = float(t[late[0]] - t[0])
        raise LaterStart(f"the FDI test starts at t = {start:.4g} s of the record, not at t = 0: its command "
                         f"matches the sequence from there (from t = 0 it is {1e3 * late[1]:.3g} mm RMS off; a "
                         f"logger started before the test?): cut the record there -- drop the rows before "
                         f"t = {start:.4g} s and subtract {start:.4g} s from t (the CLI does it, and says so)")


def from_zero(t: np.ndarray) -> np.ndarray:
    """``t - t[0]`` [s]; put on a uniform grid when the stamps are uniform within the float rounding
    of their magnitude -- absolute clock stamps (Unix time: 2.4e-7 s at 1.7e9 s) would otherwise give
    a sample rate off by parts in 1e4, which no integration step divides -- its rate rounded to the
    mHz where the record's span cannot tell it from that."""
    t = np.asarray(t, float)
    rel = t - t[0]
    n, span = len(t), float(rel[-1])
    res = 4.0 * float(np.spacing(np.max(np.abs(t))))
    if n < 3 or span <= 0 or np.max(np.abs(rel - np.arange(n) * (span / (n - 1)))) > res:
        return rel      # uniform to the last bit already, or real jitter: Record.from_response judges it
    rate = (n - 1) / span
    if abs(round(rate, 3) - rate) <= 2.0 * res / span * rate:
        rate = round(rate, 3)
    return np.arange(n) / rate


def from_test_start(response: Response, sequence: FDISequence | None = None) -> tuple[Response, str | None]:
    """``response`` cut where its command shows ``sequence`` starting (:func:`later_start`), t from 0
    there, and a note saying so; t counted from the first sample, and a note, when it starts
    elsewhere (a logger's absolute clock: :func:`from_zero`); unchanged and None when it starts at 0."""
    seq = sequence or FDISequence()
    t = np.asarray(response.t, float)
    if len(t) < 2 or not (np.diff(t) > 0).all():
        return response, None           # Record.from_response names the problem
    late = later_start(t, response.command, seq)
    if late is None:
        if abs(t[0]) <= 0.5 * float(np.median(np.diff(t))):
            return response, None
        return replace(response, t=from_zero(t)), (
            f"the record's time starts at t = {t[0]:.10g} s (an absolute clock?): t counted from its first sample")
    k, err0 = late
    cut = response.sliced(slice(k, None))
    return replace(cut, t=from_zero(cut.t)), (
        f"the FDI test starts at t = {t[k] - t[0]:.4g} s of the record (its command matches the sequence from "
        f"there; from t = 0 it is {1e3 * err0:.3g} mm RMS off): the {k} samples before it were dropped and t "
        f"counted from there")


def recorded(response: Response) -> tuple[str, ...]:
    """The measured channels ``response`` holds: those with a finite sample (a CSV without the
    column, or a bag without the topic, reads all NaN)."""
    return tuple(c for c in MEASURED if getattr(response, c, None) is not None
                 and np.isfinite(np.asarray(getattr(response, c), float)).any())


#: A recorded FDI command whose white noise (second differences) is above this share of its peak
#: carries a logger's noise [-]: a command the controller computed reads ~1e-16 of it
COMMAND_NOISE_SHARE = 1e-9


def logged_command(response: Response, sequence: FDISequence) -> tuple[Response, str | None]:
    """``response`` with a noisy or quantised recording of ``sequence``'s command replaced by the
    sequence as that logger saw it, ``a + (1 + e) u(t - d)`` (offset a [m], gain error e, delay d
    [s] in whole samples within +-20: least squares), and a line saying so; unchanged (None) when
    the recorded command is noise-free, or (with a line) when the fit leaves more than 3x its noise.

    The actuator received the controller's command, not the logger's reading of it: driven by a
    command with 0.5 um of ADC noise the monitor's current carried 25 uA of noise against the
    measured 2.7 uA, and the discrepancy loop named stribeck (1 um: vibration_null_shift; 2 um:
    "unexplained"). Offset, gain and delay are kept, for the loop's command candidates to judge.
    Samples after the sequence's end keep their recorded values."""
    t = np.asarray(response.t, float)
    c = np.asarray(response.command, float)
    inside = t <= sequence.duration + 1e-9
    if inside.sum() < 10 or not np.isfinite(c[inside]).all():
        return response, None
    ci, ti = c[inside], t[inside]
    peak = float(np.max(np.abs(ci)))
    sd, q = noise_level(ci), quantisation_step(ci)
    if peak <= 0 or (sd <= COMMAND_NOISE_SHARE * peak and q <= 0):
        return response, None
    # the delay in whole samples (the recorded steps then fall where the logger put them; a
    # sub-sample delay leaves more than the noise and the command is used as recorded), then the
    # offset and gain by linear least squares
    rate = 1.0 / float(np.median(np.diff(ti)))
    u0 = sequence.command(ti)

    def shifted(k: int) -> np.ndarray:
        """u0 k samples late (by index: a step stays on its sample), ends held."""
        return np.concatenate([np.full(k, u0[0]), u0[:len(u0) - k]]) if k >= 0 else \
            np.concatenate([u0[-k:], np.full(-k, u0[-1])])

    fits = []
    for k in range(-20, 21):
        A = np.column_stack([np.ones(len(u0)), shifted(k)])
        coef = np.linalg.lstsq(A, ci, rcond=None)[0]
        fits.append((float(np.sum((ci - A @ coef) ** 2)), k, coef))
    _, k, (offset, gain) = min(fits, key=lambda f: f[0])
    smooth = offset + gain * shifted(k)
    left = float(np.sqrt(np.mean((ci - smooth) ** 2)))
    level = max(sd, q / np.sqrt(12.0))
    what = " and ".join(([f"white noise {sd:.3g} m RMS"] if sd > COMMAND_NOISE_SHARE * peak else [])
                        + ([f"quantised in steps of {q:.3g} m"] if q > 0 else []))
    if left > 3.0 * level:
        return response, (f"command: {what}, but it departs from the FDI sequence by more ({left:.3g} m RMS "
                          f"after an offset, gain and delay): used as recorded")
    out = c.copy()
    out[inside] = smooth
    return replace(response, command=out), (
        f"command: {what} (the logger's: the actuator received the controller's command): the model "
        f"is driven by the FDI sequence as recorded -- offset {offset:.3g} m, gain error {gain - 1.0:.3g}, "
        f"delay {k / rate * 1e3:.3g} ms -- without it ({left:.3g} m RMS removed)")


def fdi_record(response: Response, sequence: FDISequence) -> Record:
    """The record of an FDI test, checked against ``sequence``: the measured channels it holds (one
    that is all NaN was not recorded; one with some NaN samples is refused, naming them)."""
    rec = Record.from_response(response, recorded(response) or MEASURED)
    check_fdi(rec, sequence)
    return rec
