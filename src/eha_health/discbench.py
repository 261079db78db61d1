"""Benchmarks of the discrepancy loop (figures, not assertions).

* :func:`residual_floor` -- the monitor's own residual RMS per channel on clean
  reference runs without any missing effect (its model-form floor; written to
  ``data/discrepancy.yaml`` with ``eha-health bench floor --write``).
* :func:`synthetic` -- the issue's targets on simulated undeclared effects: each
  effect alone and with faults, plus noise-only runs; run ``eha-health bench
  discrepancy``.
"""
from __future__ import annotations

import time

import numpy as np

from .model import simulate
from .params import Faults, ModelParams, load

CHANNELS = ("position", "velocity", "pressure", "current")


def residual_floor(n: int = 12, seed: int = 2024, progress=None) -> dict:
    """Max per-channel diagnosis residual RMS [SI] over ``n`` clean random-fault reference runs."""
    from .identify import diagnose
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        f = Faults(*rng.uniform(0.0, 1.0, 3))
        d = diagnose(simulate(faults=f))
        rows.append([d.rms[c] for c in CHANNELS])
        if progress:
            progress(f"floor: run {i + 1}/{n}")
    r = np.array(rows)
    return {"floor": {c: float(v) for c, v in zip(CHANNELS, r.max(0))}, "runs": n, "seed": seed}


def floor_yaml(res: dict, command: str, thresholds: dict) -> str:
    lines = ["# Decision settings of the discrepancy loop for FDI tests of the shipped monitor model.",
             "# floor: the largest residual RMS per channel [SI] the monitor leaves after a diagnosis of",
             f"#        clean reference runs without any missing effect ({res['runs']} random fault triples,",
             f"#        seed {res['seed']}): its own model-form error. Made by:",
             f"#        {command}", "floor:"]
    lines += [f"  {c}: {v:.4g}" for c, v in res["floor"].items()]
    lines += ["thresholds:"] + [f"  {k}: {v:g}" for k, v in thresholds.items()]
    return "\n".join(lines) + "\n"


#: Undeclared effects of the synthetic bench: (candidate that should be found, how the plant gets it).
EFFECTS: tuple[tuple[str, object], ...] = (
    ("compressibility", lambda p: p.with_effect_names(["compressibility"])),
    ("sensor_delay", lambda p: p.with_effect_names(["sensor_delay"])),
    ("sensor_gain", lambda p: p.with_effects(sensor_calibration={"enabled": True, "gain_error": 0.03})),
    ("stribeck", lambda p: p.with_effect_names(["stribeck"])),
    ("viscous_friction", lambda p: p.updated("jack", viscous=6000.0)),
    ("valve_null_bias", lambda p: p.updated("controller", null_bias=3e-4)),
    ("load_stiffness", lambda p: p.updated("surface", hinge_stiffness=1.6e5)),
    ("leakage", lambda p: p.updated("hydraulics", leakage=5e-12)),
    ("supply_pressure", lambda p: p.updated("hydraulics", supply_pressure=14e6)),
)
FAULT_SETS = (Faults(0.0, 0.0, 0.0), Faults(0.4, 0.5, 0.0), Faults(0.3, 0.4, 0.3))


def synthetic(seed: int = 0, n_noise: int = 6, progress=None, effects=None) -> dict:
    """Run the loop (max one effect) on every effect x fault set and on noise-only runs."""
    from .discrepancy import analyse_fdi_test
    cases = []
    ref = load("reference")
    rng = np.random.default_rng(seed)
    todo = [(name, make, f) for name, make in EFFECTS if effects is None or name in effects for f in FAULT_SETS]
    todo += [(None, (lambda p: p), Faults(*rng.uniform(0.0, 1.0, 3))) for _ in range(n_noise)]
    for i, (name, make, f) in enumerate(todo):
        p: ModelParams = make(ref).with_effect_names(["sensor_noise"])
        r = simulate(params=p, faults=f, seed=seed + 100 + i)
        truth = dict(zip(("k_gm", "k_fsj", "k_bkl"), f.as_tuple()))
        t0 = time.perf_counter()
        rep = analyse_fdi_test(r, max_effects=1, truth=truth)
        cases.append({
            "effect": name, "faults": truth, "selected": rep.selected,
            "ranked_first": rep.candidates[0].name if rep.candidates else None,
            "rms_before": rep.before.rms["position"], "rms_after": rep.after.rms["position"],
            "err_before": max(rep.before.errors.values()), "err_after": max(rep.after.errors.values()),
            "wall_time_s": time.perf_counter() - t0})
        if progress:
            progress(f"case {i + 1}/{len(todo)}: {name or 'noise only'} -> {rep.verdict}")
    eff = [c for c in cases if c["effect"]]
    noise = [c for c in cases if not c["effect"]]
    return {
        "seed": seed, "cases": cases,
        "ranked_first_share": float(np.mean([c["ranked_first"] == c["effect"] for c in eff])) if eff else None,
        "selected_share": float(np.mean([c["selected"][:1] == [c["effect"]] for c in eff])) if eff else None,
        "false_reports_share": float(np.mean([bool(c["selected"]) for c in noise])) if noise else None,
        "max_wall_time_s": float(max(c["wall_time_s"] for c in cases)),
    }


def format_synthetic(res: dict) -> str:
    lines = [f"{'effect':17s} {'faults (gm,fsj,bkl)':20s} {'ranked first':17s} {'selected':17s} "
             f"{'pos RMS um before->after':>25s} {'max|dK| before->after':>22s} {'time s':>7s}"]
    for c in res["cases"]:
        f = ",".join(f"{v:.2f}" for v in c["faults"].values())
        lines.append(f"{c['effect'] or '(noise only)':17s} {f:20s} {c['ranked_first'] or '-':17s} "
                     f"{','.join(c['selected']) or '-':17s} {c['rms_before'] * 1e6:11.2f} -> {c['rms_after'] * 1e6:8.2f}"
                     f"   {c['err_before']:9.4f} -> {c['err_after']:7.4f} {c['wall_time_s']:7.1f}")
    lines.append(f"true effect ranked first: {100 * res['ranked_first_share']:.0f} % (target >= 90 %); "
                 f"selected: {100 * res['selected_share']:.0f} %; false 'missing effect' on noise-only runs: "
                 f"{100 * res['false_reports_share']:.0f} % (target <= 5 %); slowest analysis "
                 f"{res['max_wall_time_s']:.1f} s (target <= 30 s)")
    return "\n".join(lines)
