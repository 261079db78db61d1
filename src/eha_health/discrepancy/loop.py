"""The discrepancy loop: residual -> missing effect -> augmented model -> error before and after.

1. **Before**: the model as it stands (its base knobs fitted: the fault
   coefficients for an FDI test, the calibrated nominal parameters for a rig)
   and the analysis of its residual (:mod:`residuals`).
2. **Attribution**, on a split of the record (the first ``fit_fraction`` of the
   samples to fit, the rest held out), for every candidate of the library
   (:mod:`candidates`), two kinds of evidence:

   * *projection*: the share of the fit residual that the candidate's output
     sensitivity explains beyond what the base knobs already can,
     ``1 - |P_[J S]^perp r|^2 / |P_J^perp r|^2`` (J: base-knob Jacobian, S: the
     candidate's signature, r: weighted residual, all at the current fit);
   * *refit*: base knobs and the candidate's parameters fitted together on the
     fit part (a grid scan of the candidate's knob, then bounded least squares),
     judged on the held-out part by an information criterion
     ``dIC = n_eff ln(RSS_aug / RSS_base) + k ln(n_fit)`` where n_eff is the
     held-out sample count deflated by the residual autocorrelation.

   The ranking is by dIC. The best candidate is *selected* only when the
   residual is structured, dIC < 0, and the held-out and fit residual powers
   drop below the ratios of :class:`Settings`. If none is, on a structured
   residual, each candidate is evaluated once more from the base knobs
   re-identified globally with it in the model (another basin). Then the loop repeats with it
   included, up to ``max_effects``; from the second effect on, the held-out
   power itself (not only its excess over noise and floor) must drop below the
   held-out ratio.
3. **After**: the selected effects added, every knob re-fitted together (from
   the better of the local path and, given ``rediagnose``, the base knobs
   re-identified globally with the selected effects in the model); the
   report gives both states (per-channel RMS, fitness, coefficients and their
   errors against a known truth) and the ranked candidates with their evidence.
   The verdict is "model lacks: ..." (effects selected), "no significant missing
   effect" (the residual is noise), or, when the residual is structured but no
   candidate passes, :data:`UNEXPLAINED`: the model lacks something the library
   cannot supply, and a diagnosis fitted without it may be biased.

Nothing here imports ROS.
"""
from __future__ import annotations

import functools
import time
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from ..identification.problem import FAULT_KNOBS, AugmentedModel, Fit, Knob, Record, Residual, fit
from .candidates import CANDIDATES, Candidate
from ..identification.fitness import CHANNEL_COLUMNS
from ..identification.diagnose import _autocorr_inflation
from ..physics.params import ModelParams, load
from ..signals.residuals import DISPLAY_UNITS, ResidualAnalysis, analyse, rest_noise_level


#: Verdict when the residual is noise (within noise and the model's floor, or white).
NO_MISSING_EFFECT = "no significant missing effect"
#: Verdict when the residual is structured but no candidate passes: the model lacks something the
#: library does not hold (or that its time-domain refit cannot match, e.g. a limit cycle's phase), and
#: the coefficients fitted without it may be biased.
UNEXPLAINED = "structured residual that no candidate effect explains"


@dataclass(frozen=True)
class Settings:
    """Decision thresholds of the loop (``data/discrepancy.yaml`` says how they were set)."""
    fit_fraction: float = 0.7          # share of the samples fitted; the rest is held out
    held_out_ratio: float = 0.5        # selected only if the held-out residual power above noise and
                                       # floor, with / without the effect, is <= this
    fit_ratio: float = 0.8             # ... and RSS_fit(aug)/RSS_fit(base) <= this
    grid: int = 48                     # grid points of a candidate's knob before the local fit
    starts: int = 3                    # local fits per candidate, from the best distinct grid points
    max_nfev: int = 30                 # iterations of each local fit
    floor: dict = field(default_factory=dict)   # per-channel residual floor of the model [SI]
    effect_floor: dict = field(default_factory=dict)  # {candidate: per-channel floor} once it is added
    rest_noise: bool = False           # noise also measured where the command rests (a rig's coloured
                                       # interference; residuals.rest_noise_level)

    def floor_with(self, effects) -> dict[str, float]:
        """Per-channel floor [SI] of the model holding ``effects``: its largest known model-form error."""
        out = dict(self.floor)
        for e in effects:
            for c, v in self.effect_floor.get(e, {}).items():
                out[c] = max(out.get(c, 0.0), v)
        return out


