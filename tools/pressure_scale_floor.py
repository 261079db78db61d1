"""Is a +3 % pressure transducer scale inside the monitor's own pressure floor? (a probe)

    python tools/pressure_scale_floor.py [N_NOISE]

`eha-health bench discrepancy` misses pressure_scale (+3 %) at all three fault sets: "no
significant missing effect". This script puts the pressure_scale candidate's evidence in those
three cases beside the same candidate's evidence on N_NOISE (default 8) noise-only runs at random
faults (seed 11; noise seeds 500 + case): its fitted size +/- standard error, dIC, fit and
held-out ratios and projection share, the pressure channel's residual RMS, noise and floor, the
first-ranked candidate and the largest fault-coefficient error of the starting diagnosis. Figures
in docs/discrepancy.md ("The misses, by kind").
"""
import sys

import numpy as np

from eha_health.bench import discrepancy as bd
from eha_health.discrepancy.loop import analyse_fdi_test
from eha_health.physics.faults import Faults
from eha_health.physics.model import simulate
from eha_health.physics.params import load


def main() -> None:
    n_noise = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    ref = load("reference").with_effect_names(["sensor_noise"])
    alter = bd.effect_change("pressure_scale")[1]
    rng = np.random.default_rng(11)
    cases = [("pressure_scale", f) for f in bd.FAULT_SETS]
    cases += [(None, Faults(*rng.uniform(0, 1, 3))) for _ in range(n_noise)]
    for i, (name, f) in enumerate(cases):
        r = simulate(params=ref, faults=f, seed=500 + i)
        if name:
            r = alter(r)
        rep = analyse_fdi_test(r, max_effects=1, truth=f.as_dict())
        ch = rep.residual_before.channels["pressure"]
        e = next(c for c in rep.candidates if c.name == "pressure_scale")
        top = rep.candidates[0]
        print(f"{name or 'noise only':15s} {f.k_gm:.2f},{f.k_fsj:.2f},{f.k_bkl:.2f} {rep.verdict[:22]:22s} "
              f"pressure RMS {ch.rms / 1e3:.1f} kPa, noise {ch.noise_sd / 1e3:.1f}, floor {ch.floor / 1e3:.1f} | "
              f"pressure_scale {e.parameters['pressure_scale']:+.4f} +/- {e.std['pressure_scale']:.4f} "
              f"dIC {e.delta_ic:.1f} fit x{e.fit_ratio:.3f} held-out x{e.held_out_ratio:.3f} "
              f"projection {e.projection:.2f} | first {top.name} (dIC {top.delta_ic:.1f}) | "
              f"max|dK| {max(rep.before.errors.values()):.3f}", flush=True)


if __name__ == "__main__":
    main()
