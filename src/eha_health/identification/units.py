"""Is each recorded channel in the unit the model speaks (SI: m, m/s, Pa, A)?

The healthy monitor model is run once on the record's own command (and load); each channel's
least-squares gain against it, g = <y~, m~> / <m~, m~> with both centred, is what the
recording's unit makes of the SI value. Faults and every modelled effect move a channel's
amplitude by far less than the common unit factors (mm or mA 1e3, kPa 1e-3, bar 1e-5, MPa 1e-6,
psi 1.45e-4, inch 39.4): beyond :data:`LIMIT` either way the record is refused, naming the
channel, the gain and the unit it looks like, before any fit spends its time on it (a pressure
in bar was otherwise "explained" as a -30 % pressure_scale with K_FSJ 0 for a true 0.4).
A pressure that is one chamber's, not the differential (:func:`~eha_health.signals.datachecks.single_chamber`),
is refused the same way (it was fitted as K_FSJ 1.5, on its bound, for a true 0.4), and so is a
channel whose sign is inverted (:func:`~eha_health.signals.datachecks.inverted_sign`: a pressure
recorded as P2 - P1 was diagnosed K_FSJ 0.0 for a true 0.4, and the loop called it unexplained).
"""
from __future__ import annotations

import numpy as np

from ..signals.channels import UNITS
from ..signals.datachecks import inverted_sign, single_chamber
from .problem import KnobModel
from .residual import CHANNEL_COLUMNS

#: Gain (either way) beyond which a channel is taken to be in another unit.
LIMIT = 20.0
#: Common units of each channel as (value in that unit per SI unit, name).
OTHER_UNITS = {
    "position": ((1e3, "mm"), (1e6, "um"), (39.37, "in")),
    "velocity": ((1e3, "mm/s"), (39.37, "in/s")),
    "pressure": ((1e-3, "kPa"), (1e-5, "bar"), (1e-6, "MPa"), (1.450377e-4, "psi")),
    "current": ((1e3, "mA"), (1e6, "uA")),
}


def _output(model: KnobModel, x=None) -> np.ndarray:
    x = model.off() if x is None else np.asarray(x, float)
    return model.run(x[None, :], count=False)[0]


def unit_gains(model: KnobModel, x=None, out: np.ndarray | None = None) -> dict[str, float]:
    """Least-squares gain of each recorded channel against the model at knob vector ``x``
    (default: its ``off`` vector, the healthy model; nan where the model's channel does not move);
    ``out``: the model's output there, if already run."""
    out = _output(model, x) if out is None else out
    gains = {}
    for c, y in model.record.channels.items():
        m = out[:, CHANNEL_COLUMNS[c]] - np.mean(out[:, CHANNEL_COLUMNS[c]])
        yc = np.asarray(y, float) - np.mean(y)
        mm = float(m @ m)
        gains[c] = float(yc @ m) / mm if mm > 0 else float("nan")
    return gains


def check_units(model: KnobModel, x=None) -> np.ndarray:
    """Raise ``ValueError`` naming the first channel whose recording is more than :data:`LIMIT`
    times larger or smaller than the model's at ``x`` (default: healthy), whose sign is inverted
    against it, or a pressure that is one chamber's instead of the differential. Returns the
    model's output at ``x`` (the run the check made)."""
    out = _output(model, x)
    for c, g in unit_gains(model, x, out).items():
        if np.isfinite(g) and g != 0 and max(abs(g), 1 / abs(g)) > LIMIT:
            near = min(OTHER_UNITS.get(c, ()), key=lambda u: abs(np.log10(abs(g) / u[0])), default=None)
            guess = f" -- in {near[1]}?" if near and abs(np.log10(abs(g) / near[0])) < 0.5 else ""
            raise ValueError(f"channel {c} is {abs(g):.3g} x the healthy model's (least-squares gain {g:.3g}): "
                             f"not in {UNITS[c]}{guess} (every channel must be SI: convert it, e.g. by the "
                             f"scale of its column in an `eha-health import` channel map)")
    if "pressure" in model.record.channels:
        chamber = single_chamber(model.record.channels["pressure"], out[:, CHANNEL_COLUMNS["pressure"]],
                                 model.base.hydraulics.supply_pressure)
        if chamber:
            raise ValueError(f"channel pressure {chamber} Record P1 - P2 (an `eha-health import` channel map "
                             f"takes `minus: COLUMN` for the second chamber)")
    # after the chamber check: P2 = (Ps - P12) / 2 is anticorrelated too, and that is the better name
    for c, y in model.record.channels.items():
        r = inverted_sign(y, out[:, CHANNEL_COLUMNS[c]])
        if r is not None:
            raise ValueError(f"channel {c} is anticorrelated with the healthy model (correlation {r:.2f}): its "
                             f"sign is inverted in the acquisition (a transducer wired the other way round"
                             f"{', or P2 - P1 recorded for P1 - P2' if c == 'pressure' else ''})? Flip it "
                             f"(scale: -1 for its column in an `eha-health import` channel map)")
    return out
