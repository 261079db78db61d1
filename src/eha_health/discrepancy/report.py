"""What the discrepancy loop reports: each candidate's evidence, the model before and after, the verdict."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..signals.channels import DISPLAY_UNITS
from ..signals.residuals import ResidualAnalysis

#: Verdict when the residual is noise (within noise and the model's floor, or white).
NO_MISSING_EFFECT = "no significant missing effect"
#: Verdict when the residual is structured but no candidate passes: the model lacks something the
#: library does not hold (or that its time-domain refit cannot match, e.g. a limit cycle's phase), and
#: the coefficients fitted without it may be biased.
UNEXPLAINED = "structured residual that no candidate effect explains"
#: Two candidates whose held-out information criteria differ by no more than this are reported as
#: equally supported (Burnham & Anderson 2002, section 2.6: a difference below 2 is no evidence for
#: either). Measured on the bench's spool and supply cases: a supply sag and a slower spool (their
#: pilot-flow physics is one signature where the sagged supply does not limit the pressure) 0.0-2.0
#: apart; a slower spool and a feedback delay 240-640 apart.
EQUIVALENT_DIC = 2.0


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
    kind: str = "in-loop"         # 'in-loop' (changes the model) or 'recording' (changes a recorded channel)
    channel: str | None = None    # the recorded channel of a recording effect
    refit: bool = True            # False: pruned after the cheap evidence, judged at its screened point
    pruned_by: str = ""           # the evidence that pruned it
    sparse_rank: int | None = None  # order of entry in the sparse regression of the residual (1 = first)
    note: str = ""                # why it ranks where it does when not by its own evidence (a nested, simpler candidate preferred)
    frequency_ratio: float | None = None  # rig records: held-out position/command response error power, with / without it
    kinematic_ratio: float | None = None  # a velocity recording effect: mismatch of the recorded velocity and the
                                          # recorded position's derivative, with / without it (signals.kinematics)
    # a selected effect: the other candidates of its round the data support as well (they pass the
    # same gates, dIC within EQUIVALENT_DIC): the record cannot tell them apart
    equivalent: list[str] = field(default_factory=list)


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
    # the model fitted on the fit part, per channel [SI]: RMS on the fit part, and the excess over
    # noise and floor, sqrt(max(rms^2 - noise^2 - floor^2, 0)), on the fit and the held-out part
    rms_fit: dict[str, float] = field(default_factory=dict)
    excess_fit: dict[str, float] = field(default_factory=dict)
    excess_held_out: dict[str, float] = field(default_factory=dict)


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
    # where an unexplained structure lives and what it may bias (see :func:`.structure.locate`)
    unexplained: dict | None = None
    data_checks: list[str] = field(default_factory=list)   # quantisation, clipping, interference
    pruned: list[str] = field(default_factory=list)        # candidates judged on screening evidence only
    # rig records, per round: the held-out frequency-response error of the model as it stands
    # (power, the estimate's own scatter, and whether it is structure) and which gates the round used
    frequency_evidence: list[dict] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"verdict": self.verdict, "selected": self.selected,
                "before": asdict(self.before), "after": asdict(self.after),
                "candidates": [asdict(c) for c in self.candidates],
                "residual_before": self.residual_before.as_dict(),
                "residual_after": self.residual_after.as_dict(),
                "split_time_s": self.split_time_s, "wall_time_s": self.wall_time_s, "runs": self.runs,
                "frequency_response": self.frequency_response, "unexplained": self.unexplained,
                "data_checks": self.data_checks, "pruned": self.pruned, "frequency_evidence": self.frequency_evidence}


def format_report(rep: DiscrepancyReport, what: str = "") -> str:
    """Readable summary: verdict, before/after per channel and coefficients, ranked candidates."""
    lines = [f"discrepancy analysis{' of ' + what if what else ''}: {rep.verdict}"]
    lines += [f"  {c.name} is not the only explanation: {', '.join(c.equivalent)} explain(s) the record as well "
              f"(dIC within {EQUIVALENT_DIC:g}, the same gates passed); the notes below give the faults with each"
              for c in rep.candidates if c.selected and c.equivalent]
    lines.append(f"  residual before: {rep.residual_before.verdict}")
    lines += [f"    {e}" for e in rep.residual_before.evidence[:4]]
    lines.append(f"  {'channel':9s} {'RMS before':>14s} {'RMS after':>14s} {'held-out before':>16s} {'held-out after':>15s}")
    for c in rep.before.rms:
        k, u = DISPLAY_UNITS[c]
        lines.append(f"  {c:9s} {rep.before.rms[c] * k:10.4g} {u:3s} {rep.after.rms[c] * k:10.4g} {u:3s} "
                     f"{rep.before.rms_held_out[c] * k:12.4g} {u:3s} {rep.after.rms_held_out[c] * k:11.4g} {u:3s}")
    lines.append(f"  {'channel':9s} {'excess over noise and floor (model fitted on the fit part):':s}")
    lines.append(f"  {'':9s} {'fit before':>14s} {'fit after':>14s} {'held-out before':>16s} {'held-out after':>15s}")
    for c in rep.before.excess_fit:
        k, u = DISPLAY_UNITS[c]
        cells = [rep.before.excess_fit[c], rep.after.excess_fit.get(c, float("nan")),
                 rep.before.excess_held_out[c], rep.after.excess_held_out.get(c, float("nan"))]
        lines.append(f"  {c:9s} " + " ".join(f"{v * k:10.4g} {u:3s}" for v in cells))
    if rep.unexplained:
        lines.append("  unexplained structure: " + "; ".join(rep.unexplained["where"]))
        lines += [f"    {b}" for b in rep.unexplained["bias"]]
        lines += [f"    {k}: segment(s) {', '.join(s)} alone do not determine it (left out of its spread)"
                  for k, s in rep.unexplained.get("undetermined", {}).items()]
    lines += [f"  data check: {d}" for d in rep.data_checks]
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
        mark = " <- selected" if c.selected else ("" if c.refit else " (screened only)")
        lines.append(f"   r{c.round} {c.name:20s} {c.kind:9s} dIC {c.delta_ic:9.1f}  held-out x{c.held_out_ratio:6.3f} "
                     f"(excess x{min(c.held_out_excess_ratio, 99.0):6.3f})  fit x{c.fit_ratio:6.3f}  "
                     f"projection {c.projection:5.2f}  " +
                     (f"response x{c.frequency_ratio:6.3f}  " if c.frequency_ratio is not None else "") +
                     (f"kinematic x{c.kinematic_ratio:6.3f}  " if c.kinematic_ratio is not None else "") + f"{pars}{mark}")
        if c.note:
            lines.append(f"       ({c.note})")
    for fe in rep.frequency_evidence:
        lines.append(f"  round {fe['round']}: held-out position/command response error power {fe['error_power']:.3g} "
                     f"({fe['error_power'] / max(fe['noise_power'], 1e-300):.1f}x the estimate's scatter"
                     f"{': structure' if fe['significant'] else ''}); gates: {fe['gates']}")
    if rep.frequency_response:
        lines.append("  frequency response position/command (H1 over the record; bands where the command has power "
                     "and the measured coherence >= 0.9):")
        lines.append(f"  {'band Hz':>12s} {'measured':>16s} {'before':>16s} {'after':>16s}   (gain, phase deg)")
        for b in rep.frequency_response:
            cells = "".join(f" {b['gain'][k]:7.3f} {b['phase_deg'][k]:7.1f} " for k in ("measured", "before", "after"))
            lines.append(f"  {b['f_lo']:5.1f}-{b['f_hi']:5.1f} {cells}")
    lines.append(f"  {rep.runs} model runs in {rep.wall_time_s:.1f} s")
    return "\n".join(lines)
