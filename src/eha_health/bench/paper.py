"""``eha-health bench paper``: our identification against the paper's Tables 1 and 3-6.

Cases: the single-fault cases of Tables 1/3 (each fault alone at 0, 0.4, 0.6,
1.0) and the 16 combined cases of Tables 4/5, simulated on the reference model
(optionally with the default sensor noise), diagnosed by each method, printed
next to the paper's published estimates. Errors: Eq. (2) percent error
``(K - K_est)/K`` (absolute error where K = 0, where Eq. 2 is undefined); Eq. (3)
mean of |% err| over the defined coefficients; the Table 6 summary (largest
|% err| per coefficient, largest mean) next to the paper's rows. scipy's
``differential_evolution`` on the same fitness runs as an independent peer.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution, nnls

from ..identification.diagnose import DEFAULT_METHOD, GUARD_FACTOR, METHODS, diagnose
from ..identification.fitness import make_fitness
from ..identification.knobs import FAULT_KNOBS
from ..identification.problem import KnobModel, Problem
from ..identification.record import fdi_record
from ..physics.faults import FAULT_NAMES, Faults
from ..physics.model import simulate
from ..physics.params import load
from ..physics.sequence import FDISequence
from ..signals.residuals import noise_level

# ---- the paper's published values
PAPER_SINGLE = {  # method -> fault -> [(true, estimated)]  (Tables 1 and 3)
    "deterministic": {"fsj": [(0, .00084), (.4, .40083), (.6, .60081), (1, 1.0008)],
                      "gm": [(0, .02094), (.4, .40269), (.6, .60213), (1, 1.0024)],
                      "bkl": [(0, 0.0), (.4, .39891), (.6, .60365), (1, .99)]},
    "ga": {"fsj": [(0, .00084), (.4, .40094), (.6, .60105), (1, .99)],
           "gm": [(0, .00539), (.4, .40428), (.6, .60373), (1, .99)],
           "bkl": [(0, .00047), (.4, .40415), (.6, .60503), (1, .99)]},
}
COMBINED = [(0, 0, 0), (.4, .4, .4), (.4, .4, .6), (.6, .4, .4), (.4, .6, .4), (.6, .4, .6), (.6, .6, .4),
            (.4, .6, .6), (.6, .6, .6), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1),
            (1, 1, 1)]  # (K_GM, K_FSJ, K_BKL), Tables 4/5
PAPER_COMBINED = {
    "deterministic": [(.02075, .00084, 0), (.40944, .40083, .40612), (.40944, .40075, .60851),
                      (.60775, .40058, .40561), (.413, .60088, .40794), (.60781, .40067, .60719),
                      (.61056, .60061, .40835), (.41306, .60076, .60939), (.61056, .60067, .60811),
                      (1.0023, .00053, .00516), (.07963, 1.0008, .00543), (.02081, .00071, .99),
                      (1.0106, 1.0003, .00701), (1.0024, .00864, .99), (.07956, 1.0008, .99),
                      (1.0106, 1.0, .99)],
    "ga": [(.00531, .00084, .00003), (.41154, .40083, .3983), (.41214, .40076, .59807), (.60985, .40058, .39765),
           (.41546, .60089, .39724), (.60925, .40066, .59761), (.61303, .60062, .39657), (.42636, .60077, .63025),
           (.62888, .60066, .59008), (.99, .00053, .0007), (.04776, .98997, .00192), (.0198, .00041, .925),
           (.99, .99, .01869), (.99, .00001, .99), (.0435, .99, .99), (.99, .99, .99)],
}
PAPER_TABLE6 = {"deterministic": (0.21, 2.5, 2.0, 1.8), "ga": (0.21, 4.0, 1.0, 1.6)}  # FSJ, GM, BKL, mean [%]


def single_cases() -> list[tuple[float, float, float]]:
    out = [(0.0, 0.0, 0.0)]
    for i in range(3):
        for k in (0.4, 0.6, 1.0):
            c = [0.0, 0.0, 0.0]
            c[i] = k
            out.append(tuple(c))
    return out


def pct_errors(true, est):
    """Eq. (2) per coefficient: percent where K != 0, else None (absolute error reported apart)."""
    return [100.0 * (t - e) / t if t != 0 else None for t, e in zip(true, est)]


def mean_pct(true, est):
    """Eq. (3) over the coefficients where Eq. (2) is defined (None if none)."""
    p = [abs(v) for v in pct_errors(true, est) if v is not None]
    return float(np.mean(p)) if p else None


@dataclass
class Row:
    case: tuple
    est: tuple
    std: tuple
    wall_time_s: float
    evaluations: int
    group: str  # single / combined / random
    std_stat: tuple = (np.nan,) * 3     # the Gauss-Newton part of std
    noise_position: float = 0.0         # position noise measured in the run [m]
    fit_cost: float = float("nan")      # stage cost at the estimate (fitness.fdi_stage_residual)
    fit_quality: float = float("nan")   # fit_cost over the model's floor plus the noise's cost
    guard: str = ""                     # the fast method's global guard: passed / fired


def run_de(resp, seed: int, fitness: str = "lsq"):
    """scipy differential_evolution on the same fitness (vectorised over the batch simulator)."""
    seq = FDISequence()
    rec = fdi_record(resp, seq)
    model = KnobModel(load("monitor"), FAULT_KNOBS, rec)
    problem = Problem(model, make_fitness(fitness, rec, seq))
    t0 = time.perf_counter()
    sol = differential_evolution(lambda X: problem.costs(np.asarray(X).T), list(zip(model.lower, model.upper)), seed=seed,
                                 vectorized=True, updating="deferred", tol=1e-8, atol=0, maxiter=200,
                                 popsize=15, polish=False)
    return tuple(sol.x), time.perf_counter() - t0, model.runs


def run_bench(methods=METHODS, fitness: str = "lsq", noise: bool = False,
              n_random: int = 0, seed: int = 0, de: bool = True, progress=None) -> dict:
    """Run every case with every method; returns a JSON-able dict of rows and summaries."""
    params = load("reference")
    if noise:
        params = params.with_effects(sensor_noise={"enabled": True})
    rng = np.random.default_rng(seed)
    cases = [(c, "single") for c in single_cases()] + [(c, "combined") for c in COMBINED]
    cases += [(tuple(np.round(rng.uniform(0, 1, 3), 4)), "random") for _ in range(n_random)]
    responses = {}
    for i, (c, _) in enumerate(cases):
        if c not in responses:
            responses[c] = simulate("reference", Faults(*c), params=params, seed=(seed * 1000 + i) if noise else None)
    out = {"fitness": fitness, "noise": noise, "seed": seed, "methods": {}}
    for m in methods:
        rows = []
        for c, group in cases:
            d = diagnose(responses[c], method=m, fitness=fitness, seed=seed)
            rows.append(Row(c, d.faults.as_tuple(), tuple(d.std[k] for k in FAULT_NAMES),
                            d.wall_time_s, d.evaluations, group,
                            tuple(d.std_stat[k] for k in FAULT_NAMES),
                            noise_level(responses[c].position), d.fit_cost, d.fit_quality, d.guard))
            if progress:
                progress(f"{m:13s} {group:8s} true {c} -> est ({rows[-1].est[0]:.4f}, {rows[-1].est[1]:.4f}, "
                         f"{rows[-1].est[2]:.4f})  {d.wall_time_s:.2f} s")
        out["methods"][m] = summarise(rows)
    if de:
        rows = []
        for c, group in cases:
            est, wt, n = run_de(responses[c], seed, fitness)
            rows.append(Row(c, est, (np.nan,) * 3, wt, n, group))
            if progress:
                progress(f"{'scipy-DE':13s} {group:8s} true {c} -> est ({est[0]:.4f}, {est[1]:.4f}, {est[2]:.4f})  {wt:.2f} s")
        out["methods"]["scipy_de"] = summarise(rows)
    return out


def summarise(rows: list[Row]) -> dict:
    recs = []
    for r in rows:
        err = np.array(r.est) - np.array(r.case)
        within = [abs(e) <= 2 * s if np.isfinite(s) and s > 0 else None for e, s in zip(err, r.std)]
        recs.append({"group": r.group, "true": list(r.case), "est": [float(v) for v in r.est],
                     "std": [float(v) for v in r.std], "std_stat": [float(v) for v in r.std_stat],
                     "noise_position": float(r.noise_position), "pct_err": pct_errors(r.case, r.est),
                     "abs_err": [float(v) for v in err], "mean_pct_err": mean_pct(r.case, r.est),
                     "within_2sd": within, "wall_time_s": r.wall_time_s, "evaluations": r.evaluations,
                     "fit_cost": float(r.fit_cost), "fit_quality": float(r.fit_quality), "guard": r.guard})

    def table6(groups):
        sel = [x for x in recs if x["group"] in groups]
        if not sel:
            return None
        mx = []
        for i in range(3):
            v = [abs(x["pct_err"][i]) for x in sel if x["pct_err"][i] is not None]
            mx.append(max(v) if v else None)
        means = [x["mean_pct_err"] for x in sel if x["mean_pct_err"] is not None]
        # order as the paper's Table 6: FSJ, GM, BKL, mean
        return {"fsj_pct": mx[1], "gm_pct": mx[0], "bkl_pct": mx[2], "mean_pct": max(means) if means else None,
                "max_abs_err": float(max(max(abs(e) for e in x["abs_err"]) for x in sel))}

    cov = [w for x in recs for w in x["within_2sd"] if w is not None]
    cov_random = [w for x in recs if x["group"] == "random" for w in x["within_2sd"] if w is not None]
    return {"rows": recs,
            "table6_paper_cases": table6(("single", "combined")),
            "table6_random": table6(("random",)),
            "max_abs_err_all": float(max(max(abs(e) for e in x["abs_err"]) for x in recs)),
            "coverage_2sd": (float(np.mean(cov)) if cov else None),
            "coverage_2sd_random": (float(np.mean(cov_random)) if cov_random else None),
            "wall_time_s_mean": float(np.mean([x["wall_time_s"] for x in recs])),
            "wall_time_s_max": float(np.max([x["wall_time_s"] for x in recs])),
            "evaluations_mean": float(np.mean([x["evaluations"] for x in recs])),
            "guard_fired": int(sum(x["guard"] == "fired" for x in recs)),
            "guard_probed": int(sum(x["guard"] == "probed" for x in recs)),
            "guard_judged": int(sum(x["guard"] in ("passed", "probed", "fired") for x in recs)),
            "fit_quality_max": float(np.nanmax([x["fit_quality"] for x in recs]))
            if np.isfinite([x["fit_quality"] for x in recs]).any() else None,
            "combined_table_wall_s": float(sum(x["wall_time_s"] for x in recs if x["group"] == "combined"))}


def _f(v, fmt="{:.4f}"):
    return "-" if v is None else fmt.format(v)


def _pct_cells(t: dict, fmt: str) -> list[str]:
    """Table 6 cells in the paper's order: FSJ, GM, BKL, mean [%]."""
    return [_f(t[k], fmt) for k in ("fsj_pct", "gm_pct", "bkl_pct", "mean_pct")]


