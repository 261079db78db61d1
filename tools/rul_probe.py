"""Shared by the prognosis probes (prognose_laws.py, prognose_noise.py): run `prognose` on a
synthetic K_FSJ history and print one line of how its RULs compare with the truth."""
import argparse
import csv
from pathlib import Path

import numpy as np

from eha_health.prognostics import prognose
from eha_health.prognostics.config import load_settings


def probe_args(doc: str, what: str, names, units: int, seed: int, extra=None):
    """The probes' command line: positional ``what`` (of ``names``; default all), ``--units``,
    ``--seed``, ``--settings``, ``--clock`` and whatever ``extra(parser)`` adds. Returns (args, chosen names,
    settings or None); an unknown name is an argparse error."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", metavar=what.upper(), help="of: " + ", ".join(names) + " (default: all)")
    ap.add_argument("--units", type=int, default=units)
    ap.add_argument("--seed", type=int, default=seed)
    ap.add_argument("--settings", help="prognostics settings YAML merged over data/prognostics.yaml")
    ap.add_argument("--clock", choices=("time", "usage"), help="prognosis.clock (default: the settings')")
    if extra is not None:
        extra(ap)
    a = ap.parse_args()
    unknown = set(a.names) - set(names)
    if unknown:
        ap.error(f"unknown {what}(s) {', '.join(sorted(unknown))}; known: {', '.join(names)}")
    over = {"prognosis": {"clock": a.clock}} if a.clock else None
    return a, a.names or list(names), (load_settings(a.settings, over) if a.settings or over else None)


def draw_unit(rng: np.random.Generator, interval_h: float, cut=(0.4, 0.8)) -> tuple[float, float, np.ndarray]:
    """(life L [h], onset [h], test times [h]) of one probe unit: L lognormal (median 1000 h, sd of
    log 0.3), onset after a uniform 5-25 % of L, a test every ``interval_h`` up to a uniform
    ``cut`` (40-80 %) of L after the onset."""
    life = 1000.0 * np.exp(rng.normal(0.0, 0.3))
    onset = rng.uniform(0.05, 0.25) * life
    return life, onset, np.arange(0.0, onset + rng.uniform(*cut) * life, interval_h)


def report(label: str, rows: list[dict], truth: dict[str, float], workdir: str | Path, settings=None) -> dict:
    """Write ``rows`` as a HISTORY.csv, prognose it and print: units given a RUL, coverage of the
    5-95 % interval (no RUL = a miss; "late": the failure before the 5 % quantile), medians within +-20 % of ``truth`` [h], median/true
    quantiles. Returns prognose's ``actuators`` object."""
    path = Path(workdir) / "history.csv"
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    out = prognose(path, settings=settings)["actuators"]
    got = [(out[u]["faults"]["fsj"], r) for u, r in truth.items()]
    if all(np.isinf(r) for _, r in got):        # no wear: every RUL given is a false alarm
        false = [F for F, _ in got if F["rul_p05_h"] is not None]
        warn = sum((F["p_fail_next"] if F["p_fail_next"] is not None else F.get("p_fail_next_min", 0.0)) >= 0.05
                   for F in false)
        low = min((F["rul_p05_h"] for F in false), default=None)
        print(f"{label} no wear: RUL given {len(false):2d}/{len(got)} (false alarms); P(failure before the "
              f"next check) >= 5 % {warn:2d}/{len(got)}; lowest p05 {'-' if low is None else f'{low:.0f} h'}", flush=True)
        return out
    given = [(F, r) for F, r in got if F["rul_median_h"] is not None]
    inside = sum((F["rul_p05_h"] or 0.0) <= r <= (F["rul_p95_h"] if F["rul_p95_h"] is not None else np.inf)
                 for F, r in given)
    late = sum(r < (F["rul_p05_h"] or 0.0) for F, r in given)       # the unsafe side: failure before the 5 % quantile
    close = sum(abs(F["rul_median_h"] - r) <= 0.2 * r for F, r in given)
    q = np.percentile([F["rul_median_h"] / r for F, r in given], [10, 50, 90]) if given else [np.nan] * 3
    print(f"{label} RUL given {len(given):2d}/{len(got)}; 90 % interval covers {inside / len(got):4.0%} "
          f"(late {late:2d}); "
          f"median within 20 % {close / len(got):4.0%}; median/true 10/50/90 % {q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f}",
          flush=True)
    return out
