"""`prognose` on stochastic wear processes and regime changes (a calibration probe).

    python tools/prognose_processes.py [CASE ...] [--units 40] [--seed 5] [--settings YAML]

`tools/prognose_laws.py` varies the mean path's shape, `tools/prognose_noise.py` the diagnosis
error. This probe varies the wear process itself, as an independent black-box probe of
2026-11-29 did: per case, ``--units`` actuators whose K_FSJ follows a latent path on a 1-h grid
from 0 to the threshold 0.915 (life L lognormal, median 1000 h, sd of log 0.3), tests every
``interval`` h from 0 h up to a uniform ``cut`` of the life, each test the latent K plus Gaussian
error of sd ``noise`` (stated as such), clipped to [0, 1.5] as a diagnosis is; K_GM and K_BKL sit
at 0.02 with the same error (they must raise no alarm). The true RUL is the latent path's first
passage. Cases:

  gamma          gamma process, linear mean, Var K = nu E K, nu 0.001-0.006; error 0.005
  gamma_n03      the same, error 0.03
  gamma_t2       gamma process, mean ~ t^2, nu 0.001-0.004
  wiener         Wiener process with drift, volatility 0.005-0.02 K per sqrt(100 h)
  two_stage      gamma (nu 0.001), its rate 4x from a uniform 40-70 % of the life on
  rate_jumps     gamma (nu 0.001), its rate x lognormal(0, 0.4) at Poisson times (mean L / 3)
  healthy_gamma  no wear for 20-50 % of the life, then gamma (nu 0.002); cut at 50-85 %
  healthy_n03    the same, error 0.03
  exp_n03_100h   exponential mean (rate 2-4 per life) with gamma jitter (nu 0.0005), error
                 0.03, a test every 100 h, cut at 50-85 %
  young          healthy_gamma tested every 10 h, cut 60-150 h after the wear began: young wear
                 (another black-box probe of 2026-11-29 found medians 0.36x and false WARNs)
  partial_repair gamma (nu 0.001, linear mean); at a uniform 30-55 % of the life K falls by
                 0.1-0.2 (a partial repair nobody recorded) and wear goes on at its rate; a test
                 every 40 h, cut at 65-90 % of the (later) end of life
  partial_t2     the same on gamma_t2's mean ~ t^2 (nu 0.001)
  pause          gamma (nu 0.001, linear mean), no wear for 20-40 % of the life from a uniform 25-50 %
                 of it, then wear again at the same rate; a test every 40 h (an independent probe,
                 2026-12-07, found late misses just after the wear resumes)
  usage_seasons  gamma (nu 0.001) in the usage, not the hours: the usage rate [usage/h] is
                 lognormal(0, 0.7) per 200-h season about 1; tests every 50 h carry the usage
                 (compare --clock time and --clock usage)
  shocks         random-shock wear: a compound Poisson process, a shock every 40 h on average
                 (1-h Bernoulli), sizes Weibull of shape 0.7, plus a steady drift of 30 % of the
                 mean wear; mean K = 0.915 t / L; a test every 50 h (an independent probe,
                 2026-12-07, found 12.5 % late misses)
  rare_shocks    the same with a shock every 150 h on average (fewer, bigger shocks; same mean)
                 The cut at a fraction of the first passage makes the history's end depend on the
                 failure to come and weights short lives (by 1 / life). One more line says how
                 many units fail before the 5 % quantile of an oracle told each unit's latent K at
                 the cut, its rate and the shock law (its future shocks alone unknown): on seeds
                 1-5, 19 of 200 for shocks and 13 of 200 for rare_shocks, not 10

Prints per case the line of `rul_probe.report` (units given a RUL, coverage of the 5-95 %
interval with a unit without a RUL a miss, medians within +-20 %, median/true quantiles), how
many of them rest on the fleet prior, K_GM / K_BKL given a RUL where any is (a false alarm), and
the false WARNs: P(failure within the next 50 h) >= 5 % where the true RUL exceeds 100 h. For ``two_stage``, two more lines split the coverage by whether the history ends before the rate
change: nothing in such a history shows the change to come. For the partial repairs, one more:
how many say ``unrecorded_repair_h`` within 2 tests of the fall, and how many set tests aside
instead. Where the tests carry a usage, one more: the coverage of ``rul_*_usage`` against the
true usage to failure. docs/prognostics.md ("Wear processes
and regime changes") quotes this script.
"""
import math
import tempfile

import numpy as np

from rul_probe import probe_args, report