def format_markdown(res: dict, command: str) -> str:
    L = [f"Generated by `{command}` (fitness `{res['fitness']}`, noise {'on' if res['noise'] else 'off'}, "
         f"seed {res['seed']}).", ""]
    methods = res["methods"]
    L.append("### Table 6 - largest errors over the paper's single and combined cases")
    L.append("")
    L.append("| method | K_FSJ % err | K_GM % err | K_BKL % err | mean % err | max abs err | mean time [s] | max time [s] | sims/diagnosis |")
    L.append("|---|---|---|---|---|---|---|---|---|")
    for m, s in methods.items():
        t = s["table6_paper_cases"]
        L.append(f"| {m} | {' | '.join(_pct_cells(t, '{:.3f}'))} | {t['max_abs_err']:.4f} | "
                 f"{s['wall_time_s_mean']:.2f} | {s['wall_time_s_max']:.2f} | {s['evaluations_mean']:.0f} |")
        if m in PAPER_TABLE6:
            p = PAPER_TABLE6[m]
            L.append(f"| paper {m} | < {p[0]} | < {p[1]} | < {p[2]} | < {p[3]} | | | | |")
    if any(s["table6_random"] for s in methods.values()):
        L += ["", "### Random cases", "", "| method | K_FSJ % err | K_GM % err | K_BKL % err | mean % err | max abs err | within 2 sd |",
              "|---|---|---|---|---|---|---|"]
        for m, s in methods.items():
            t = s["table6_random"]
            if t:
                cov = s["coverage_2sd_random"]
                L.append(f"| {m} | {' | '.join(_pct_cells(t, '{:.3f}'))} | {t['max_abs_err']:.4f} | "
                         f"{_f(cov, '{:.0%}')} |")
    if peer_ratio(res):
        L += ["", peer_ratio(res) + "."]
    if guard_line(res):
        L += ["", guard_line(res) + "."]
    for m, s in methods.items():
        L += ["", f"### {m}: every case (true -> estimated; Eq. 2 % error, absolute where K = 0)", "",
              "| group | K_GM | K_FSJ | K_BKL | est K_GM | est K_FSJ | est K_BKL | % err GM / FSJ / BKL | mean % | time [s] |",
              "|---|---|---|---|---|---|---|---|---|---|"]
        for x in s["rows"]:
            pe = " / ".join(_f(p, "{:+.3f}") if p is not None else f"abs {a:+.4f}" for p, a in zip(x["pct_err"], x["abs_err"]))
            L.append(f"| {x['group']} | {x['true'][0]:g} | {x['true'][1]:g} | {x['true'][2]:g} | {x['est'][0]:.5f} | "
                     f"{x['est'][1]:.5f} | {x['est'][2]:.5f} | {pe} | {_f(x['mean_pct_err'], '{:.3f}')} | {x['wall_time_s']:.2f} |")
        if m in PAPER_SINGLE:
            L += ["", f"Paper's single-fault estimates for {m} (Table {'1' if m == 'deterministic' else '3'}): " +
                  "; ".join(f"K_{f.upper()} {t:g} -> {e:g}" for f, rows in PAPER_SINGLE[m].items() for t, e in rows)]
        if m in PAPER_COMBINED:
            L += ["", f"Paper's combined-case estimates for {m} (Table {'4' if m == 'deterministic' else '5'}): " +
                  "; ".join(f"{c} -> {e}" for c, e in zip(COMBINED, PAPER_COMBINED[m]))]
    return "\n".join(L) + "\n"