@functools.lru_cache(maxsize=None)
def _packaged_settings() -> dict:
    return yaml.safe_load(resources.files("eha_health").joinpath("data/discrepancy.yaml").read_text()) or {}


def fdi_settings(path: str | Path | None = None) -> Settings:
    """Settings for FDI tests of the shipped monitor: thresholds and the model's residual floor."""
    data = yaml.safe_load(Path(path).read_text()) if path else _packaged_settings()
    fl = {k: float(v) for k, v in (data.get("floor") or {}).items()}
    ef = {e: {k: float(v) for k, v in (chans or {}).items()} for e, chans in (data.get("effect_floor") or {}).items()}
    th = data.get("thresholds") or {}
    return Settings(**{k: float(v) for k, v in th.items() if k in ("held_out_ratio", "fit_ratio")}, floor=fl,
                    effect_floor=ef)


@dataclass
class CandidateEvidence:
    """One candidate's evidence in one round of the loop."""
    name: str
    mechanism: str
    round: int
    projection: float             # share of the fit residual its signature explains (0..1)
    fit_ratio: float              # RSS on the fit part, with / without it
    held_out_ratio: float         # RSS on the held-out part, with / without it
    held_out_excess_ratio: float  # the same for the power above the noise and floor (the gate)
    delta_ic: float               # information criterion change on the held-out part (< 0: better)
    parameters: dict[str, float]
    std: dict[str, float]
    units: dict[str, str]
    selected: bool = False


@dataclass
class State:
    """The model at one stage (before or after augmentation)."""
    effects: list[str]
    values: dict[str, float]      # every fitted knob (fault coefficients included)
    std: dict[str, float]
    rms: dict[str, float]         # per-channel residual RMS over the whole record [SI]
    rms_held_out: dict[str, float]  # per-channel RMS on the held-out part, model fitted on the fit part
    fitness: float                # weighted residual power over the whole record
    errors: dict[str, float] | None = None   # |estimate - truth| where the truth is known


@dataclass
class DiscrepancyReport:
    before: State
    after: State
    candidates: list[CandidateEvidence]
    selected: list[str]
    verdict: str                  # 'model lacks: ...', UNEXPLAINED or NO_MISSING_EFFECT
    residual_before: ResidualAnalysis
    residual_after: ResidualAnalysis
    wall_time_s: float
    runs: int
    t: np.ndarray = field(repr=False, default=None)
    measured: dict = field(repr=False, default_factory=dict)
    fitted_before: dict = field(repr=False, default_factory=dict)
    fitted_after: dict = field(repr=False, default_factory=dict)
    split_time_s: float = 0.0
    # rig records: position/command gain and phase per band, measured and modelled (frequency.compare)
    frequency_response: list | None = None

    def as_dict(self) -> dict:
        return {"verdict": self.verdict, "selected": self.selected,
                "before": asdict(self.before), "after": asdict(self.after),
                "candidates": [asdict(c) for c in self.candidates],
                "residual_before": self.residual_before.as_dict(),
                "residual_after": self.residual_after.as_dict(),
                "split_time_s": self.split_time_s, "wall_time_s": self.wall_time_s, "runs": self.runs,
                "frequency_response": self.frequency_response}


# --------------------------------------------------------------------------- pieces
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