THRESHOLD = 0.915        # K_FSJ threshold of `eha-health thresholds`
OTHER_K = 0.02           # K_GM and K_BKL: healthy

# name: (law, error sd, test interval [h], cut: a fraction of the life, or ("after onset", lo, hi) [h])
CASES = {
    "gamma": ("gamma", 0.005, 50.0, (0.3, 0.85)),
    "gamma_n03": ("gamma", 0.03, 50.0, (0.3, 0.85)),
    "gamma_t2": ("gamma_t2", 0.005, 50.0, (0.3, 0.85)),
    "wiener": ("wiener", 0.005, 50.0, (0.3, 0.85)),
    "two_stage": ("two_stage", 0.005, 40.0, (0.3, 0.85)),
    "rate_jumps": ("rate_jumps", 0.005, 40.0, (0.3, 0.85)),
    "healthy_gamma": ("healthy_gamma", 0.005, 50.0, (0.5, 0.85)),
    "healthy_n03": ("healthy_gamma", 0.03, 50.0, (0.5, 0.85)),
    "exp_n03_100h": ("exp", 0.03, 100.0, (0.5, 0.85)),
    "young": ("healthy_gamma", 0.005, 10.0, ("after onset", 60.0, 150.0)),
    "partial_repair": ("partial_repair", 0.005, 40.0, (0.65, 0.9)),
    "partial_t2": ("partial_t2", 0.005, 40.0, (0.65, 0.9)),
    "usage_seasons": ("usage_seasons", 0.005, 50.0, (0.3, 0.85)),
    "pause": ("pause", 0.005, 40.0, (0.3, 0.85)),
    "shocks": ("shocks", 0.005, 50.0, (0.3, 0.85)),
    "rare_shocks": ("rare_shocks", 0.005, 50.0, (0.3, 0.85)),
}
SHOCKS = {"shocks": 40.0, "rare_shocks": 150.0}   # mean time between shocks [h]
SHOCK_SHAPE = 0.7        # Weibull shape of the shock sizes (heavy-tailed below 1)
SHOCK_DRIFT = 0.3        # share of the mean wear that is a steady drift


def _gamma_steps(rng: np.random.Generator, mean_steps: np.ndarray, nu: float) -> np.ndarray:
    """Increments of a gamma process of the given mean increments and Var = nu mean."""
    return rng.gamma(np.maximum(mean_steps, 1e-12) / nu, nu)