def peer_ratio(res: dict) -> str:
    """The peer ratio line (scipy DE / the default method, time and max abs error), or ''."""
    methods = res["methods"]
    if "scipy_de" not in methods or DEFAULT_METHOD not in methods:
        return ""
    a, b = methods[DEFAULT_METHOD], methods["scipy_de"]
    return (f"Peer ratio (scipy differential_evolution / {DEFAULT_METHOD}, same cases, one run): mean wall time "
            f"{b['wall_time_s_mean'] / a['wall_time_s_mean']:.1f}x, max abs error "
            f"{b['max_abs_err_all'] / max(a['max_abs_err_all'], 1e-12):.2f}x (DE {b['max_abs_err_all']:.4f}, "
            f"{DEFAULT_METHOD} {a['max_abs_err_all']:.4f})")


def guard_line(res: dict) -> str:
    """How often the fast method's global guard fired, and the largest fit quality seen, or ''."""
    out = []
    for m, s in res["methods"].items():
        if s.get("guard_judged"):
            q = s["fit_quality_max"]
            out.append(f"{m}: global guard fired in {s['guard_fired']} of {s['guard_judged']} diagnoses, "
                       f"passed after the local probe in {s.get('guard_probed', 0)} "
                       f"(largest fit quality {_f(q, '{:.2f}')}, limit {GUARD_FACTOR:g})")
    return "; ".join(out)


