"""``eha-health bench loss``: the same FDI test through the in-process graph with a lossy relay
dropping 0 %, 1 % and 5 % of the plant's samples (BEST_EFFORT link, gap fill up to ``max_fill``).

Figures, not assertions: samples dropped and filled, the verdict, and each estimate's largest
difference from the lossless one (target: <= 0.01 at 1 % loss).
"""
from __future__ import annotations

import numpy as np

from ..physics.faults import Faults
from ..ros.graph import Graph


def loss(fractions=(0.0, 0.01, 0.05), max_fill: int = 10, seed: int = 7, faults: Faults = Faults(0.4, 0.6, 0.4),
         progress=None) -> dict:
    rows = []
    for p in fractions:
        if progress:
            progress(f"loss {p:.0%} ...")
        with Graph(faults=faults, log_path="", loss=p, loss_seed=seed, best_effort=True, max_fill=max_fill) as g:
            r = g.run_test()
            dropped = sum(g.relay.dropped.values())
            passed = sum(g.relay.passed.values())
        d = r["diagnosis"]
        rows.append({"loss": p, "dropped": dropped, "messages": dropped + passed, "level": r["level"],
                     "message": r["message"], "k": list(d.faults.as_tuple()) if d else None,
                     "filled": sum((r["response"].meta.get("filled") or {}).values()) if r["response"] else 0})
        if progress:     # the figures so far (a long run stopped early still says them)
            ref = rows[0]["k"]
            diff = np.max(np.abs(np.subtract(rows[-1]["k"], ref))) if rows[-1]["k"] and ref else float("nan")
            progress(f"loss {p:.0%}: dropped {dropped}, filled {rows[-1]['filled']}, K {rows[-1]['k']}, "
                     f"|dK| max {diff:.5f}: {r['level']}: {r['message']}")
    ref = rows[0]["k"]
    for row in rows:
        row["max_diff"] = float(np.max(np.abs(np.subtract(row["k"], ref)))) if row["k"] and ref else None
    return {"max_fill": max_fill, "seed": seed, "truth": list(faults.as_tuple()), "rows": rows}


def format_loss(res: dict) -> str:
    lines = [f"lossy relay, BEST_EFFORT, gap fill up to {res['max_fill']} samples, seed {res['seed']}, "
             f"truth {res['truth']}",
             f"{'loss':>5} {'dropped':>8} {'filled':>7} {'K_GM':>7} {'K_FSJ':>7} {'K_BKL':>7} {'|dK| max':>9}  verdict"]
    for r in res["rows"]:
        k = r["k"] or [float("nan")] * 3
        diff = f"{r['max_diff']:.5f}" if r["max_diff"] is not None else "-"
        lines.append(f"{r['loss']:>5.0%} {r['dropped']:>8} {r['filled']:>7} {k[0]:7.4f} {k[1]:7.4f} {k[2]:7.4f} "
                     f"{diff:>9}  {r['level']}: {r['message']}")
    return "\n".join(lines)