def _rescan(model: AugmentedModel, residual: Residual, start: Fit, n_base: int,
            factors=np.geomspace(0.6, 1.6, 17)) -> np.ndarray:
    """Before the final fit: each effect knob scanned over x0.6-1.6 of its value, the others held.

    The candidate was sized on the fit part from a coarse grid; on the whole record the cost in an
    effect parameter can have several local minima (measured: oil compliance, 0.81 /GPa local
    against 1.04 global for a true 1.0, the pressure residual jumping with stick-slip events in
    between), and a local fit stays in the first one. One batch per knob; keeps ``start.x`` if nothing
    scanned is better.
    """
    x = np.asarray(start.x, float).copy()
    best = residual.rss(start.output)
    for i in range(n_base, len(x)):
        if x[i] == 0.0:
            continue
        X = np.repeat(x[None], len(factors), axis=0)
        X[:, i] = np.clip(x[i] * factors, model.lower[i], model.upper[i])
        costs = np.array([residual.rss(o) for o in model.run(X)])
        j = int(np.argmin(costs))
        if costs[j] < best:
            x, best = X[j].copy(), float(costs[j])
    return x


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


def _channels(record: Record, out: np.ndarray) -> dict[str, np.ndarray]:
    return {c: out[:, CHANNEL_COLUMNS[c]].copy() for c in record.channels}


def _state(f: Fit, r_all: Residual, held: Residual, out_held: np.ndarray,
           effects: list[str], inflation: float, truth: dict | None) -> State:
    """``out_held``: the output of the model fitted on the fit part (its held-out prediction)."""
    values = f.values()
    errors = None
    if truth:
        errors = {k: abs(values[k] - float(v)) for k, v in truth.items() if k in values}
    return State(effects=list(effects), values=values, std=f.std(inflation), rms=r_all.rms(f.output),
                 rms_held_out=held.rms(out_held), fitness=r_all.rss(f.output), errors=errors)


def _evaluate(model: AugmentedModel, cand: Candidate, base: Fit, anchors: list[np.ndarray], r_fit: Residual,
              r_held: Residual, rss_held_base: float, rss_held_noise: float, n_eff: float, n_fit: float,
              settings: Settings, rnd: int):
    """Attribution evidence of one candidate against the current base fit."""
    mc = model.extended(cand.knobs)
    nb = len(base.x)
    x_off = np.concatenate([base.x, [k.off for k in cand.knobs]])
    # signature: output change per unit of each knob, from off to its typical value
    X = np.repeat(x_off[None], len(cand.knobs), axis=0)
    for j, k in enumerate(cand.knobs):
        X[j, nb + j] = k.typical
    outs = mc.run(X)
    S = np.column_stack([(r_fit(o) - base.residual) / (k.typical - k.off) for o, k in zip(outs, cand.knobs)])
    share = projection_share(base.jacobian, S, base.residual)
    # grid scan of the first knob (any further knob absent) with the base knobs held at each anchor
    # (the current fit, and the whole-record fit: on a split record the base knobs may have absorbed
    # the effect differently), then local fits from the best distinct points
    G = np.vstack([candidate_grid(a, cand, settings.grid) for a in anchors])
    costs = np.array([r_fit.rss(o) for o in mc.run(G)])
    starts: list[np.ndarray] = []
    for i in np.argsort(costs):
        if all(np.max(np.abs(G[i] - s0) / np.maximum(mc.upper - mc.lower, 1e-300)) > 0.02 for s0 in starts):
            starts.append(G[i])
        if len(starts) == settings.starts:
            break
    best = min((fit(mc, r_fit, s0, max_nfev=settings.max_nfev) for s0 in starts), key=lambda f: f.rss)
    rss_held = r_held.rss(mc.run(best.x)[0])
    ratio_h = rss_held / rss_held_base if rss_held_base > 0 else 1.0
    # what is above noise and floor on the held-out part: where the base is already there, the
    # effect must keep it there (ratio 0), else it must remove a share of the excess
    excess = max(rss_held - rss_held_noise, 0.0) / max(rss_held_base - rss_held_noise, 1e-3 * rss_held_base, 1e-300)
    k = len(cand.knobs)
    dic = n_eff * float(np.log(max(ratio_h, 1e-300))) + k * float(np.log(n_fit))
    infl = _autocorr_inflation(best.residual, len(r_fit.channels))
    sd = best.std(infl)
    ev = CandidateEvidence(
        name=cand.name, mechanism=cand.mechanism, round=rnd, projection=share,
        fit_ratio=best.rss / base.rss if base.rss > 0 else 1.0, held_out_ratio=ratio_h,
        held_out_excess_ratio=excess, delta_ic=dic,
        parameters={kn.name: float(best.x[nb + j]) for j, kn in enumerate(cand.knobs)},
        std={kn.name: sd.get(kn.name, float("nan")) for kn in cand.knobs},
        units={kn.name: kn.unit for kn in cand.knobs})
    return ev, mc, best