def latent_path(law: str, rng: np.random.Generator, life: float):
    """(K on a 1-h grid, first passage of THRESHOLD [h], regime change or partial repair [h] or
    None, usage on the grid or None)."""
    n = int(10 * life) + 10
    t = np.arange(n, dtype=float)
    rate = THRESHOLD / life                                   # K / h of the mean path
    change = drop = usage = None
    if law.startswith("partial"):
        change, drop = rng.uniform(0.3, 0.55) * life, rng.uniform(0.1, 0.2)
        law = "gamma" if law == "partial_repair" else "gamma_t2"
        nu = 0.001
    else:
        nu = None
    if law == "gamma":
        inc = _gamma_steps(rng, np.full(n - 1, rate), nu or rng.uniform(0.001, 0.006))
    elif law == "gamma_t2":
        inc = _gamma_steps(rng, np.diff(THRESHOLD * (t / life) ** 2), nu or rng.uniform(0.001, 0.004))
    elif law == "wiener":
        vol = rng.uniform(0.005, 0.02) / 10.0                 # K per sqrt(h)
        inc = rate + vol * rng.standard_normal(n - 1)
    elif law == "two_stage":
        change = rng.uniform(0.4, 0.7) * life
        r1 = THRESHOLD / (change + 4.0 * (life - change))     # reaches the threshold at L on average
        inc = _gamma_steps(rng, np.where(t[1:] < change, r1, 4.0 * r1), 0.001)
    elif law == "rate_jumps":
        jump = rng.random(n - 1) < 3.0 / life
        factor = np.where(jump, np.exp(rng.normal(0.0, 0.4, n - 1)), 1.0)
        inc = _gamma_steps(rng, rate * np.cumprod(factor), 0.001)
    elif law == "healthy_gamma":
        start = change = rng.uniform(0.2, 0.5) * life
        inc = np.where(t[1:] < start, 0.0, _gamma_steps(rng, np.full(n - 1, THRESHOLD / (life - start)), 0.002))
    elif law == "usage_seasons":
        per_h = np.repeat(np.exp(rng.normal(0.0, 0.7, n // 200 + 1)), 200)[:n - 1]   # usage / h, by season
        usage = np.concatenate([[0.0], np.cumsum(per_h)])
        # gamma wear per unit of usage; its mean reaches the threshold at the usage of hour ``life``
        inc = _gamma_steps(rng, THRESHOLD / usage[int(life)] * per_h, 0.001)
    elif law == "pause":
        p0 = rng.uniform(0.25, 0.5) * life
        change = (p0, p0 + rng.uniform(0.2, 0.4) * life)      # no wear from p0 to the resumption
        inc = np.where((t[1:] > change[0]) & (t[1:] <= change[1]), 0.0, _gamma_steps(rng, np.full(n - 1, rate), 0.001))
    elif law in SHOCKS:
        # compound Poisson shocks (Weibull sizes) plus a steady drift; mean K = rate t
        mean_size = (1.0 - SHOCK_DRIFT) * rate * SHOCKS[law]
        scale = mean_size / math.gamma(1.0 + 1.0 / SHOCK_SHAPE)
        hits = rng.random(n - 1) < 1.0 / SHOCKS[law]
        inc = SHOCK_DRIFT * rate + np.where(hits, scale * rng.weibull(SHOCK_SHAPE, n - 1), 0.0)
    elif law == "exp":
        b = rng.uniform(2.0, 4.0)
        inc = _gamma_steps(rng, np.diff(THRESHOLD * np.expm1(b * t / life) / np.expm1(b)), 0.0005)
    else:
        raise ValueError(law)
    k = np.concatenate([[0.0], np.cumsum(inc)])
    if drop is not None:
        k = np.where(t >= change, np.maximum(k - drop, 0.0), k)
    hit = np.nonzero(k >= THRESHOLD)[0]
    return k, (float(t[hit[0]]) if len(hit) else np.inf), change, usage


def fleet(case: str, units: int, rng: np.random.Generator) -> tuple[list[dict], dict, dict]:
    """HISTORY.csv rows, true RUL [h] and regime change [h] (or None) per unit."""
    law, noise, interval, cut = CASES[case]
    rows, truth, changes = [], {}, {}
    while len(truth) < units:
        life = 1000.0 * np.exp(rng.normal(0.0, 0.3))
        k, eol, change, usage = latent_path(law, rng, life)
        if not np.isfinite(eol):
            continue
        end = change + rng.uniform(*cut[1:]) if cut[0] == "after onset" else rng.uniform(*cut) * eol
        times = np.arange(0.0, min(end, eol - 1.0) + 1e-9, interval)
        if len(times) < 3:
            continue
        u = f"U{len(truth):03d}"
        for ti in times:
            y = np.clip(np.array([OTHER_K, k[int(ti)], OTHER_K]) + rng.normal(0.0, noise, 3), 0.0, 1.5)
            rows.append({"actuator_id": u, "time_h": float(ti), "k_gm": float(y[0]), "k_fsj": float(y[1]),
                         "k_bkl": float(y[2]), "std_gm": noise, "std_fsj": noise, "std_bkl": noise}
                        | ({} if usage is None else {"usage": round(float(usage[int(ti)]), 3)}))
        truth[u] = eol - times[-1]
        changes[u] = (bool(times[-1] < change) if law == "two_stage" else
                      (*change, times[-1]) if law == "pause" else
                      (change, interval) if law.startswith("partial") else
                      (float(k[int(times[-1])]), THRESHOLD / life) if law in SHOCKS else
                      float(usage[int(eol)] - usage[int(times[-1])]) if usage is not None else None)
    return rows, truth, changes


def main() -> None:
    a, cases, settings = probe_args(__doc__, "case", CASES, units=40, seed=5)
    with tempfile.TemporaryDirectory() as d:
        for case in cases:
            rows, truth, before = fleet(case, a.units, np.random.default_rng(a.seed))
            out = report(f"{case:14s}", rows, truth, d, settings)
            got = {u: out[u]["faults"]["fsj"] for u in truth}
            prior = sum(F["fleet_prior"] and F["rul_median_h"] is not None for F in got.values())
            print(f"  on the fleet prior (fewer than 6 points since onset): {prior} of those given a RUL", flush=True)
            false = sum(out[u]["faults"][f]["rul_median_h"] is not None for u in truth for f in ("gm", "bkl"))
            if false:
                print(f"  K_GM / K_BKL (no wear) given a RUL: {false} of {2 * len(truth)}", flush=True)
            far = [u for u in truth if truth[u] > 100.0]      # 2 checks of 50 h away: a WARN is false
            warn = sum((got[u]["p_fail_next"] if got[u]["p_fail_next"] is not None else
                        got[u].get("p_fail_next_min") or 0.0) >= 0.05 for u in far)
            print(f"  false WARN (P(failure within 50 h) >= 5 %, true RUL > 100 h): {warn} of {len(far)}", flush=True)
            if CASES[case][0] == "usage_seasons":
                inside = [got[u]["rul_median_usage"] is not None and
                          (got[u]["rul_p05_usage"] or 0.0) <= before[u] <= (got[u]["rul_p95_usage"] or np.inf)
                          for u in truth]
                close = [got[u]["rul_median_usage"] is not None and abs(got[u]["rul_median_usage"] / before[u] - 1) <= 0.2
                         for u in truth]
                print(f"  usage to failure (rul_*_usage against the true usage): 90 % interval covers "
                      f"{np.mean(inside):4.0%}; median within 20 % {np.mean(close):4.0%}", flush=True)
            elif case.startswith("partial"):
                said = sum(abs((got[u].get("unrecorded_repair_h") or -1e9) - before[u][0]) <= 2 * before[u][1]
                           for u in truth)
                aside = sum(bool(got[u].get("outliers_h")) for u in truth)
                print(f"  the partial repair said (unrecorded_repair_h within 2 tests of it): {said} of {len(truth)}; "
                      f"tests set aside as failed diagnoses: {aside}", flush=True)
            elif CASES[case][0] == "pause":
                groups = {"history ends before the pause": lambda p0, p1, te: te < p0,
                          "history ends in the pause": lambda p0, p1, te: p0 <= te < p1,
                          "ends within 100 h of the resumption": lambda p0, p1, te: p1 <= te < p1 + 100.0,
                          "ends later": lambda p0, p1, te: te >= p1 + 100.0}
                for label, keep in groups.items():
                    _split(label, [u for u in truth if keep(*before[u])], truth, got)
            elif CASES[case][0] in SHOCKS:
                rng = np.random.default_rng(a.seed + 1000)
                o05 = {u: shock_oracle_p05(CASES[case][0], *before[u], rng) for u in truth}
                late = sum(truth[u] < o05[u] for u in truth)
                print(f"  an oracle told each unit's latent K, rate and shock law (its future shocks alone unknown): "
                      f"{late} of {len(truth)} failed before its 5 % quantile", flush=True)
            elif any(v is not None for v in before.values()):
                for label, keep in (("history ends before the change", True), ("history ends after it", False)):
                    _split(label, [u for u in truth if before[u] is keep], truth, got)


def shock_oracle_p05(law: str, k_now: float, rate: float, rng: np.random.Generator, paths: int = 4000) -> float:
    """5 % quantile [h] of the first passage of THRESHOLD from the latent ``k_now`` of a shocks
    case with its mean wear ``rate`` [1/h] known: shocks as a Poisson process (the latent path's
    1-h Bernoulli draws, to within an hour), the drift between them exact."""
    drift, gap = SHOCK_DRIFT * rate, SHOCKS[law]
    scale = (1.0 - SHOCK_DRIFT) * rate * gap / math.gamma(1.0 + 1.0 / SHOCK_SHAPE)
    need = THRESHOLD - k_now
    n = int(need / drift / gap * 1.5) + 50        # more shocks than the drift alone leaves time for
    t = np.cumsum(rng.exponential(gap, (paths, n)), 1)
    c = np.cumsum(scale * rng.weibull(SHOCK_SHAPE, (paths, n)), 1)
    j = np.argmax(drift * t + c >= need, 1)       # the first shock after which K is past the threshold
    rows = np.arange(paths)
    before = np.where(j > 0, c[rows, j - 1], 0.0)
    passage = np.where(drift * t[rows, -1] + c[rows, -1] >= need,
                       np.minimum(t[rows, j], (need - before) / drift), need / drift)
    return float(np.quantile(passage, 0.05))


def _split(label: str, sub: list[str], truth: dict, got: dict) -> None:
    """One line: the coverage and the late misses of the units ``sub``."""
    inside = [(got[u]["rul_p05_h"] or 0.0) <= truth[u] <= (got[u]["rul_p95_h"] or np.inf)
              if got[u]["rul_median_h"] is not None else False for u in sub]
    late = sum(got[u]["rul_p05_h"] is not None and truth[u] < got[u]["rul_p05_h"] for u in sub)
    print(f"  {label}: {len(sub)} units, 90 % interval covers {np.mean(inside) if sub else 0:4.0%}, "
          f"{late} with the true RUL below the 5 % quantile (late)", flush=True)


if __name__ == "__main__":
    main()