def format_text(res: dict) -> str:
    L = [f"bench paper: fitness {res['fitness']}, noise {'on' if res['noise'] else 'off'}, seed {res['seed']}",
         f"{'method':14s} {'FSJ %':>8s} {'GM %':>8s} {'BKL %':>8s} {'mean %':>8s} {'max|err|':>9s} {'t mean':>7s} {'t max':>7s} {'sims':>6s}"]
    for m, s in res["methods"].items():
        t = s["table6_paper_cases"]
        L.append(f"{m:14s} {' '.join(_pct_cells(t, '{:8.3f}'))} {t['max_abs_err']:9.4f} "
                 f"{s['wall_time_s_mean']:7.2f} {s['wall_time_s_max']:7.2f} {s['evaluations_mean']:6.0f}")
        if m in PAPER_TABLE6:
            p = PAPER_TABLE6[m]
            L.append(f"{'  paper':14s} {'<' + str(p[0]):>8s} {'<' + str(p[1]):>8s} {'<' + str(p[2]):>8s} {'<' + str(p[3]):>8s}")
        if s["table6_random"]:
            r = s["table6_random"]
            L.append(f"{'  random':14s} {' '.join(_pct_cells(r, '{:8.3f}'))} {r['max_abs_err']:9.4f}  "
                     f"within 2 sd: {_f(s['coverage_2sd_random'], '{:.0%}')} (all cases {_f(s['coverage_2sd'], '{:.0%}')})")
    for line in (peer_ratio(res), guard_line(res)):
        if line:
            L.append(line)
    return "\n".join(L)