def _rediagnosed(model: AugmentedModel, x: np.ndarray, n_base: int, rediagnose) -> tuple[np.ndarray, int]:
    """``x`` with its base knobs identified globally with the model at ``x`` (effects included).

    Returns the new knob vector and the model runs the identification took.
    """
    xb, spent = rediagnose(model.params_at(x)[0])
    alt = np.array(x, float)
    alt[:n_base] = np.clip(xb, model.lower[:n_base], model.upper[:n_base])
    return alt, spent


def _retry_from_rediagnosis(results, candidates, model: AugmentedModel, base: Fit, before: Fit, rediagnose,
                            r_fit: Residual, r_held: Residual, rss_held_base: float, held_noise, n_eff: float,
                            n_fit: float, settings: Settings, say) -> tuple[list, int]:
    """Round-1 candidates evaluated again from the base knobs re-identified with each in the model.

    Only a candidate whose re-identified model (its first knob at its typical value, any other
    absent) lowers the fit-part residual power to the fit gate is evaluated again (the others
    cannot pass); its new evidence replaces the old when it ranks better. Returns the results
    (unsorted) and the model runs spent.
    """
    by_name = {c.name: c for c in candidates}
    nb = len(base.x)
    out, runs = [], 0
    for ev, mc, best in results:
        cand = by_name[ev.name]
        say(f"round 1: {cand.name} -- base re-identified with it in the model")
        probe = [k.typical if j == 0 else k.off for j, k in enumerate(cand.knobs)]
        x, spent = _rediagnosed(mc, np.concatenate([base.x, probe]), nb, rediagnose)
        runs += spent + 1
        if r_fit.rss(mc.run(x)[0]) > settings.fit_ratio * base.rss:
            out.append((ev, mc, best))
            continue
        new = _evaluate(model, cand, base, [base.x, before.x, x[:nb]], r_fit, r_held, rss_held_base,
                        held_noise([cand.name]), n_eff, n_fit, settings, 1)
        runs += new[1].runs
        out.append(new if _rank(new) < _rank((ev, mc, best)) else (ev, mc, best))
    return out, runs


def _rank(result) -> tuple:
    """Sort key of an (evidence, model, fit) result: a refit that does not lower its own fit
    residual (fit ratio >= 1) last, then by the held-out information criterion."""
    ev = result[0]
    return ev.fit_ratio >= 1.0, ev.delta_ic


def _n_eff(res: Residual, r: np.ndarray) -> float:
    return len(r) / _autocorr_inflation(r, len(res.channels))


