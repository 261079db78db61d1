"""What was measured: a :class:`Record` to fit, and the checks every record passes.

A record is the command, the channels a rig measured (any of
:data:`~eha_health.signals.channels.MEASURED`) and, optionally, a measured external load
force [N]. :meth:`Record.from_response` is the one place a record is checked (length,
time axis, finite values); :func:`check_fdi` adds what an FDI test needs (it starts at
t = 0 and covers the sequence).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..physics.sequence import FDISequence
from ..signals.channels import MEASURED
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


def check_fdi(record: Record, sequence: FDISequence) -> None:
    """Raise ``ValueError`` unless ``record`` can be a run of ``sequence``: it starts at t = 0 and
    lasts the whole sequence."""
    t, rate = record.t, record.sample_rate
    if abs(t[0]) > 0.5 / rate:
        raise ValueError(f"record starts at t={t[0]:g} s: the test window must start at t=0")
    if t[-1] + 1.0 / rate < sequence.duration - 1e-9:
        raise ValueError(f"record covers {t[-1] + 1.0 / rate:.3f} s but the FDI sequence lasts {sequence.duration:g} s")


def fdi_record(response: Response, sequence: FDISequence) -> Record:
    """The record of an FDI test: every measured channel required, checked against ``sequence``."""
    rec = Record.from_response(response, MEASURED)
    check_fdi(rec, sequence)
    return rec
