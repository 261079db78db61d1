"""``eha-health bench guard``: how often the fast method's global guard fires, and whether it lets
a wrong basin through.

Random fault triples (clean reference runs) diagnosed by the default method from random start
points in [0, FAULT_UPPER]^3 instead of the signature tables' start: a far start is how the fast
path lands in a wrong basin. Per case: whether the guard fired (or passed after the local probe,
:func:`~eha_health.identification.diagnose.probe`), the final error, the runs. A miss
is a final error above ``tolerance`` with the guard passed.
"""
from __future__ import annotations

import numpy as np

from ..identification.diagnose import DEFAULT_METHOD, diagnose
from ..physics.faults import FAULT_UPPER, Faults
from ..physics.model import simulate


def guard_bench(n: int = 12, seed: int = 3, tolerance: float = 0.01, progress=None) -> dict:
    """Run ``n`` cases (seeded); returns the rows and the counts."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n):
        case = tuple(float(v) for v in np.round(rng.uniform(0, 1, 3), 4))
        start = Faults(*(float(v) for v in np.round(rng.uniform(0, FAULT_UPPER, 3), 3)))
        d = diagnose(simulate("reference", Faults(*case)), start=start)
        err = float(np.max(np.abs(np.array(d.faults.as_tuple()) - case)))
        rows.append({"true": case, "start": list(start.as_tuple()), "est": list(d.faults.as_tuple()),
                     "max_abs_err": err, "guard": d.guard, "fit_quality": d.fit_quality,
                     "evaluations": d.evaluations, "wall_time_s": d.wall_time_s})
        if progress:
            progress(f"true {case} start {start.as_tuple()} -> err {err:.4f}, guard {d.guard}, "
                     f"{d.evaluations} runs")
    fired = [r for r in rows if r["guard"] == "fired"]
    return {"method": DEFAULT_METHOD, "seed": seed, "cases": n, "tolerance": tolerance, "rows": rows,
            "fired": len(fired), "probed": sum(r["guard"] == "probed" for r in rows), "missed": sum(r["max_abs_err"] > tolerance and r["guard"] != "fired" for r in rows),
            "max_abs_err": max(r["max_abs_err"] for r in rows),
            "runs_mean_passed": float(np.mean([r["evaluations"] for r in rows if r["guard"] != "fired"] or [np.nan])),
            "runs_mean_fired": float(np.mean([r["evaluations"] for r in fired] or [np.nan]))}


def format_guard(res: dict) -> str:
    return (f"bench guard ({res['method']}, {res['cases']} random cases from random starts, seed {res['seed']}): "
            f"guard fired {res['fired']} times, passed after the local probe {res.get('probed', 0)}, wrong basins let through {res['missed']} "
            f"(final error > {res['tolerance']}); largest final error {res['max_abs_err']:.4f}; runs: "
            f"{res['runs_mean_passed']:.0f} mean when it passed, {res['runs_mean_fired']:.0f} when it fired")
