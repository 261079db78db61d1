"""The evidence for one candidate effect: cheap screening, then (for the best few) a held-out refit.

* *screen* (:func:`screen`): the candidate's signature, projection share, a coarse scan of its
  first knob and the linearised fit, in one batch of runs (a recording effect's scan: one run);
  :func:`sparse_order` regresses the residual on every candidate's signature at once;
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

from ..identification.concurrency import concurrently
from ..identification.knobs import Knob
from ..identification.local import least_squares
from ..identification.problem import KnobModel, Problem
from ..identification.residual import Residual
from ..identification.result import FitResult
from ..identification.uncertainty import autocorr_inflation
from ..signals.frequency import ResponseError
from ..signals.kinematics import Kinematics
from .candidates import IN_LOOP, RECORDING_CHAIN, Candidate, overlapping
from .report import CandidateEvidence
from .settings import Settings


#: Gates of a round run on the frequency-response evidence (see :meth:`Round.passes`).
FREQUENCY = "frequency"


@dataclass
class Round:
    """What the candidates of one round are judged against: the model as it stands and its fit on
    the fit part (``base``), the residuals of the split record and the held-out reference figures.

    ``structured`` says which gates the round's selection uses: True, the time-domain residual is
    structured; :data:`FREQUENCY`, it is within noise but the held-out frequency response is not
    (``frequency``: the held-out position/command :class:`~..signals.frequency.ResponseError` of
    an output, given for broadband records)."""
    number: int
    model: KnobModel
    base: FitResult
    r_fit: Residual
    r_held: Residual
    out_base: np.ndarray          # the base model fitted on the fit part, over the whole record
    settings: Settings
    held_noise: Callable[[list[str]], float]   # held-out power noise and floor leave, model with effects
    selected: tuple[str, ...] = ()
    structured: bool | str = True
    frequency: Callable[[np.ndarray], ResponseError] | None = None
    kinematics: Kinematics | None = None   # the recorded velocity against the recorded position's derivative
    frequency_base: ResponseError | None = None   # ``frequency`` of ``out_base`` (computed when not given)

    def __post_init__(self):
        r = self.r_held(self.out_base)
        self.rss_held_base = float(r @ r)
        self.n_eff = n_eff(self.r_held, r)
        self.n_fit = n_eff(self.r_fit, self.base.residual)
        if self.frequency_base is None and self.frequency is not None:
            self.frequency_base = self.frequency(self.out_base)
        self.kinematic_base = self.kinematics.identity_mismatch if self.kinematics is not None else None

    def passes(self, ev: CandidateEvidence, structured: bool | str) -> bool:
        """The gates of a selection. Time-domain structure: dIC < 0, held-out excess over noise and
        floor and fit power down to their ratios. Frequency-response structure only (the time-domain
        residual within noise, which then fails the power ratios whatever the model: measured on the
        MTS rig, 25 um of logger interference under a 27 um excess): dIC < 0, the refit lowers its
        own fit residual, and the held-out response error power drops to the held-out ratio."""
        st = self.settings
        if structured and self.kinematic_pass(ev):
            return True
        if structured == FREQUENCY:
            return (ev.delta_ic < 0 and ev.fit_ratio < 1.0 and ev.frequency_ratio is not None
                    and ev.frequency_ratio <= st.held_out_ratio)
        return (bool(structured) and ev.delta_ic < 0 and ev.held_out_excess_ratio <= st.held_out_ratio
                and ev.fit_ratio <= st.fit_ratio)

    def kinematic_pass(self, ev: CandidateEvidence) -> bool:
        """The gates of a velocity recording effect on the kinematic evidence: the two recordings
        disagree (:attr:`~..signals.kinematics.Kinematics.significant`), the effect at its fitted
        size removes the disagreement down to the held-out ratio, and its refit lowers the model
        residual too (dIC < 0, own fit down). The velocity weighs 0.05 in the model residual, so a
        +3 % velocity scale fails the residual gates (measured: held-out excess x1.0, the other
        channels' form error dominating) while its kinematic mismatch is 300x the noise's."""
        return (ev.kinematic_ratio is not None and self.kinematics.significant and ev.refit
                and ev.kinematic_ratio <= self.settings.held_out_ratio and ev.delta_ic < 0 and ev.fit_ratio < 1.0)


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


def _refit(rnd: Round, mc: KnobModel, cand: Candidate, anchors: list[np.ndarray], sc: "Screen | None" = None) -> FitResult:
    """Grid scan of the first knob (any further knob absent) with the base knobs held at each anchor
    (the current fit, and the whole-record fit: on a split record the base knobs may have absorbed
    the effect differently), then local fits from the best distinct points; the best fit. With the
    candidate's screen ``sc``, its scanned points stand for the scan at the current fit, and the
    other anchors get a scan of the screen's size (a recording effect: the full grid, free)."""
    st = rnd.settings
    n = st.grid if sc is None or cand.kind == RECORDING_CHAIN else st.scan
    scans = anchors if sc is None else [a for a in anchors if not np.array_equal(a, rnd.base.x)]
    G = np.vstack([candidate_grid(a, cand, n) for a in scans]) if scans else np.zeros((0, len(mc.knobs)))
    # the scan and the fits read the fit part only: their runs stop at its end (the model is causal;
    # a recording candidate acts on the whole recorded output, so its model runs whole: KnobModel.until)
    fit_part = mc.until(rnd.r_fit.horizon)
    costs = rnd.r_fit.costs(fit_part.run(G)) if len(G) else np.zeros(0)
    if sc is not None:
        G, costs = np.vstack([G, sc.rows]), np.concatenate([costs, sc.costs])
    # a round on frequency evidence: the fit part's cost is mostly noise, and a candidate that trades
    # with the base knobs (a loop delay against the valve's time constant) is only reached from the
    # linearised fit, where they have moved together; it is the first start
    starts: list[np.ndarray] = [sc.x_lin] if sc is not None and rnd.structured == FREQUENCY else []
    for i in np.argsort(costs):
        if all(np.max(np.abs(G[i] - s0) / np.maximum(mc.upper - mc.lower, 1e-300)) > 0.02 for s0 in starts):
            starts.append(G[i])
        if len(starts) >= st.starts + (rnd.structured == FREQUENCY):
            break
    problem = Problem(fit_part, rnd.r_fit)
    # the fits from distinct starts are independent: one thread each (a trial point is one run, on
    # one core; a refit alone -- an overlap, a retry -- left the other core idle). Each fit and the
    # choice between them are what they were in sequence.
    fits = concurrently(lambda s0: least_squares(problem, s0, max_nfev=st.max_nfev), starts)
    best = min(fits, key=lambda f: f.cost)
    return _healthy_corners(problem, best, st.max_nfev)


def _healthy_corners(problem: Problem, f: FitResult, max_nfev: int) -> FitResult:
    """``f``, or a local fit from ``f`` with one fault coefficient set to 0, where that coefficient is
    within its typical magnitude (:attr:`Knob.typical`) of 0 and the point costs less than ``f``.

    The monitor's cost has local minima in a fault coefficient near 0 (backlash: its contact
    events), and a local fit started from a biased diagnosis can stop in one short of 0: measured,
    a 40 % slower spool with faults 0 -- the valve candidate's fit stopped at K_BKL 0.028 with
    fit-part cost 0.033, while K_BKL = 0 cost 0.0056, and its held-out prediction lost the ranking
    to the supply sag. Farther from 0 a cheaper corner is another basin, not a local dip,
    and the fit part alone does not choose basins: a pressure offset's refit with a 1 ms loop delay
    still missing cost x0.99 at K_BKL 0.27 -> 0 (x0.94 refitted), and predicted the held-out part
    worse (x0.80 against x0.21). One run per coefficient checked."""
    mc = problem.model
    faults = [j for j in problem.free
              if mc.knobs[j].fault is not None and mc.knobs[j].off < f.x[j] <= mc.knobs[j].off + mc.knobs[j].typical]
    if not faults:
        return f
    X = np.repeat(f.x[None], len(faults), axis=0)
    for i, j in enumerate(faults):
        X[i, j] = mc.knobs[j].off
    costs = problem.costs(X)
    i = int(np.argmin(costs))
    # a local fit never ends worse than its start
    return least_squares(problem, X[i], max_nfev=max_nfev) if costs[i] < f.cost else f


@dataclass
class Screen:
    """Cheap evidence of one candidate: its signature, the linearised size and a coarse scan.

    ``x`` is the best point screened (base knobs + candidate knobs), ``out`` its output over
    the whole record; ``signature`` the change of the fit residual per unit of each knob.
    """
    candidate: Candidate
    model: KnobModel
    signature: np.ndarray
    projection: float
    x: np.ndarray
    out: np.ndarray
    fit_cost: float
    rows: np.ndarray          # every point screened
    costs: np.ndarray         # their fit-part costs
    x_lin: np.ndarray | None = None          # the linearised fit (base and candidate knobs)
    frequency_ratio: float | None = None     # held-out response error power there, with / without it


def screen(rnd: Round, cand: Candidate, n_scan: int) -> Screen:
    """Signature, projection share and a coarse scan of one candidate: one batch of runs.

    The rows are: each knob at its typical value (the signature), the first knob over
    :func:`knob_grid` (``n_scan`` points; a recording effect's whole grid, which shares one
    simulation), then the linearised fit -- base and candidate knobs from least squares of the
    fit residual on ``[J S]`` -- in a second batch of one row, and, where their linearisation
    promises a better fit, the best row with the base knobs re-solved (:func:`_base_resolved`).
    """
    mc = rnd.model.extended(cand.knobs)
    nb, nk = len(rnd.base.x), len(cand.knobs)
    x_off = np.concatenate([rnd.base.x, [k.off for k in cand.knobs]])
    X = np.repeat(x_off[None], nk, axis=0)
    for j, k in enumerate(cand.knobs):
        X[j, nb + j] = k.typical
    G = candidate_grid(rnd.base.x, cand, rnd.settings.grid if cand.kind == RECORDING_CHAIN else n_scan)
    outs = mc.run(np.vstack([X, G]))
    scanned, R = rnd.r_fit.costs_and_residuals(outs)
    r0 = rnd.base.residual
    S = np.column_stack([(R[j] - r0) / (k.typical - k.off) for j, k in enumerate(cand.knobs)])
    J = rnd.base.jacobian
    A = np.column_stack([J, S])
    coef, *_ = np.linalg.lstsq(A, -r0, rcond=None)
    x_lin = x_off.copy()
    x_lin[rnd.base.free] += coef[:J.shape[1]]
    x_lin[nb:] += coef[J.shape[1]:]
    x_lin = np.clip(x_lin, mc.lower, mc.upper)
    out_lin = mc.run(x_lin)[0]
    rows = np.vstack([X, G, x_lin[None]])
    allouts = np.concatenate([outs, out_lin[None]])
    costs = np.append(scanned, rnd.r_fit.costs(out_lin[None]))
    # (an in-loop effect only: a recording effect's 48-row grid was most of the re-solving's time, and
    # on the bench -- every case, re-solved for every candidate -- it changed no recording case)
    x_vp, predicted = _base_resolved(rnd, np.vstack([X, G]), R, J, nb) if cand.kind == IN_LOOP else (None, np.inf)
    i = int(np.argmin(costs))
    x_best, out_best, c_best = rows[i], allouts[i], float(costs[i])
    if predicted < VP_GAIN * c_best:
        # (one row at a time: a single run takes the serial kernel, two would wake the parallel one)
        x_vp = np.clip(x_vp, mc.lower, mc.upper)
        out_vp = mc.run(x_vp)[0]
        c_vp = rnd.r_fit.cost(out_vp)
        # the screened evidence only, not a start of the full refit: from a linearised point on a
        # noise-free record the local fit stopped short of the grid's start (measured: the committed
        # sensor-delay bag, delay's dIC -516 for -1913, and flow asymmetry selected in round 2 for
        # what round 1 had left, then dropped by the final fit)
        if c_vp < c_best:
            x_best, out_best, c_best = x_vp, out_vp, c_vp
    return Screen(cand, mc, S, projection_share(J, S, r0), x_best, out_best, c_best, rows, costs,
                  x_lin, _frequency_ratio(rnd, out_lin))


#: A screen simulates its best row with the base knobs re-solved only when their linearisation
#: predicts a fit-part cost below this share of the best it has seen (else the run is spent for nothing).
VP_GAIN = 0.9


def _base_resolved(rnd: Round, rows: np.ndarray, R: np.ndarray, J: np.ndarray, nb: int) -> tuple[np.ndarray, float]:
    """The screened row that is best once the base knobs are re-solved on their linearisation, with
    them re-solved, and its predicted fit-part cost (variable projection: the residual of every row
    with the span of ``J`` taken out costs no run). An effect the base knobs absorbed is reached
    only with them moved back (measured: a supply at 14 MPa with no fault, diagnosed K_GM 0.11; the
    scan at the base's K_GM saw x0.88 of its fit, and three new candidates pushed it out of the refits).
    ``R``: the fit residual of every row."""
    Q, _ = np.linalg.qr(J)
    P = R - (R @ Q) @ Q.T
    left = np.einsum("ij,ij->i", P, P)
    i = int(np.argmin(left))
    dx, *_ = np.linalg.lstsq(J, -R[i], rcond=None)
    x = rows[i].copy()
    x[:nb][rnd.base.free] += dx
    return x, float(left[i])


def sparse_order(J: np.ndarray, screens: list[Screen], r: np.ndarray, terms: int = 3) -> list[str]:
    """Greedy sparse regression of the fit residual on every candidate's signature (orthogonal
    matching pursuit, SINDy's idea of a few active terms out of a library): the candidates in
    the order they enter, beyond the span of the base knobs' Jacobian ``J``."""
    def reduce(A, v):
        if A.shape[1] == 0:
            return v
        c, *_ = np.linalg.lstsq(A, v, rcond=None)
        return v - A @ c
    chosen: list[int] = []
    base = J
    for _ in range(min(terms, len(screens))):
        rr = reduce(base, r)
        best, gain = None, 0.0
        for i, sc in enumerate(screens):
            if i in chosen:
                continue
            Sp = np.column_stack([reduce(base, s) for s in sc.signature.T])
            rest = reduce(Sp, rr)
            g = float(rr @ rr - rest @ rest)
            if g > gain:
                best, gain = i, g
        if best is None:
            break
        chosen.append(best)
        base = np.column_stack([base, screens[best].signature])
    return [screens[i].candidate.name for i in chosen]


def _judge(rnd: Round, cand: Candidate, mc: KnobModel, x: np.ndarray, out: np.ndarray, fit_cost: float,
           share: float, std: dict, refit: bool, pruned_by: str = "") -> CandidateEvidence:
    """The evidence record of a candidate at its fitted point ``x`` (output ``out``)."""
    nb = len(rnd.base.x)
    rss_held = rnd.r_held.cost(out)
    ratio_h = rss_held / rnd.rss_held_base if rnd.rss_held_base > 0 else 1.0
    # what is above noise and floor on the held-out part: where the base is already there, the
    # effect must keep it there (ratio 0), else it must remove a share of the excess
    noise = rnd.held_noise(list(rnd.selected) + [cand.name])
    excess = max(rss_held - noise, 0.0) / max(rnd.rss_held_base - noise, 1e-3 * rnd.rss_held_base, 1e-300)
    k = len(cand.knobs)
    dic = rnd.n_eff * float(np.log(max(ratio_h, 1e-300))) + k * float(np.log(rnd.n_fit))
    return CandidateEvidence(
        name=cand.name, mechanism=cand.mechanism, round=rnd.number, projection=share,
        fit_ratio=fit_cost / rnd.base.cost if rnd.base.cost > 0 else 1.0, held_out_ratio=ratio_h,
        held_out_excess_ratio=excess, delta_ic=dic,
        parameters={kn.name: float(x[nb + j]) for j, kn in enumerate(cand.knobs)},
        std={kn.name: std.get(kn.name, float("nan")) for kn in cand.knobs},
        units={kn.name: kn.unit for kn in cand.knobs}, kind=cand.kind, channel=cand.channel, refit=refit,
        pruned_by=pruned_by, frequency_ratio=_frequency_ratio(rnd, out),
        kinematic_ratio=_kinematic_ratio(rnd, cand, x[nb:]))


def _kinematic_ratio(rnd: Round, cand: Candidate, values: np.ndarray) -> float | None:
    """Kinematic mismatch with / without a velocity recording effect (None: not one, or no evidence)."""
    if rnd.kinematics is None or cand.kind != RECORDING_CHAIN or cand.channel != "velocity":
        return None
    return rnd.kinematics.mismatch(cand.knobs[0].output.kind, float(values[0])) / max(rnd.kinematic_base, 1e-300)


def _frequency_ratio(rnd: Round, out: np.ndarray) -> float | None:
    """Held-out response error power with / without the candidate (None: no frequency evidence)."""
    if rnd.frequency_base is None or rnd.frequency_base.power <= 0.0:
        return None
    return rnd.frequency(out).power / rnd.frequency_base.power


def screened(rnd: Round, sc: Screen, reason: str) -> Result:
    """Evidence of a candidate pruned after screening (no refit): judged at its best screened point."""
    ev = _judge(rnd, sc.candidate, sc.model, sc.x, sc.out, sc.fit_cost, sc.projection, {}, False, reason)
    fit = FitResult(sc.x, sc.model.names, np.arange(len(sc.x)), sc.fit_cost, 0, output=sc.out)
    return Result(ev, sc.model, fit)


def evaluate(rnd: Round, cand: Candidate, anchors: list[np.ndarray], sc: Screen | None = None) -> Result:
    """Attribution evidence of one candidate against the round's base fit (a full refit)."""
    mc = sc.model if sc is not None else rnd.model.extended(cand.knobs)
    share = sc.projection if sc is not None else \
        projection_share(rnd.base.jacobian, _signature(rnd, mc, cand), rnd.base.residual)
    best = _refit(rnd, mc, cand, anchors, sc)
    out = mc.run(best.x)[0]
    best.output = out           # (the refit's own runs stopped at the fit part's end)
    sd = best.std(autocorr_inflation(best.residual, len(rnd.r_fit.channels)))
    return Result(_judge(rnd, cand, mc, best.x, out, best.cost, share, sd, True), mc, best)


def rank(result: Result) -> tuple:
    """Sort key: a refit that does not lower its own fit residual (fit ratio >= 1) last, then by the
    held-out information criterion. Such a refit cannot claim the held-out gain, which is then luck
    of a coloured residual: the two kinds of evidence must agree."""
    ev = result.evidence
    return ev.fit_ratio >= 1.0, ev.delta_ic


#: A knob within this many standard errors of its off value adds nothing the data show.
NESTED_SIGMAS = 2.0


def nested_in(result: Result, cand: Candidate) -> str | None:
    """The simpler candidate that ``cand``'s refit reduces to, if one of its nesting knobs
    (:attr:`~.candidates.Candidate.nests`) is within :data:`NESTED_SIGMAS` standard errors of off."""
    ev = result.evidence
    knobs = {k.name: k for k in cand.knobs}
    for name, simpler in cand.nests:
        v, sd = ev.parameters.get(name), ev.std.get(name, float("nan"))
        if v is not None and np.isfinite(sd) and sd > 0 and abs(v - knobs[name].off) <= NESTED_SIGMAS * sd:
            return simpler
    return None


def prefer_simpler(rnd: Round, results: list[Result], cand_of: Callable[[str], Candidate],
                   refit: Callable[[str], Result] | None = None) -> list[Result]:
    """Occam's rule on the round's ranking: when the first candidate's extra knob is consistent
    with off (it then *is* a simpler candidate of the library, e.g. vibration_null_shift with no
    shift is valve_null_bias), the simpler candidate goes first, refitted if it was pruned, as long
    as it passes the same gates whenever the first one does (without ``refit``, only a refitted
    simpler candidate is considered). The difference in their held-out
    figures is then the refits' paths, not the data (measured: a null bias at faults 0.3, 0.4, 0.3
    named vibration_null_shift, shift 0.2 sd from 0). ``results`` sorted by :func:`rank`."""
    top = results[0]
    simpler = nested_in(top, cand_of(top.evidence.name))
    j = next((i for i, r in enumerate(results) if r.evidence.name == simpler), None)
    if j is None:
        return results
    if not results[j].evidence.refit:
        if refit is None:
            return results
        results[j] = refit(simpler)
    gates = rnd.structured or True      # the round's gates, were its residual structured
    if rnd.passes(top.evidence, gates) and not rnd.passes(results[j].evidence, gates):
        return results
    ev = top.evidence
    knob = next(k for k, s in cand_of(ev.name).nests if s == simpler)
    ev.note = (f"ranked after {simpler}: its {knob} ({ev.parameters[knob]:.3g} +- {ev.std[knob]:.2g}) is within "
               f"{NESTED_SIGMAS:g} standard errors of off, where it is {simpler}")
    return [results[j], top] + [r for i, r in enumerate(results) if i not in (0, j)]


def prefer_consistent(rnd: Round, results: list[Result], refit: Callable[[str], Result] | None = None) -> list[Result]:
    """The kinematic evidence on the round's ranking: when the recorded velocity disagrees with
    the recorded position's derivative and the first candidate does not pass its gates, or is itself
    a velocity recording effect, the velocity recording effect that removes the disagreement best
    goes first (refitted if it was pruned) if it passes :meth:`Round.kinematic_pass`; its evidence
    carries a note. Measured: a 3 ms velocity lag named velocity_skew (kinematic x0.010 against the
    lag's x0.000); a +3 % velocity scale left unexplained."""
    if rnd.kinematics is None or not rnd.kinematics.significant or not rnd.structured:
        return results
    top = results[0]
    vel = [i for i, r in enumerate(results) if r.evidence.kinematic_ratio is not None]
    if not vel or (rnd.passes(top.evidence, rnd.structured) and top.evidence.kinematic_ratio is None):
        return results
    j = min(vel, key=lambda i: results[i].evidence.kinematic_ratio)
    if j == 0:
        return results
    if not results[j].evidence.refit:
        if refit is None:
            return results
        results[j] = refit(results[j].evidence.name)
    best = results[j].evidence
    if not rnd.kinematic_pass(best) or (top.evidence.kinematic_ratio is not None
                                        and top.evidence.kinematic_ratio <= best.kinematic_ratio):
        return results
    best.note = (f"ranked first on the kinematic evidence: the recorded velocity disagrees with the recorded "
                 f"position's derivative ({rnd.kinematic_base / rnd.kinematics.noise_power:.0f}x the noise's "
                 f"mismatch) and this effect removes it to x{best.kinematic_ratio:.3f}")
    return [results[j]] + [r for i, r in enumerate(results) if i != j]


def rediagnosed(model: KnobModel, x: np.ndarray, n_base: int, rediagnose) -> tuple[np.ndarray, int]:
    """``x`` with its base knobs identified globally with the model at ``x`` (effects included).

    Returns the new knob vector and the model runs the identification took.
    """
    xb, spent = rediagnose(model, x)
    alt = np.array(x, float)
    alt[:n_base] = np.clip(xb, model.lower[:n_base], model.upper[:n_base])
    return alt, spent


#: Retries run side by side before the gates are checked (:func:`retry_from_rediagnosis`, :func:`retry_pruned`):
#: a fixed number, so that the report does not depend on the threads.
RETRY_BATCH = 2


def _retry(rnd: Round, res: Result, cand: Candidate, anchors: list[np.ndarray], n_base: int,
           rediagnose, say) -> tuple[Result, int]:
    """``res`` evaluated again from the base knobs re-identified with ``cand`` in the model; the
    new evidence when it ranks better, and the model runs spent."""
    say(f"round {rnd.number}: {cand.name} -- base re-identified with it in the model")
    # the probe: an in-loop knob at its typical value; a recording effect at its refitted size
    # (the data are corrected by it)
    k0 = cand.knobs[0]
    probe = [res.evidence.parameters[k0.name] if k0.recording else k0.typical] + [k.off for k in cand.knobs[1:]]
    x, spent = rediagnosed(res.model, np.concatenate([rnd.base.x, probe]), n_base, rediagnose)
    # a probe that does not lower the fit-part power to the fit gate cannot pass (the gate saves the
    # refit) -- except for a later round's effect that passed the gates but the held-out power itself:
    # the round's base holds an effect whose knobs the probe does not re-size, and the refit judges
    # (measured: a 0.2 MPa pressure offset after oil at 1.5 GPa, probe x0.8+ of the base, its refit
    # from the probe's faults x0.44, held out x0.06)
    gated = rnd.number == 1 or not rnd.passes(res.evidence, rnd.structured)
    if gated and rnd.r_fit.cost(res.model.run(x)[0]) > rnd.settings.fit_ratio * rnd.base.cost:
        return res, spent + 1
    new = evaluate(rnd, cand, list(anchors) + [x[:len(rnd.base.x)]])
    return (new if rank(new) < rank(res) else res), spent + 1 + new.model.runs


def _retry_in_batches(rnd: Round, results: list[Result], order: list[int], candidates, anchors: list[np.ndarray],
                      n_base: int, rediagnose, say, passes: Callable[[CandidateEvidence], bool] | None
                      ) -> tuple[list[Result], int]:
    """``results[i]`` for i in ``order`` retried (:func:`_retry`), :data:`RETRY_BATCH` side by side,
    until one of a batch passes ``passes`` (None: all of them). Returns the results and the runs spent."""
    by_name = {c.name: c for c in candidates}
    results, spent = list(results), 0
    for j in range(0, len(order), RETRY_BATCH):
        batch = order[j:j + RETRY_BATCH]
        # independent retries: one thread each (the model runs release the GIL)
        done = concurrently(lambda i: _retry(rnd, results[i], by_name[results[i].evidence.name], anchors, n_base,
                                              rediagnose, say), batch)
        for i, (res, n) in zip(batch, done):
            results[i], spent = res, spent + n
        if passes is not None and any(passes(results[i].evidence) for i in batch):
            break
    return results, spent


def retry_from_rediagnosis(rnd: Round, results: list[Result], candidates, anchors: list[np.ndarray], n_base: int,
                           rediagnose, say, passes: Callable[[CandidateEvidence], bool] | None = None
                           ) -> tuple[list[Result], int]:
    """Candidates evaluated again from the ``n_base`` base knobs re-identified with each in the model.

    Only a candidate whose re-identified model (its first knob at its typical value, any other
    absent) lowers the fit-part residual power to the fit gate is evaluated again (the others
    cannot pass; in a later round, one that passed every gate but the held-out power itself is
    evaluated again in any case); its new evidence replaces the old when it ranks better. In the
    order of their fit ratio (the best fits first: they are the ones that pass the probe and pay a
    refit), :data:`RETRY_BATCH` side by side, until one passes ``passes`` (the round's gates; None:
    every candidate). Returns the results (unsorted) and the model runs spent.
    """
    order = sorted(range(len(results)), key=lambda i: results[i].evidence.fit_ratio)
    return _retry_in_batches(rnd, results, order, candidates, anchors, n_base, rediagnose, say, passes)


#: :func:`retry_pruned`'s second pass looks at this many of the first candidates by rank.
RISEN_RANKS = 3


def retry_pruned(rnd: Round, results: list[Result], candidates, anchors: list[np.ndarray], n_base: int,
                 rediagnose, say, structured: bool | str) -> tuple[list[Result], int]:
    """In-loop candidates pruned at screening, retried as :func:`retry_from_rediagnosis` does,
    :data:`RETRY_BATCH` at a time, until one passes the round's gates: first those among the first
    :data:`RISEN_RANKS` by rank with dIC < 0 (strong held-out evidence), then
    ``settings.pruned_retries`` more in the order of their screened fit ratio (the loop calls it in
    its first round only, whose base was identified without any effect).

    Their screen ran from the base knobs identified without them, and an in-loop effect can move
    the fit to another basin where that screen sees nothing (measured: oil at 0.8 GPa with faults
    (0.3, 0.4, 0.3), diagnosed K_BKL 0.012 and K_FSJ 0.24 without it; compressibility screened at
    fit x0.976, seventh by dIC, and the verdict was "unexplained"). A candidate that overlaps a
    refitted one (:attr:`~.candidates.Candidate.overlaps`: shared physics) is not retried: its
    partner's retry, run before, asked the same question (measured: valve_response, third by its
    screen, took the fourth retry from compressibility in that case once supply_pressure had been
    retried).

    The held-out evidence of the screen can be strong where its fit part is weak, and the fit-ratio
    order alone then leaves the candidate out (measured, ``bench discrepancy --seed 1``: a +3 %
    feedback sensor gain at (0.3, 0.4, 0.3), screened at fit x0.997, 32nd of 41 by the fit part,
    held out x0.815, dIC -133, second by rank behind a refitted load_mass that failed the gates; the
    four retries went to flow_asymmetry, velocity_feedback, viscous_friction, command_scale and the
    verdict was "unexplained" with K_BKL 0.144 off; retried, dIC -3357, gain_error 0.0302 for
    0.03). Retries change the ranks, so when the first by rank still fails the gates, a second pass
    retries the in-loop candidates still judged at their screened point that now rank among the
    first :data:`RISEN_RANKS` with dIC < 0 and were not tried.
    Returns the results (unsorted) and the model runs spent."""
    kind = {c.name: c.kind for c in candidates}

    def pruned_in_loop(ev: CandidateEvidence) -> bool:
        return not ev.refit and kind[ev.name] != RECORDING_CHAIN

    def gates(ev: CandidateEvidence) -> bool:
        return rnd.passes(ev, structured)

    def strong(res: list[Result], allowed: Callable[[int], bool]) -> list[int]:
        """Indices of ``res`` among its first :data:`RISEN_RANKS` by rank, with dIC < 0, that ``allowed`` keeps."""
        first = sorted(range(len(res)), key=lambda i: rank(res[i]))[:RISEN_RANKS]
        return [i for i in first if allowed(i) and res[i].evidence.delta_ic < 0]

    tried = {r.evidence.name for r in results if r.evidence.refit}
    pruned = [i for i, r in enumerate(results) if pruned_in_loop(r.evidence)
              and not tried & set(overlapping(r.evidence.name, candidates))]
    # strong held-out evidence first: where such a candidate is the answer, the fit-ratio retries
    # before it were spent for nothing (measured: the sensor gain below, 3079 -> 2481 runs)
    ahead = strong(results, lambda i: i in pruned)
    by_fit = sorted((i for i in pruned if i not in ahead), key=lambda i: results[i].evidence.fit_ratio)
    order = ahead + by_fit[:rnd.settings.pruned_retries]
    results, spent = _retry_in_batches(rnd, results, order, candidates, anchors, n_base, rediagnose, say, gates)
    if gates(min(results, key=rank).evidence):
        return results, spent
    tried |= {results[i].evidence.name for i in order}
    risen = strong(results, lambda i: pruned_in_loop(results[i].evidence) and results[i].evidence.name not in tried)
    results, more = _retry_in_batches(rnd, results, risen, candidates, anchors, n_base, rediagnose, say, gates)
    return results, spent + more


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
