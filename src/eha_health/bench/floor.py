"""``eha-health bench floor``: the monitor's own residual floor, written to ``data/discrepancy.yaml``.

* :func:`residual_floor` -- the monitor's residual RMS per channel on clean reference runs
  without any missing effect (its model-form floor).
* :func:`effect_floor` -- the same for the monitor that already holds the right effect (the
  floor of the loop's next round once it is added).
"""
from __future__ import annotations

import numpy as np

from ..discrepancy.candidates import BY_NAME
from ..discrepancy.evidence import candidate_grid
from ..discrepancy.loop import start_diagnosis
from ..identification.knobs import FAULT_KNOBS
from ..identification.local import least_squares
from ..identification.problem import KnobModel, Problem
from ..identification.record import Record
from ..identification.residual import Residual
from ..physics.faults import Faults
from ..physics.model import simulate
from ..physics.params import load
from ..signals.channels import MEASURED
from .discrepancy import EFFECTS, recording_alterations, reference_run


def residual_floor(n: int = 12, seed: int = 2024, progress=None) -> dict:
    """Max per-channel residual RMS [SI] of the loop's starting diagnosis
    (:func:`~eha_health.discrepancy.loop.start_diagnosis`) over ``n`` clean random-fault reference runs."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        f = Faults(*rng.uniform(0.0, 1.0, 3))
        d = start_diagnosis(simulate(faults=f))
        rows.append([d.rms[c] for c in MEASURED])
        if progress:
            progress(f"floor: run {i + 1}/{n}")
    r = np.array(rows)
    return {"floor": {c: float(v) for c, v in zip(MEASURED, r.max(0))}, "runs": n, "seed": seed}


def effect_floor(n: int = 6, seed: int = 2025, progress=None) -> dict:
    """Max per-channel residual RMS [SI] of the monitor that already holds the right effect.

    For every effect of :data:`EFFECTS` (in the plant) and every recording alteration of
    :func:`~.discrepancy.recording_alterations` (on the record after the test): ``n`` clean
    reference runs (random faults) with the effect, the monitor augmented with that candidate,
    faults and effect knobs fitted (the knob from a grid scan, the faults from the truth: the best
    this model class can do). What is left is the augmented model's own model-form error, the floor
    of the loop's next round. A recording effect can leave more than the base floor too: a time
    base 0.5 % fast, undone by resampling, leaves 2.0x it on the current and 1.3x on velocity, and
    before the recording alterations were measured here a second round ran on that form error
    (the three time-base cases of `bench discrepancy`, 1150-1380 model runs more each).
    """
    rng = np.random.default_rng(seed)
    ref, mon = load("reference"), load("monitor")
    # in-loop effects first, in the order and with the random faults they had before the recording
    # alterations were added (their floors are unchanged)
    cases = [(name, make, None) for name, make in EFFECTS] + \
        [(name, None, alter) for name, alter in recording_alterations()]
    out = {}
    for e, (name, make, alter) in enumerate(cases):
        cand = BY_NAME[name]
        rows = []
        for i in range(n):
            f = Faults(*rng.uniform(0.0, 1.0, 3))
            rec = Record.from_response(reference_run(f, None, make, alter, ref))
            model = KnobModel(mon, FAULT_KNOBS + cand.knobs, rec)
            res = Residual(rec)
            G = candidate_grid(np.array(f.as_tuple()), cand, 48)
            x0 = G[int(np.argmin([res.cost(o) for o in model.run(G)]))]
            rms = res.rms(least_squares(Problem(model, res), x0, max_nfev=40).output)
            rows.append([rms[c] for c in MEASURED])
            if progress:
                progress(f"effect floor: {name} ({e + 1}/{len(cases)}), run {i + 1}/{n}")
        out[name] = {c: float(v) for c, v in zip(MEASURED, np.max(rows, axis=0))}
    return {"effect_floor": out, "runs": n, "seed": seed}


def floor_yaml(res: dict, command: str, thresholds: dict, effects: dict | None = None) -> str:
    lines = ["# Decision settings of the discrepancy loop for FDI tests of the shipped monitor model.",
             "# floor: the largest residual RMS per channel [SI] the monitor leaves after a diagnosis of",
             f"#        clean reference runs without any missing effect ({res['runs']} random fault triples,",
             f"#        seed {res['seed']}): its own model-form error. Made by:",
             f"#        {command}", "floor:"]
    lines += [f"  {c}: {v:.4g}" for c, v in res["floor"].items()]
    if effects:
        lines += [f"# effect_floor: the same for the monitor that holds the right effect ({effects['runs']} clean runs",
                  f"#        per effect, seed {effects['seed']}): the floor of the next round once it is added.",
                  "effect_floor:"]
        lines += [f"  {e}: {{" + ", ".join(f"{c}: {v:.4g}" for c, v in chans.items()) + "}"
                  for e, chans in effects["effect_floor"].items()]
    lines += ["thresholds:"] + [f"  {k}: {v:g}" for k, v in thresholds.items()]
    return "\n".join(lines) + "\n"


