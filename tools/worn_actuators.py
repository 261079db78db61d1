"""The discrepancy loop on worn actuators: effects at fault sets beyond the bench's (a generalisation probe).

    python tools/worn_actuators.py [EFFECT ...]

`eha-health bench discrepancy` places every effect at faults (0, 0, 0), (0.4, 0.5, 0) and
(0.3, 0.4, 0.3). An actuator near its limit has coefficients of 0.7-0.95, where backlash and
friction shape the response far more. This script runs nine of the bench's effects (in-loop ones
in the plant, recording ones altered after the test, as the bench makes them) at worn fault sets,
and two noise-only runs near the limit: one noisy reference run each (seeds 500 + i), one effect
at most. Per case the verdict, the first three candidates, the largest fault-coefficient error
before -> after, the model runs and the time with the start diagnosis (what `eha-health
discrepancy` takes). docs/discrepancy.md ("Worn actuators") quotes its output.
"""
from __future__ import annotations

import sys
import time

from eha_health.bench.discrepancy import effect_change, reference_run
from eha_health.discrepancy.loop import analyse_fdi_test
from eha_health.physics.faults import Faults
from eha_health.physics.params import load

#: (effect or None for noise only, faults (K_GM, K_FSJ, K_BKL)).
CASES = (("sensor_delay", (0.8, 0.9, 0.8)), ("position_offset", (0.8, 0.9, 0.8)),
         ("compressibility", (0.9, 0.2, 0.7)), ("pressure_offset", (0.2, 0.9, 0.9)),
         ("leakage", (0.7, 0.7, 0.0)), ("position_skew", (0.6, 0.3, 0.9)),
         ("valve_null_bias", (0.9, 0.9, 0.9)), ("current_scale", (0.8, 0.1, 0.5)),
         ("supply_pressure", (0.7, 0.8, 0.6)), (None, (0.9, 0.9, 0.9)), (None, (0.95, 0.05, 0.95)))


def main() -> None:
    ref = load("reference")
    only = sys.argv[1:]
    for i, (name, k) in enumerate(CASES):
        if only and name not in only:
            continue
        faults = Faults(*k)
        r = reference_run(faults, 500 + i, *effect_change(name), ref)
        t0 = time.perf_counter()
        rep = analyse_fdi_test(r, max_effects=1, truth=faults.as_dict())
        print(f"{name or 'noise only'} at {k}: {rep.verdict}; first {', '.join(c.name for c in rep.candidates[:3])}; "
              f"max|dK| {max(rep.before.errors.values()):.3f} -> {max(rep.after.errors.values()):.3f}; "
              f"{rep.runs} runs, {time.perf_counter() - t0:.1f} s", flush=True)


if __name__ == "__main__":
    main()
