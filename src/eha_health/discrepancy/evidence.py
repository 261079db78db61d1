"""The evidence for one candidate effect: projection on its signature, then a held-out refit.

* *projection* (:func:`projection_share`): the share of the fit residual that the
  candidate's output sensitivity explains beyond what the base knobs already can,
  ``1 - |P_[J S]^perp r|^2 / |P_J^perp r|^2`` (J: base-knob Jacobian, S: the candidate's
  signature, r: weighted residual, all at the current fit);
* *refit* (:func:`evaluate`): base knobs and the candidate's parameters fitted together on
  the fit part (a grid scan of the candidate's first knob, then bounded least squares from
  the best distinct grid points), judged on the held-out part by an information criterion
  ``dIC = n_eff ln(RSS_aug / RSS_base) + k ln(n_fit)``, n_eff the held-out sample count
  deflated by the residual autocorrelation.

Every candidate of a round is judged against the same :class:`Round`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..identification.knobs import Knob
from ..identification.local import least_squares
from ..identification.problem import KnobModel, Problem
from ..identification.residual import Residual
from ..identification.result import FitResult
from ..identification.uncertainty import autocorr_inflation
from .candidates import Candidate
from .report import CandidateEvidence
from .settings import Settings


@dataclass
class Round:
    """What the candidates of one round are judged against: the model as it stands and its fit on
    the fit part (``base``), the residuals of the split record and the held-out reference figures."""
    number: int
    model: KnobModel
    base: FitResult
    r_fit: Residual
    r_held: Residual
    out_base: np.ndarray          # the base model fitted on the fit part, over the whole record
    settings: Settings
    held_noise: Callable[[list[str]], float]   # held-out power noise and floor leave, model with effects
    selected: tuple[str, ...] = ()

    def __post_init__(self):
        r = self.r_held(self.out_base)
        self.rss_held_base = float(r @ r)
        self.n_eff = n_eff(self.r_held, r)
        self.n_fit = n_eff(self.r_fit, self.base.residual)

    def passes(self, ev: CandidateEvidence, structured: bool) -> bool:
        """The gates of a selection: structured residual, dIC < 0, held-out excess and fit power down."""
        st = self.settings
        return (structured and ev.delta_ic < 0 and ev.held_out_excess_ratio <= st.held_out_ratio
                and ev.fit_ratio <= st.fit_ratio)


@dataclass
class Result:
    """A candidate's evidence, its augmented model and the refit."""
    evidence: CandidateEvidence
    model: KnobModel
    fit: FitResult


def n_eff(res: Residual, r: np.ndarray) -> float:
    """Effective sample count of the residual ``r`` (its length over the autocorrelation inflation)."""
    return len(r) / autocorr_inflation(r, len(res.channels))


def knob_grid(k: Knob, n: int) -> np.ndarray:
    """Scan values of a knob: log-spaced over a wide positive range, else linear."""
    if k.lo >= 0 and k.hi > 0:
        a = max(k.lo, abs(k.typical) / 50.0)
        if k.hi / a > 20:
            return np.unique(np.concatenate([[k.lo], np.geomspace(a, k.hi, n - 1)]))
    return np.linspace(k.lo, k.hi, n)


def candidate_grid(anchor: np.ndarray, cand: Candidate, n: int) -> np.ndarray:
    """Rows ``anchor + candidate knobs``: the first knob over :func:`knob_grid`, any further knob off."""
    g = knob_grid(cand.knobs[0], n)
    G = np.repeat(np.concatenate([anchor, [k.off for k in cand.knobs]])[None], len(g), axis=0)
    G[:, len(anchor)] = g
    return G


def projection_share(J: np.ndarray, S: np.ndarray, r: np.ndarray) -> float:
    """Share of r, beyond the span of J, that the columns S explain (least squares)."""
    def resid(A):
        if A.shape[1] == 0:
            return r
        coef, *_ = np.linalg.lstsq(A, r, rcond=None)
        return r - A @ coef
    r0 = resid(J)
    e0 = float(r0 @ r0)
    if e0 <= 0:
        return 0.0
    r1 = resid(np.column_stack([J, S]))
    return float(max(0.0, 1.0 - float(r1 @ r1) / e0))


def _signature(rnd: Round, mc: KnobModel, cand: Candidate) -> np.ndarray:
    """Change of the fit residual per unit of each knob, from off to its typical value."""
    nb = len(rnd.base.x)
    x_off = np.concatenate([rnd.base.x, [k.off for k in cand.knobs]])
    X = np.repeat(x_off[None], len(cand.knobs), axis=0)
    for j, k in enumerate(cand.knobs):
        X[j, nb + j] = k.typical
    return np.column_stack([(rnd.r_fit(o) - rnd.base.residual) / (k.typical - k.off)
                            for o, k in zip(mc.run(X), cand.knobs)])


def _refit(rnd: Round, mc: KnobModel, cand: Candidate, anchors: list[np.ndarray]) -> FitResult:
    """Grid scan of the first knob (any further knob absent) with the base knobs held at each anchor
    (the current fit, and the whole-record fit: on a split record the base knobs may have absorbed
    the effect differently), then local fits from the best distinct points; the best fit."""
    st = rnd.settings
    G = np.vstack([candidate_grid(a, cand, st.grid) for a in anchors])
    costs = np.array([rnd.r_fit.cost(o) for o in mc.run(G)])
    starts: list[np.ndarray] = []
    for i in np.argsort(costs):
        if all(np.max(np.abs(G[i] - s0) / np.maximum(mc.upper - mc.lower, 1e-300)) > 0.02 for s0 in starts):
            starts.append(G[i])
        if len(starts) == st.starts:
            break
    problem = Problem(mc, rnd.r_fit)
    return min((least_squares(problem, s0, max_nfev=st.max_nfev) for s0 in starts), key=lambda f: f.cost)


