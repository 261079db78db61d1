"""`prognose` on histories with diagnosis errors of other kinds (a robustness probe).

    python tools/prognose_noise.py [KIND ...] [--laws linear,exponential,power2,sqrt] [--units 30]
                                   [--seed 11] [--settings YAML]

`eha-health bench rul` diagnoses every test for real, and its diagnoses are accurate (errors of
about 0.001). A user's history may carry worse: larger or understated errors, no std columns,
heavy tails, failed diagnoses. Per law and error kind, ``--units`` actuators whose K follows a
deterministic mean path thr h((t - t_on) / L) (the K_FSJ threshold 0.915, L lognormal, median
1000 h, sd of log 0.3; onset after 5-25 % of L; a test every 50 h (``--interval-h``); the history cut at a uniform
40-80 % of L), plus the error; the true RUL is where the mean path reaches the threshold.
``--laws flat``: K stays at 0.05 (no wear); what it prints is the false alarms. ``--interval-h``:
hours between tests (dense histories); ``--cut LO,HI``: where the histories end (young fleets).

Error kinds (sd 0.01 and stated as such unless said):
  white        Gaussian
  white_big    Gaussian, sd 0.03 (stated)
  understated  Gaussian, sd 0.02, stated 0.005
  nostd        Gaussian, sd 0.015, no std columns (the importer estimates them)
  outliers     Gaussian, and 8 % of the tests off by 0.1-0.3 either way (failed diagnoses)
  hetero       Gaussian, sd 0.003 + 0.03 K, no std columns
  t3           Student t with 3 degrees of freedom, scale 0.01
  precise      Gaussian, sd 0.001 (stated): the deterministic path nearly bare

Prints per kind and law: the units given a RUL, the coverage of the 5-95 % interval (a unit
without a RUL counts as a miss), the share of medians within +-20 % of the truth and the 10/50/90 %
quantiles of median/true. docs/prognostics.md ("Diagnosis errors the bench does not make") quotes it.
"""
import argparse
import tempfile

import numpy as np

from rul_probe import draw_unit, probe_args, report

THRESHOLD = 0.915
LAWS = {"linear": lambda s: s, "exponential": lambda s: np.expm1(2.2 * s) / np.expm1(2.2),
        "power2": lambda s: s ** 2, "sqrt": np.sqrt,
        "flat": lambda s: 0.0 * s}    # no wear (K stays at FLAT_K): any RUL is a false alarm
DEFAULT_LAWS = ("linear", "exponential", "power2", "sqrt")
FLAT_K = 0.05
KINDS = ("white", "white_big", "understated", "nostd", "outliers", "hetero", "t3", "precise")


def error(kind: str, mu: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float | None]:
    """(error added to K, stated standard error or None for no std columns)."""
    n = len(mu)
    if kind == "white":
        return rng.normal(0, 0.01, n), 0.01
    if kind == "white_big":
        return rng.normal(0, 0.03, n), 0.03
    if kind == "understated":
        return rng.normal(0, 0.02, n), 0.005
    if kind == "nostd":
        return rng.normal(0, 0.015, n), None
    if kind == "outliers":
        e = rng.normal(0, 0.01, n)
        bad = rng.random(n) < 0.08
        e[bad] += rng.choice([-1, 1], bad.sum()) * rng.uniform(0.1, 0.3, bad.sum())
        return e, 0.01
    if kind == "hetero":
        return rng.normal(0, 1, n) * (0.003 + 0.03 * mu), None
    if kind == "t3":
        return 0.01 * rng.standard_t(3, n), 0.01
    if kind == "precise":
        return rng.normal(0, 0.001, n), 0.001
    raise ValueError(kind)


def fleet(law: str, kind: str, units: int, rng: np.random.Generator, interval_h: float = 50.0,
          cut=(0.4, 0.8)) -> tuple[list[dict], dict]:
    h = lambda s: LAWS[law](np.clip(s, 0.0, None))    # noqa: E731
    rows, truth = [], {}
    for u in range(units):
        life, onset, t = draw_unit(rng, interval_h, cut)
        mu = THRESHOLD * h((t - onset) / life) + (FLAT_K if law == "flat" else 0.0)
        e, stated = error(kind, mu, rng)
        truth[f"U{u}"] = np.inf if law == "flat" else onset + life - t[-1]
        for ti, yi in zip(t, np.clip(mu + e, 0.0, 1.5)):
            r = {"actuator_id": f"U{u}", "time_h": float(ti), "k_gm": 0.01, "k_fsj": float(yi), "k_bkl": 0.01}
            if stated is not None:
                r.update({"std_gm": stated, "std_fsj": stated, "std_bkl": stated})
            rows.append(r)
    return rows, truth


def _law_list(text: str) -> list[str]:
    """``--laws``: a comma-separated list of known laws (argparse says which is not)."""
    laws = text.split(",")
    unknown = sorted(set(laws) - set(LAWS))
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown law(s): {', '.join(unknown)}; known: {', '.join(LAWS)}")
    return laws


def _noise_options(ap) -> None:
    ap.add_argument("--laws", type=_law_list, default=list(DEFAULT_LAWS), help="of: " + ", ".join(LAWS))
    ap.add_argument("--interval-h", type=float, default=50.0, help="hours between tests (default 50)")
    ap.add_argument("--cut", default="0.4,0.8", help="LO,HI: the history ends at a uniform LO-HI of the life "
                                                     "after onset (default 0.4,0.8)")


def main() -> None:
    a, kinds, settings = probe_args(__doc__, "kind", KINDS, units=30, seed=11, extra=_noise_options)
    laws = a.laws
    with tempfile.TemporaryDirectory() as d:
        for kind in kinds:
            for law in laws:
                rows, truth = fleet(law, kind, a.units, np.random.default_rng(a.seed), a.interval_h,
                                    tuple(float(x) for x in a.cut.split(",")))
                report(f"{kind:12s} {law:12s}", rows, truth, d, settings)


if __name__ == "__main__":
    main()
