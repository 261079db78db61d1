"""Knobs: the scalars a fit may move, with their units, bounds and scales.

A :class:`Knob` is one fitted scalar of the monitor model: a fault coefficient, a nominal
parameter calibrated to a unit, or the size of an added effect. Its ``typical`` magnitude
sets the scale of the search and the finite-difference step; its ``off`` value is where its
mechanism is absent (a fault of 0, an effect switched off).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..physics.faults import FAULT_DOCS, FAULT_NAMES, FAULT_UPPER
from ..physics.params import ModelParams

#: Finite-difference step of every knob, as a share of its typical magnitude: a coefficient
#: (typical 0.1) steps by 0.002, which resolves the cost's slope without stepping over the
#: stick-slip and backlash events that make it rough on a finer scale.
STEP_SHARE = 0.02


@dataclass(frozen=True)
class Knob:
    """One fitted scalar of the monitor model [``unit``], within ``[lo, hi]``.

    ``apply(params, value)`` returns the changed parameter set; a fault coefficient has
    ``fault`` set instead (one of :data:`~eha_health.physics.faults.FAULT_NAMES`); a
    measurement-chain knob has ``output(out, value, rate)`` instead, which changes a simulated
    output ``[n, N_OUT]`` (sampled at ``rate`` [Hz]) after the fact and needs no simulation.
    """
    name: str
    unit: str
    lo: float
    hi: float
    typical: float
    off: float = 0.0
    apply: Callable[[ModelParams, float], ModelParams] | None = None
    fault: str | None = None
    doc: str = ""
    step_share: float = STEP_SHARE      # finite-difference step as a share of ``typical``
    output: Callable | None = None      # measurement-chain knob: out[n, N_OUT], value, rate -> out

    @property
    def recording(self) -> bool:
        """True when the knob acts on the recorded output, not on the model."""
        return self.output is not None

    @property
    def step(self) -> float:
        """Finite-difference step [unit]: ``step_share`` of the typical magnitude."""
        return self.step_share * abs(self.typical)


#: The three fault coefficients as knobs (0 healthy, searched up to FAULT_UPPER).
FAULT_KNOBS = tuple(Knob(n, "-", 0.0, FAULT_UPPER, 0.1, 0.0, fault=n, doc=FAULT_DOCS[n]) for n in FAULT_NAMES)