def evaluate(rnd: Round, cand: Candidate, anchors: list[np.ndarray]) -> Result:
    """Attribution evidence of one candidate against the round's base fit."""
    mc = rnd.model.extended(cand.knobs)
    nb = len(rnd.base.x)
    share = projection_share(rnd.base.jacobian, _signature(rnd, mc, cand), rnd.base.residual)
    best = _refit(rnd, mc, cand, anchors)
    rss_held = rnd.r_held.cost(mc.run(best.x)[0])
    ratio_h = rss_held / rnd.rss_held_base if rnd.rss_held_base > 0 else 1.0
    # what is above noise and floor on the held-out part: where the base is already there, the
    # effect must keep it there (ratio 0), else it must remove a share of the excess
    noise = rnd.held_noise(list(rnd.selected) + [cand.name])
    excess = max(rss_held - noise, 0.0) / max(rnd.rss_held_base - noise, 1e-3 * rnd.rss_held_base, 1e-300)
    k = len(cand.knobs)
    dic = rnd.n_eff * float(np.log(max(ratio_h, 1e-300))) + k * float(np.log(rnd.n_fit))
    sd = best.std(autocorr_inflation(best.residual, len(rnd.r_fit.channels)))
    ev = CandidateEvidence(
        name=cand.name, mechanism=cand.mechanism, round=rnd.number, projection=share,
        fit_ratio=best.cost / rnd.base.cost if rnd.base.cost > 0 else 1.0, held_out_ratio=ratio_h,
        held_out_excess_ratio=excess, delta_ic=dic,
        parameters={kn.name: float(best.x[nb + j]) for j, kn in enumerate(cand.knobs)},
        std={kn.name: sd.get(kn.name, float("nan")) for kn in cand.knobs},
        units={kn.name: kn.unit for kn in cand.knobs})
    return Result(ev, mc, best)


def rank(result: Result) -> tuple:
    """Sort key: a refit that does not lower its own fit residual (fit ratio >= 1) last, then by the
    held-out information criterion. Such a refit cannot claim the held-out gain, which is then luck
    of a coloured residual: the two kinds of evidence must agree."""
    ev = result.evidence
    return ev.fit_ratio >= 1.0, ev.delta_ic


def rediagnosed(model: KnobModel, x: np.ndarray, n_base: int, rediagnose) -> tuple[np.ndarray, int]:
    """``x`` with its base knobs identified globally with the model at ``x`` (effects included).

    Returns the new knob vector and the model runs the identification took.
    """
    xb, spent = rediagnose(model.params_at(x)[0])
    alt = np.array(x, float)
    alt[:n_base] = np.clip(xb, model.lower[:n_base], model.upper[:n_base])
    return alt, spent


def retry_from_rediagnosis(rnd: Round, results: list[Result], candidates, before: FitResult, rediagnose,
                           say) -> tuple[list[Result], int]:
    """Round-1 candidates evaluated again from the base knobs re-identified with each in the model.

    Only a candidate whose re-identified model (its first knob at its typical value, any other
    absent) lowers the fit-part residual power to the fit gate is evaluated again (the others
    cannot pass); its new evidence replaces the old when it ranks better. Returns the results
    (unsorted) and the model runs spent.
    """
    by_name = {c.name: c for c in candidates}
    nb = len(rnd.base.x)
    out, runs = [], 0
    for res in results:
        cand = by_name[res.evidence.name]
        say(f"round 1: {cand.name} -- base re-identified with it in the model")
        probe = [k.typical if j == 0 else k.off for j, k in enumerate(cand.knobs)]
        x, spent = rediagnosed(res.model, np.concatenate([rnd.base.x, probe]), nb, rediagnose)
        runs += spent + 1
        if rnd.r_fit.cost(res.model.run(x)[0]) > rnd.settings.fit_ratio * rnd.base.cost:
            out.append(res)
            continue
        new = evaluate(rnd, cand, [rnd.base.x, before.x, x[:nb]])
        runs += new.model.runs
        out.append(new if rank(new) < rank(res) else res)
    return out, runs


def rescan(model: KnobModel, residual: Residual, start: FitResult, n_base: int,
           factors=np.geomspace(0.6, 1.6, 17)) -> np.ndarray:
    """Before the final fit: each effect knob scanned over x0.6-1.6 of its value, the others held.

    The candidate was sized on the fit part from a coarse grid; on the whole record the cost in an
    effect parameter can have several local minima (measured: oil compliance, 0.81 /GPa local
    against 1.04 global for a true 1.0, the pressure residual jumping with stick-slip events in
    between), and a local fit stays in the first one. One batch per knob; keeps ``start.x`` if nothing
    scanned is better.
    """
    x = np.asarray(start.x, float).copy()
    best = residual.cost(start.output)
    for i in range(n_base, len(x)):
        if x[i] == 0.0:
            continue
        X = np.repeat(x[None], len(factors), axis=0)
        X[:, i] = np.clip(x[i] * factors, model.lower[i], model.upper[i])
        costs = np.array([residual.cost(o) for o in model.run(X)])
        j = int(np.argmin(costs))
        if costs[j] < best:
            x, best = X[j].copy(), float(costs[j])
    return x
