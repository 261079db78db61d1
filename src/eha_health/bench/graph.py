"""``eha-health bench graph``: one full FDI test through the in-process node graph.

Figures, not assertions: wall time, messaging and diagnosis time, message throughput per executor.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from ..physics.faults import Faults
from ..physics.sequence import FDISequence
from ..ros.graph import Graph


def graph(executors=("single", "events"), rate: float = 0.0, progress=None) -> dict:
    """Wall time of one full FDI test through the in-process node graph (command, plant,
    monitor recording to MCAP, diagnosis) and the message throughput, per executor."""

    res = {"rate": rate, "samples_expected": int(round(FDISequence().duration * 1000)), "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for ex in executors:
            if progress:
                progress(f"graph on the {ex} executor ...")
            with Graph(faults=Faults(0.4, 0.6, 0.4), rate=rate, executor=ex,
                       log_path=Path(tmp) / f"{ex}.mcap") as g:
                t0 = time.perf_counter()
                r = g.run_test()
                total = time.perf_counter() - t0
                msgs = sum(g.monitor.received.values())
            d = r["diagnosis"]
            diag = d.wall_time_s if d else float("nan")
            res["runs"][ex] = {"wall_s": total, "diagnosis_s": diag, "messaging_s": total - diag,
                               "messages": msgs, "msgs_per_s": msgs / (total - diag),
                               "samples": len(r["response"]) if r["response"] is not None else 0,
                               "level": r["level"], "message": r["message"]}
    return res


def format_graph(res: dict) -> str:
    lines = [f"One FDI test through the in-process graph (1 kHz, rate {res['rate']:g}: "
             f"{'as fast as possible' if res['rate'] == 0 else 'x real time'})",
             f"{'executor':10s} {'wall [s]':>9s} {'messaging':>10s} {'diagnosis':>10s} {'msgs':>7s} "
             f"{'msg/s':>7s} {'samples':>8s}"]
    for ex, r in res["runs"].items():
        lines.append(f"{ex:10s} {r['wall_s']:9.2f} {r['messaging_s']:10.2f} {r['diagnosis_s']:10.2f} "
                     f"{r['messages']:7d} {r['msgs_per_s']:7.0f} {r['samples']:5d}/{res['samples_expected']}")
    runs = list(res["runs"].values())
    if len(runs) == 2 and runs[1]["messaging_s"] > 0:
        lines.append(f"messaging time ratio {list(res['runs'])[0]}/{list(res['runs'])[1]}: "
                     f"{runs[0]['messaging_s'] / runs[1]['messaging_s']:.2f}")
    return "\n".join(lines)