def model_error_yaml(res: dict, method: str, command: str, previous: dict | None = None) -> str:
    """data/model_error.yaml text with ``method``'s block re-made from a bench of it; the rest kept
    from ``previous``. The default method's block is the file's top level, any other's sits under
    ``methods: {name: ...}`` (:func:`~eha_health.identification.uncertainty.model_error`).

    Clean bench: ``model_error_sd``, the RMS error per coefficient (all of it model mismatch and
    where the search stops), ``model_error_variance`` (NNLS of the squared errors on 1 and the
    estimates) and, for the default method, ``fit_floor``. Noisy bench: ``noise_error_sd``, the RMS
    error left after the model-form and Gauss-Newton parts, sqrt(mean(err^2) - model_sd^2 -
    mean(sd_stat^2)), at the mean measured position noise ``noise_reference_m``, and
    ``noise_error_variance``: the same excess per run (scaled to that noise) by NNLS on the estimates.
    """
    names = FAULT_NAMES
    data = dict(previous or {})
    methods = dict(data.pop("methods", None) or {})
    block = data if method == DEFAULT_METHOD else dict(methods.get(method) or {})
    rows = res["methods"][method]["rows"]
    e2 = np.array([r["abs_err"] for r in rows]) ** 2          # squared error per run and coefficient
    err2 = e2.mean(axis=0)
    est = np.clip(np.array([r["est"] for r in rows]), 0.0, None)
    design = np.column_stack([np.ones(len(rows)), est])     # 1, K_GM, K_FSJ, K_BKL of each run
    if res.get("noise"):
        if "model_error_sd" not in block:
            raise ValueError(f"measure {method}'s model-form error first (a clean bench), then the noise part")
        if "model_error_variance" in block:
            c = np.array([[float(v) for v in block["model_error_variance"][n]] for n in names])
            model2_run = design @ c.T
        else:
            model2_run = np.broadcast_to(np.array([float(block["model_error_sd"][n]) for n in names]) ** 2, e2.shape)
        stat2_run = np.array([r["std_stat"] for r in rows]) ** 2
        noise = np.array([r["noise_position"] for r in rows])
        ref = float(np.mean(noise))
        excess = e2 - model2_run - stat2_run
        block["noise_error_sd"] = dict(zip(names, np.sqrt(np.maximum(excess.mean(axis=0), 0.0))))
        scaled = excess / np.maximum(noise / ref, 1e-9)[:, None] ** 2    # to the reference noise
        block["noise_error_variance"] = {n: list(nnls(design, scaled[:, i])[0]) for i, n in enumerate(names)}
        block["noise_reference_m"] = ref
        block["noise_error_command"] = f"{command}  ({len(rows)} noisy runs, {method}, fitness {res['fitness']})"
    else:
        block["model_error_sd"] = dict(zip(names, np.sqrt(err2)))
        block["model_error_variance"] = {n: list(nnls(design, e2[:, i])[0]) for i, n in enumerate(names)}
        block["model_error_command"] = f"{command}  ({len(rows)} clean runs, {method}, fitness {res['fitness']})"
        costs = [r["fit_cost"] for r in rows if np.isfinite(r["fit_cost"])]
        if costs and method == DEFAULT_METHOD:
            block["fit_floor"] = float(max(costs))
    if method != DEFAULT_METHOD:
        methods[method] = block
    lines = ["# Error terms added in quadrature to the Gauss-Newton standard error of every diagnosis",
             "# (identification.uncertainty: model_error, noise_error), 1 sd per fault coefficient, measured",
             "# per identification method: the top level is the default method's (fast); methods: holds the",
             "# others' (their whole-test cost is a saw-tooth in K_BKL, so where they stop is part of the error).",
             "# model_error_sd: the monitor's model-form error, the RMS identification error on clean",
             "#   reference runs (no noise: all of it is model mismatch); model_error_variance: how it",
             "#   grows with the damage on the same runs (used when the estimate is known).",
             "# noise_error_sd: what sensor noise adds beyond the Gauss-Newton term (it moves the",
             "#   stick-slip and backlash events): the RMS error on noisy runs less the other two parts,",
             "#   at position noise noise_reference_m [m]; scaled by the noise measured in each run;",
             "#   noise_error_variance: how that excess grows with the damage (the same runs).",
             "# fit_floor: the largest stage cost (fitness.fdi_stage_residual) a diagnosis left on the same",
             "#   clean runs: the model's floor, against which the fast method's global guard judges a fit.",
             "# Each block was made by the command beside it (eha-health bench paper ... --write-model-error)."]
    lines += _error_lines(data, "")
    if methods:
        lines.append("methods:")
        for m in sorted(methods):
            lines.append(f"  {m}:")
            lines += _error_lines(methods[m], "    ")
    return "\n".join(lines) + "\n"


