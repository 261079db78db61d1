"""Progressive fault coefficients: the one place their names and bounds are defined.

Each coefficient is 0 for a healthy actuator and 1 at the paper's limit condition;
values above 1 are beyond-limit damage, searched up to :data:`FAULT_UPPER`. What a
coefficient means physically is :class:`~eha_health.physics.params.FaultLimits` and
:func:`~eha_health.physics.packing.effective`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: Names of the coefficients, in the order of every vector of them (K_GM, K_FSJ, K_BKL).
FAULT_NAMES = ("k_gm", "k_fsj", "k_bkl")
#: Short names (command line, history files): ``gm=0.4,fsj=0.6``.
FAULT_KEYS = tuple(n.removeprefix("k_") for n in FAULT_NAMES)
#: What each coefficient measures.
FAULT_DOCS = {"k_gm": "torque-motor demagnetisation", "k_fsj": "jack static-friction rise",
              "k_bkl": "linkage backlash"}
#: Upper bound of every coefficient a search or a plant accepts: beyond-limit damage is findable.
FAULT_UPPER = 1.5


@dataclass(frozen=True)
class Faults:
    """Progressive fault coefficients: 0 healthy, 1 limit, > 1 beyond-limit damage."""
    k_gm: float = 0.0
    k_fsj: float = 0.0
    k_bkl: float = 0.0

    def __post_init__(self):
        for name in FAULT_NAMES:
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"fault coefficient {name} must be a finite number, got {v!r}")
            if v < 0:
                raise ValueError(f"fault coefficient {name} must be >= 0 (0 = healthy), got {v}")

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.k_gm, self.k_fsj, self.k_bkl)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(FAULT_NAMES, self.as_tuple()))

    @classmethod
    def parse(cls, text: str) -> "Faults":
        """Parse ``"gm=0.4,fsj=0.6,bkl=0.4"`` (missing keys are 0)."""
        vals = dict.fromkeys(FAULT_KEYS, 0.0)
        for part in filter(None, (s.strip() for s in text.split(","))):
            if "=" not in part:
                raise ValueError(f"fault spec {part!r}: expected name=value (gm, fsj, bkl)")
            k, v = (s.strip().lower() for s in part.split("=", 1))
            k = k.removeprefix("k_")
            if k not in vals:
                raise ValueError(f"unknown fault {k!r}: expected gm, fsj or bkl")
            try:
                vals[k] = float(v)
            except ValueError:
                raise ValueError(f"fault {k}: {v!r} is not a number") from None
        return cls(*(vals[k] for k in FAULT_KEYS))