# --------------------------------------------------------------------------- API
def run_loop(record: Record, params: ModelParams | None = None, base_knobs: tuple[Knob, ...] = FAULT_KNOBS,
             x_start=None, segments: dict[str, np.ndarray] | None = None,
             candidates: tuple[Candidate, ...] = CANDIDATES, max_effects: int = 2,
             settings: Settings | None = None, truth: dict | None = None, final_fit: str = "all",
             progress: Callable[[str], None] | None = None,
             rediagnose: Callable[[ModelParams], tuple[np.ndarray, int]] | None = None) -> DiscrepancyReport:
    """Run the discrepancy loop on one record.

    Parameters
    ----------
    record : Record
        Measured command, channels and optional load.
    params : ModelParams
        The monitor model as it stands (default: the shipped monitor).
    base_knobs : tuple of Knob
        What is always fitted (default: the three fault coefficients).
    x_start : array, optional
        Start values of the base knobs (default: their ``off`` values).
    final_fit : {'all', 'fit'}
        Fit the before/after states on the whole record (an FDI diagnosis) or on
        the fit part only (a prediction test: the held-out part stays unseen).
    rediagnose : callable, optional
        Global identification of the base knobs with a given model, returning them
        and the model runs it took (FDI: the deterministic diagnosis). When round 1
        selects nothing on a structured residual, each candidate is tried once more
        from the base knobs identified
        *with it in the model*: an effect can move the fit to another basin that a
        local search from the current one cannot reach (measured: compressibility
        with backlash, a limit cycle whose phase only matches near the true faults).
    """
    if max_effects < 0:
        raise ValueError(f"max_effects must be >= 0, got {max_effects}")
    if final_fit not in ("all", "fit"):
        raise ValueError(f"final_fit must be 'all' or 'fit', got {final_fit!r}")
    settings = settings or Settings()
    if not 0.2 <= settings.fit_fraction <= 0.9:
        raise ValueError(f"fit_fraction must be within [0.2, 0.9], got {settings.fit_fraction}")
    say = progress or (lambda s: None)
    t0 = time.perf_counter()
    params = params if params is not None else load("monitor")
    model = AugmentedModel(params, tuple(base_knobs), record)
    n = len(record)
    split = int(round(settings.fit_fraction * n))
    fit_mask = np.arange(n) < split
    r_all, r_fit, r_held = Residual(record), Residual(record, fit_mask), Residual(record, ~fit_mask)
    r_final = r_all if final_fit == "all" else r_fit
    runs = 0
    x = model.off() if x_start is None else np.asarray(x_start, float)
    if len(x) != len(base_knobs):
        raise ValueError(f"x_start has {len(x)} values for {len(base_knobs)} base knobs")

    say("fitting the model as it stands")
    before = fit(model, r_final, x)
    base = fit(model, r_fit, before.x)
    noise = ({c: rest_noise_level(y, record.command, record.sample_rate) for c, y in record.channels.items()}
             if settings.rest_noise else None)
    res_before = analyse(record.t, record.channels, _channels(record, before.output), segments, settings.floor,
                         noise=noise)
    infl = _autocorr_inflation(before.residual, len(r_final.channels))
    out_base = base.output      # the fit-part model over the whole record
    state_before = _state(before, r_all, r_held, out_base, [], infl, truth)
    say(f"residual: {res_before.verdict}")

    def held_noise(effects) -> float:
        """Held-out residual power that noise and the floor of the model holding ``effects`` leave."""
        floor = settings.floor_with(effects)
        return float(sum(r_held.w[i] ** 2 * r_held.n * (res_before.channels[c].noise_sd ** 2 + floor.get(c, 0.0) ** 2)
                         for i, c in enumerate(r_held.channels)))

    evidence: list[CandidateEvidence] = []
    selected: list[str] = []
    structured = res_before.structured
    remaining = list(candidates)
    for rnd in range(1, max_effects + 1):
        # round 1 always ranks the candidates (the evidence is reported either way); a later round
        # only runs while the residual is still above the floor of the model as it now stands
        if not remaining or (rnd > 1 and not structured):
            break
        anchors = [base.x] if rnd > 1 else [base.x, before.x]
        r_held_base = r_held(out_base)
        rss_held_base = float(r_held_base @ r_held_base)
        n_eff = _n_eff(r_held, r_held_base)
        n_fit = _n_eff(r_fit, base.residual)
        results = []
        for i, cand in enumerate(remaining):
            say(f"round {rnd}: candidate {i + 1}/{len(remaining)} {cand.name}")
            results.append(_evaluate(model, cand, base, anchors, r_fit, r_held, rss_held_base,
                                     held_noise(selected + [cand.name]), n_eff, n_fit, settings, rnd))
            runs += results[-1][1].runs
        # the two kinds of evidence must agree: a refit that does not even lower the residual on
        # the data it was fitted to (fit ratio >= 1: no better than the effect switched off) cannot
        # claim the held-out gain, which is then luck of a coloured residual; such candidates rank last
        results.sort(key=_rank)

        def passes(ev) -> bool:
            return (structured and ev.delta_ic < 0 and ev.held_out_excess_ratio <= settings.held_out_ratio
                    and ev.fit_ratio <= settings.fit_ratio)

        if rnd == 1 and structured and rediagnose is not None and not passes(results[0][0]):
            results, spent = _retry_from_rediagnosis(results, remaining, model, base, before, rediagnose, r_fit,
                                                     r_held, rss_held_base, held_noise, n_eff, n_fit, settings, say)
            runs += spent
            results.sort(key=_rank)
        evidence += [e for e, _, _ in results]
        ev, mc, best = results[0]
        ok = passes(ev)
        # a further effect must also show on data it was not fitted to: the model already holds
        # one, and what it leaves is partly that model's own form error, which a small extra knob
        # can always bend to (measured: a 0.0017 flow asymmetry added after a null bias at
        # K_BKL = 0.7, held-out power x0.77 with the excess already at the floor)
        if rnd > 1:
            ok = ok and ev.held_out_ratio <= settings.held_out_ratio
        if not ok:
            break
        ev.selected = True
        selected.append(ev.name)
        model, base, out_base = mc, best, best.output
        runs -= model.runs       # counted above; the model goes on counting from here
        remaining = [c for c in remaining if c.name != ev.name]
        res = analyse(record.t, record.channels, _channels(record, best.output), segments,
                      settings.floor_with(selected), noise=noise)
        structured = res.structured
        say(f"selected {ev.name}; residual now {res.verdict}")

    after = before
    if selected:
        start = _rescan(model, r_final, base, len(base_knobs))
        if rediagnose is not None:
            # the base knobs identified globally with the selected effects in the model: the local
            # path from the biased diagnosis can stop in another basin (measured: compressibility
            # 1.6 GPa with faults 0.3, 0.4, 0.3 ended at K_FSJ 0.345)
            alt, spent = _rediagnosed(model, start, len(base_knobs), rediagnose)
            runs += spent
            c_start, c_alt = (r_final.rss(o) for o in model.run(np.vstack([start, alt])))
            start = alt if c_alt < c_start else start
        after = fit(model, r_final, start)
    res_after = analyse(record.t, record.channels, _channels(record, after.output), segments,
                        settings.floor_with(selected), noise=noise) \
        if selected else res_before
    infl = _autocorr_inflation(after.residual, len(r_final.channels))
    state_after = _state(after, r_all, r_held, out_base, selected, infl, truth)
    verdict = ("model lacks: " + ", ".join(selected)) if selected else \
        UNEXPLAINED if res_before.structured else NO_MISSING_EFFECT
    return DiscrepancyReport(
        before=state_before, after=state_after, candidates=evidence, selected=selected, verdict=verdict,
        residual_before=res_before, residual_after=res_after, wall_time_s=time.perf_counter() - t0,
        runs=runs + model.runs, t=record.t, measured=dict(record.channels),
        fitted_before=_channels(record, before.output), fitted_after=_channels(record, after.output),
        split_time_s=float(record.t[split]))