def _error_lines(block: dict, ind: str) -> list[str]:
    """YAML lines of one method's error terms (``ind``: its indentation)."""
    names = FAULT_NAMES
    lines = []

    def variance(key: str, what: str) -> None:
        if key in block:
            lines.append(f"{ind}# the same runs: {what} = c0 + c1 K_GM + c2 K_FSJ + c3 K_BKL (estimates), NNLS")
            lines.append(f"{ind}{key}:")
            lines.extend(f"{ind}  {n}: [" + ", ".join(f"{float(v):.4g}" for v in block[key][n]) + "]" for n in names)

    for part in ("model_error", "noise_error"):
        if f"{part}_sd" not in block:
            continue
        lines.append(f"{ind}{part}_command: \"{block[f'{part}_command']}\"")
        if part == "noise_error":
            lines.append(f"{ind}noise_reference_m: {float(block['noise_reference_m']):.4g}")
        lines.append(f"{ind}{part}_sd:")
        lines.extend(f"{ind}  {n}: {float(block[f'{part}_sd'][n]):.6f}" for n in names)
        if part == "model_error" and block.get("fit_floor"):
            lines.append(f"{ind}fit_floor: {float(block['fit_floor']):.4g}")
        variance(f"{part}_variance", "var" if part == "model_error" else "excess var at noise_reference_m")
    return lines
