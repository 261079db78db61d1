"""`prognose` on degradation laws the bench does not simulate (a generalisation probe).

    python tools/prognose_laws.py [LAW ...] [--units 30] [--seed 3] [--settings YAML]

`eha-health bench rul` scores the prognosis on four laws (linear, exponential, power, two-phase)
through real diagnoses. This script asks how it does on mean paths of other shapes, with the
diagnosis replaced by white noise (0.01, stated as the standard error): per law, ``--units``
actuators, each a gamma wear process (scale 0.002) about thr h((t - t_on) / L) for the K_FSJ
threshold 0.915, life L lognormal (median 1000 h, sd of log 0.3), onset after 5-25 % of L, tests
every 60 h, the history cut at a uniform 40-80 % of L; the true RUL is the gamma path continued to
the threshold. Prints, per law, the units given a RUL, the coverage of the 5-95 % interval
(a unit without a RUL counts as a miss), the share of medians within +-20 % of the truth, and
the 10/50/90 % quantiles of median/true. The figures of docs/prognostics.md ("Laws the bench
does not simulate") come from this script.
"""
import tempfile

import numpy as np

from rul_probe import draw_unit, probe_args, report

THRESHOLD = 0.915        # K_FSJ threshold of `eha-health thresholds`
NU = 0.002               # gamma-process scale: Var K = NU E K
STD = 0.01               # diagnosis standard error

LAWS = {
    "linear": lambda s: s,
    "exponential": lambda s: np.expm1(2.2 * s) / np.expm1(2.2),
    "power2": lambda s: s ** 2,
    "two_phase": lambda s: np.where(s < 0.5, s, 0.5 + 2.5 * (s - 0.5)) / 1.75,
    "cubic": lambda s: s ** 3,
    "sqrt": np.sqrt,
    "log": lambda s: np.log1p(20.0 * s) / np.log1p(20.0),
    "saturating": lambda s: -np.expm1(-3.0 * s) / -np.expm1(-3.0),
    "logistic": lambda s: (1 / (1 + np.exp(-(s - 0.6) / 0.12)) - 1 / (1 + np.exp(5.0)))
                          / (1 / (1 + np.exp(-0.4 / 0.12)) - 1 / (1 + np.exp(5.0))),
    # Paris crack growth da/dN = C a^(m/2), m = 4: a = a0 / (1 - t/t_c), a blow-up in finite time
    # (here 15 % of the life after the threshold crossing); m = 3 gives the square of it
    "paris": lambda s: np.expm1(-np.log1p(-np.minimum(s, 1.1499) / 1.15)) / np.expm1(-np.log1p(-1 / 1.15)),
    "paris2": lambda s: np.expm1(-2 * np.log1p(-np.minimum(s, 1.1499) / 1.15)) / np.expm1(-2 * np.log1p(-1 / 1.15)),
}


def fleet(law: str, units: int, rng: np.random.Generator) -> tuple[list[dict], dict]:
    h = lambda s: LAWS[law](np.clip(s, 0.0, None))    # noqa: E731
    rows, truth = [], {}
    for u in range(units):
        life, onset, t = draw_unit(rng, 60.0)
        dmu = np.diff(THRESHOLD * h((np.concatenate([[t[0]], t]) - onset) / life))
        k = np.cumsum(rng.gamma(np.maximum(dmu, 1e-12) / NU, NU))
        tt, kt = t[-1], k[-1]
        while kt < THRESHOLD and tt < t[-1] + 20 * life:        # the same path, hour by hour
            tt += 1.0
            d = THRESHOLD * (h((tt - onset) / life) - h((tt - 1.0 - onset) / life))
            kt += rng.gamma(max(float(d), 1e-12) / NU, NU)
        truth[f"U{u}"] = tt - t[-1]
        y = np.clip(k + rng.normal(0.0, STD, len(t)), 0.0, 1.5)
        rows += [{"actuator_id": f"U{u}", "time_h": float(ti), "k_gm": 0.01, "k_fsj": float(yi), "k_bkl": 0.01,
                  "std_gm": STD, "std_fsj": STD, "std_bkl": STD} for ti, yi in zip(t, y)]
    return rows, truth


def main() -> None:
    a, laws, settings = probe_args(__doc__, "law", LAWS, units=30, seed=3)
    with tempfile.TemporaryDirectory() as d:
        for law in laws:
            rows, truth = fleet(law, a.units, np.random.default_rng(a.seed))
            report(f"{law:12s}", rows, truth, d, settings)


if __name__ == "__main__":
    main()