def fdi_segments(record: Record, sequence=None) -> dict[str, np.ndarray]:
    from ..physics.sequence import FDISequence
    seq = sequence or FDISequence()
    return {name: seq.mask(name, record.t) for name in ("ramp", "step", "return", "sine_low", "sine_high")}


def quantile_segments(record: Record, parts: int = 5) -> dict[str, np.ndarray]:
    """Equal-length segments of a record that is not an FDI test (e.g. a chirp)."""
    idx = np.arange(len(record)) * parts // len(record)
    return {f"part{i + 1}": idx == i for i in range(parts)}


def analyse_fdi_test(response, max_effects: int = 2, seed: int = 0, params: ModelParams | None = None,
                     truth: dict | None = None, candidates: tuple[Candidate, ...] = CANDIDATES,
                     settings: Settings | None = None, progress=None, diagnosis=None) -> DiscrepancyReport:
    """The loop on one FDI test: start from the diagnosis (given, or run with ``seed``)."""
    from ..identification.diagnose import diagnose
    record = Record.from_response(response)
    if diagnosis is None:
        diagnosis = diagnose(response, seed=seed, params=params, progress=progress)

    def rediagnose(p: ModelParams) -> tuple[np.ndarray, int]:
        # the fast global method: one per candidate, only when round 1 finds nothing on a structured residual
        d = diagnose(response, method="deterministic", params=p)
        return np.array(d.faults.as_tuple()), int(d.evaluations)

    return run_loop(record, params, FAULT_KNOBS, np.array(diagnosis.faults.as_tuple()),
                    fdi_segments(record), candidates, max_effects, settings or fdi_settings(), truth,
                    "all", progress, rediagnose)


