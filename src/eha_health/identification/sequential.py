"""The paper's deterministic method (Sec. V.A): one knob at a time, each on its own objective.

Stages run in order, each with the knobs already found: a Nelder-Mead search (fminsearch)
or a bounded scalar search (fmincon, for a knob that cannot be negative) of one knob on
one objective of the model output. The paper's order is K_FSJ -> K_GM -> K_BKL
(:func:`~.fitness.fdi_stages`): friction shapes the loop's error signal, so it comes first;
backlash acts like friction, so it comes last, when the others are known.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from .fitness import Stage
from .problem import Problem
from .result import FitResult

#: Stopping tolerance of each one-knob search [knob units].
XATOL = 1e-4


def sequential(problem: Problem, x0, stages: tuple[Stage, ...], history: list | None = None,
               progress=None) -> FitResult:
    """Run ``stages`` from ``x0``; returns the knob vector after the last (cost: its objective)."""
    t0 = time.perf_counter()
    m = problem.model
    runs0 = m.runs
    x = problem.clip(x0)
    cost = float("nan")
    for st in stages:
        knob, lo, hi = m.knobs[st.knob], m.lower[st.knob], m.upper[st.knob]
        ms = m.until(st.until)      # a stage's runs stop where its objective stops reading

        def f(v, st=st, ms=ms):
            xi = x.copy()
            xi[st.knob] = float(np.clip(np.ravel(v)[0], lo, hi))
            c = st.objective(ms.run(xi)[0])
            if history is not None:
                history.append(c)
            return c
        if st.bounded:
            sol = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": XATOL})
            v = sol.x
        else:
            # start at least half a typical magnitude in: a search started at 0 cannot leave it
            s = max(x[st.knob], abs(knob.typical) / 2)
            sol = minimize(f, [s], method="Nelder-Mead",
                           options={"xatol": XATOL, "fatol": 1e-12, "initial_simplex": [[s], [s + abs(knob.typical)]]})
            v = sol.x[0]
        x[st.knob] = float(np.clip(v, lo, hi))
        cost = float(sol.fun)
        if progress:
            progress(f"deterministic: {st.label} -> {x[st.knob]:.4f}")
    return FitResult(x, m.names, problem.free, cost, m.runs - runs0, time.perf_counter() - t0,
                     history=list(history) if history is not None else [])