def format_report(rep: DiscrepancyReport, what: str = "") -> str:
    """Readable summary: verdict, before/after per channel and coefficients, ranked candidates."""
    lines = [f"discrepancy analysis{' of ' + what if what else ''}: {rep.verdict}",
             f"  residual before: {rep.residual_before.verdict}"]
    lines += [f"    {e}" for e in rep.residual_before.evidence[:4]]
    lines.append(f"  {'channel':9s} {'RMS before':>14s} {'RMS after':>14s} {'held-out before':>16s} {'held-out after':>15s}")
    for c in rep.before.rms:
        k, u = DISPLAY_UNITS[c]
        lines.append(f"  {c:9s} {rep.before.rms[c] * k:10.4g} {u:3s} {rep.after.rms[c] * k:10.4g} {u:3s} "
                     f"{rep.before.rms_held_out[c] * k:12.4g} {u:3s} {rep.after.rms_held_out[c] * k:11.4g} {u:3s}")
    lines.append(f"  fitness (weighted residual power): before {rep.before.fitness:.4g}, after {rep.after.fitness:.4g}")
    lines.append(f"  {'parameter':22s} {'before':>12s} {'after':>12s} {'+/- (after)':>12s}" +
                 (f" {'err before':>11s} {'err after':>10s}" if rep.before.errors else ""))
    for name, v in rep.after.values.items():
        b = rep.before.values.get(name)
        row = f"  {name:22s} {b if b is not None else float('nan'):12.5g} {v:12.5g} {rep.after.std.get(name, float('nan')):12.3g}"
        if rep.before.errors and name in rep.before.errors:
            row += f" {rep.before.errors[name]:11.4f} {rep.after.errors[name]:10.4f}"
        lines.append(row)
    lines.append("  candidates (ranked by the held-out information criterion dIC; excess = held-out power above "
                 "noise and floor; projection = share of the fit residual its signature explains):")
    for c in rep.candidates:
        pars = ", ".join(f"{k}={v:.4g}+/-{c.std[k]:.2g} {c.units[k]}" for k, v in c.parameters.items())
        mark = " <- selected" if c.selected else ""
        lines.append(f"   r{c.round} {c.name:17s} dIC {c.delta_ic:9.1f}  held-out x{c.held_out_ratio:6.3f} "
                     f"(excess x{min(c.held_out_excess_ratio, 99.0):6.3f})  fit x{c.fit_ratio:6.3f}  "
                     f"projection {c.projection:5.2f}  {pars}{mark}")
    if rep.frequency_response:
        lines.append("  frequency response position/command (H1 over the record; bands where the command has power "
                     "and the measured coherence >= 0.9):")
        lines.append(f"  {'band Hz':>12s} {'measured':>16s} {'before':>16s} {'after':>16s}   (gain, phase deg)")
        for b in rep.frequency_response:
            cells = "".join(f" {b['gain'][k]:7.3f} {b['phase_deg'][k]:7.1f} " for k in ("measured", "before", "after"))
            lines.append(f"  {b['f_lo']:5.1f}-{b['f_hi']:5.1f} {cells}")
    lines.append(f"  {rep.runs} model runs in {rep.wall_time_s:.1f} s")
    return "\n".join(lines)
