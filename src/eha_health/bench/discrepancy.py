"""Benchmarks of the discrepancy loop (figures, not assertions).

* :func:`residual_floor` -- the monitor's own residual RMS per channel on clean
  reference runs without any missing effect (its model-form floor; written to
  ``data/discrepancy.yaml`` with ``eha-health bench floor --write``).
* :func:`synthetic` -- the issue's targets on simulated undeclared effects: each
  in-loop effect in the plant and each recording-chain effect altered after the test
  (every channel), alone and with faults, two effects at once, plus noise-only runs;
  run ``eha-health bench discrepancy``.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from scipy.interpolate import CubicSpline
from scipy.optimize import brentq
from scipy.signal import cont2discrete, lfilter

from ..discrepancy.candidates import BY_NAME
from ..discrepancy.loop import analyse_fdi_test
from ..discrepancy.report import UNEXPLAINED
from ..discrepancy.settings import DEFAULT_MAX_EFFECTS
from ..physics.faults import FAULT_NAMES, Faults
from ..physics.model import simulate
from ..identification.residual import CHANNEL_SCALES
from ..physics.params import ModelParams, load
from ..signals.channels import DISPLAY_UNITS, MEASURED
from .speed import monitor_run_s

#: Undeclared in-loop effects of the synthetic bench: (candidate that should be found, how the plant gets it).
EFFECTS: tuple[tuple[str, object], ...] = (
    ("compressibility", lambda p: p.with_effect_names(["compressibility"])),
    ("sensor_delay", lambda p: p.with_effect_names(["sensor_delay"])),
    ("sensor_bias", lambda p: p.with_effects(sensor_calibration={"enabled": True, "bias": 2e-4})),
    ("sensor_gain", lambda p: p.with_effects(sensor_calibration={"enabled": True, "gain_error": 0.03})),
    ("stribeck", lambda p: p.with_effect_names(["stribeck"])),
    ("viscous_friction", lambda p: p.updated("jack", viscous=6000.0)),
    ("valve_null_bias", lambda p: p.updated("controller", null_bias=3e-4)),
    ("load_stiffness", lambda p: p.updated("surface", hinge_stiffness=1.6e5)),
    ("leakage", lambda p: p.updated("hydraulics", leakage=5e-12)),
    ("supply_pressure", lambda p: p.updated("hydraulics", supply_pressure=14e6)),
    ("mount_compliance", lambda p: p.updated("linkage", stiffness=5e6)),
    ("flow_asymmetry", lambda p: p.updated("hydraulics", flow_asymmetry=0.1)),
    ("vibration_null_shift", lambda p: p.with_effects(vibration_null_shift={"enabled": True, "gain": 1e-4})),
    ("load_mass", lambda p: p.updated("surface", mass=22.5)),
    ("controller_gain", lambda p: p.updated("controller", kp=p.controller.kp * 1.15)),
    ("velocity_feedback", lambda p: p.updated("controller", gas=p.controller.gas * 1.3)),
    # the reference's spool end area: its flapper-nozzle stage moves the spool 1.4x slower
    ("valve_response", lambda p: p.updated("flapper_nozzle", spool_end_area=p.flapper_nozzle.spool_end_area * 1.4)),
)
FAULT_SETS = (Faults(0.0, 0.0, 0.0), Faults(0.4, 0.5, 0.0), Faults(0.3, 0.4, 0.3))


# Recording chains altered after the test, each with another numerical method than the
# candidate's (cubic-spline skew, bilinear first-order lag): the loop must not find its own arithmetic.
def late(r, channel: str, d: float):
    """``r`` with ``channel`` recorded ``d`` [s] late (cubic spline, start held)."""
    y = getattr(r, channel)
    setattr(r, channel, CubicSpline(r.t, y)(np.clip(r.t - d, r.t[0], None)))
    return r


def scaled(r, channel: str, e: float):
    setattr(r, channel, getattr(r, channel) * (1.0 + e))
    return r


def offset(r, channel: str, b: float):
    setattr(r, channel, getattr(r, channel) + b)
    return r


def lagged(r, channel: str, tau: float):
    """``r`` with ``channel`` through a first-order sensor ``tau`` [s] (bilinear transform)."""
    b, a, _ = cont2discrete(([1.0], [tau, 1.0]), 1.0 / r.sample_rate, method="bilinear")
    y = getattr(r, channel)
    setattr(r, channel, lfilter(np.ravel(b), a, y - y[0]) + y[0])
    return r


def drifting(r, channel: str, rate: float):
    """``r`` with ``channel``'s zero drifting at ``rate`` [channel unit / s] from the first sample."""
    setattr(r, channel, getattr(r, channel) + rate * (r.t - r.t[0]))
    return r


def all_late(r, d: float):
    """``r`` with every measured channel recorded ``d`` [s] late against the command."""
    for c in MEASURED:
        late(r, c, d)
    return r


def fast_clock(r, e: float):
    """``r`` with every measured channel sampled on a time base (1 + e) faster than the command's
    (cubic spline at t0 + (1 + e)(t - t0), end held)."""
    ts = np.clip(r.t[0] + (1.0 + e) * (r.t - r.t[0]), None, r.t[-1])
    for c in MEASURED:
        setattr(r, c, CubicSpline(r.t, getattr(r, c))(ts))
    return r


#: Size of each recording alteration of the bench: an offset of one residual scale of the channel
#: (position 0.1 mm, pressure 0.5 MPa, ...), +3 % scale, 4 ms late, a 3 ms sensor lag, a drift of
#: 0.3 residual scales per second (about one over the FDI test).
ALTER = {"offset": (offset, lambda c: CHANNEL_SCALES[c]), "scale": (scaled, lambda c: 0.03),
         "skew": (late, lambda c: 4e-3), "lag": (lagged, lambda c: 3e-3),
         "drift": (drifting, lambda c: 0.3 * CHANNEL_SCALES[c])}
#: The whole-record alterations: every channel 3 ms late, a time base 0.5 % fast, the recorded
#: command one position scale (0.1 mm) off or 3 % large.
ALTER_RECORD = {"command_skew": lambda r: all_late(r, 3e-3), "time_base": lambda r: fast_clock(r, 5e-3),
                "command_offset": lambda r: offset(r, "command", CHANNEL_SCALES["position"]),
                "command_scale": lambda r: scaled(r, "command", 0.03)}


def recording_alterations(channels=MEASURED) -> tuple[tuple[str, object], ...]:
    """(candidate, response -> altered response) for every recording candidate."""
    return tuple((f"{c}_{k}", (lambda r, c=c, k=k: ALTER[k][0](r, c, ALTER[k][1](c))))
                 for c in channels for k in ALTER) + tuple(ALTER_RECORD.items())


def effect_change(name: str | None) -> tuple[object, object]:
    """(plant change or None, recording alteration or None) that puts candidate ``name``'s effect
    in a :func:`reference_run` (None: neither, a noise-only run); KeyError for an unknown name."""
    if name is None:
        return None, None
    plant, altered = dict(EFFECTS).get(name), dict(recording_alterations()).get(name)
    if plant is None and altered is None:
        raise KeyError(f"no bench effect named {name!r}")
    return plant, altered


#: Two effects at once: (expected candidates, plant change, recording alteration).
TWO_EFFECTS = (
    (("pressure_offset", "sensor_delay"), lambda p: p.with_effects(sensor_delay={"enabled": True, "delay": 1e-3}),
     lambda r: offset(r, "pressure", 5e5)),
    (("position_skew", "compressibility"), lambda p: p.with_effect_names(["compressibility"]),
     lambda r: late(r, "position", 4e-3)),
)


def reference_run(faults: Faults, seed: int | None = None, plant=None, alter=None, ref: ModelParams | None = None):
    """One FDI test of the reference EHA (``ref``, default the shipped one) at ``faults``: ``plant``
    (params -> params) puts an in-loop effect in the plant, ``alter`` (response -> response) a
    recording effect on the recorded channels after the test; sensor noise with ``seed`` (None: a
    clean run). The records of :func:`synthetic`, of ``bench floor``'s effect floors and of the
    probes in tools/ (worn actuators, unlisted effects)."""
    ref = ref if ref is not None else load("reference")
    p = plant(ref) if plant is not None else ref
    r = simulate(params=p.with_effect_names(["sensor_noise"]) if seed is not None else p, faults=faults, seed=seed)
    return alter(r) if alter is not None else r


def synthetic(seed: int = 0, n_noise: int = 6, progress=None, effects=None, fault_sets=FAULT_SETS,
              two_effects: bool = True, without: tuple[str, ...] = ()) -> dict:
    """Run the loop on every effect x fault set (in-loop effects in the plant, recording effects
    altered after the test), on two-effect cases and on noise-only runs, each as `eha-health
    discrepancy` runs it (up to :data:`~..discrepancy.settings.DEFAULT_MAX_EFFECTS` effects).

    ``without``: measured channels left out of every record (all NaN, as a CSV without the column
    reads), and the cases of recording effects on them only; position cannot be left out (the
    discrepancy command requires it)."""
    bad = [c for c in without if c not in MEASURED or c == "position"]
    if bad:
        raise ValueError(f"cannot leave out channel {bad[0]!r}: the channels that may be missing are "
                         f"{', '.join(c for c in MEASURED if c != 'position')}")
    recorded = tuple(c for c in MEASURED if c not in without)
    cases = []
    ref = load("reference")
    rng = np.random.default_rng(seed)
    # a case only where the loop offers its candidate on these channels (Candidate.applies_to)
    keep = lambda n: (effects is None or n in effects) and BY_NAME[n].applies_to(recorded)   # noqa: E731
    todo = [((name,), make, None, f) for name, make in EFFECTS if keep(name) for f in fault_sets]
    todo += [((name,), (lambda p: p), alter, f) for name, alter in recording_alterations() if keep(name)
             for f in fault_sets]
    if two_effects:
        todo += [(names, make, alter, Faults(0.3, 0.4, 0.3)) for names, make, alter in TWO_EFFECTS
                 if (effects is None or set(names) & set(effects))
                 and all(BY_NAME[n].applies_to(recorded) for n in names)]
    todo += [((), (lambda p: p), None, Faults(*rng.uniform(0.0, 1.0, 3))) for _ in range(n_noise)]
    # one untimed analysis first: on a fresh tree (an empty numba cache) the first case's start
    # diagnosis would otherwise be charged the kernels' compilation (measured: 5.5 s)
    t0 = time.perf_counter()
    analyse_fdi_test(reference_run(Faults(0.0, 0.0, 0.0), seed + 99, ref=ref), max_effects=1)
    warm_up_s = time.perf_counter() - t0
    # the machine's speed before and after (a shared machine drifts): the time figures compare by it
    machine = [monitor_run_s()]
    for i, (names, make, alter, f) in enumerate(todo):
        r = reference_run(f, seed + 100 + i, make, alter, ref)
        if without:
            r = dataclasses.replace(r, **{c: np.full(len(r.t), np.nan) for c in without})
        truth = f.as_dict()
        t0 = time.perf_counter()
        # as `eha-health discrepancy` runs it: up to its default number of effects (a second round
        # runs whenever the residual is still structured after the first effect), more for more
        rep = analyse_fdi_test(r, max_effects=max(len(names), DEFAULT_MAX_EFFECTS), truth=truth)
        # the channels an effect acts on (an in-loop one: position; a recording one: those it changes)
        chans = {c for n in names for c in (BY_NAME[n].recorded or ("position",))}
        chans = [c for c in recorded if c in chans] or ["position"]
        cases.append({
            "effect": "+".join(names) or None, "effects": list(names), "faults": truth, "selected": rep.selected,
            "verdict": rep.verdict, "ranked_first": rep.candidates[0].name if rep.candidates else None,
            "parameters": {k: v for e in rep.candidates if e.selected for k, v in e.parameters.items()},
            # candidates the record supports as well as a selected one (report.EQUIVALENT_DIC)
            "equivalent": [n for e in rep.candidates if e.selected for n in e.equivalent],
            "rms_before": rep.before.rms["position"], "rms_after": rep.after.rms["position"],
            "noise_position": rep.residual_before.channels["position"].noise_sd,
            "channels": chans,
            "excess_held_before": {c: rep.before.excess_held_out[c] for c in chans},
            "excess_held_after": {c: rep.after.excess_held_out[c] for c in chans},
            "err_before": max(rep.before.errors.values()), "err_after": max(rep.after.errors.values()),
            # each coefficient's error after over its stated standard error (are the error bars honest?)
            "z_after": {k: e / rep.after.std[k] if rep.after.std.get(k, 0) > 0 else None
                        for k, e in rep.after.errors.items()},
            "errors_after": dict(rep.after.errors), "std_after": {k: rep.after.std.get(k) for k in rep.after.errors},
            "runs": rep.runs, "refits": sum(c.refit for c in rep.candidates),
            # the loop's own time (the diagnosis it starts from excluded), and with the diagnosis
            "wall_time_s": rep.wall_time_s, "with_diagnosis_s": time.perf_counter() - t0})
        if progress:
            c = cases[-1]
            ch = c["channels"][0]
            progress(f"case {i + 1}/{len(todo)}: {c['effect'] or 'noise only'} -> {rep.verdict}; first "
                     f"{c['ranked_first']}; {ch} held-out excess {c['excess_held_before'][ch]:.3g} -> "
                     f"{c['excess_held_after'][ch]:.3g}; max|dK| {c['err_before']:.4f} -> {c['err_after']:.4f}; "
                     f"{c['runs']} runs, {c['wall_time_s']:.1f} s")
    machine.append(monitor_run_s())
    res = summarise(cases, seed)
    res["without"] = list(without)
    res["monitor_run_s"] = {"start": machine[0], "end": machine[1]}
    res["warm_up_s"] = warm_up_s
    return res


def summarise(cases: list[dict], seed: int) -> dict:
    one = [c for c in cases if len(c["effects"]) == 1]
    two = [c for c in cases if len(c["effects"]) > 1]
    noise = [c for c in cases if not c["effects"]]
    found = [c for c in one if c["selected"][:1] == c["effects"]]
    times = [c["wall_time_s"] for c in cases]
    whole = [c["with_diagnosis_s"] for c in cases if "with_diagnosis_s" in c]
    third = [all(c["excess_held_after"][ch] <= c["excess_held_before"][ch] / 3 for ch in c["channels"]) for c in found]
    share = lambda v: float(np.mean(v)) if len(v) else None   # noqa: E731
    return {
        "seed": seed, "cases": cases,
        "ranked_first_share": share([c["ranked_first"] == c["effects"][0] for c in one]),
        "selected_share": share([c["selected"][:1] == c["effects"] for c in one]),
        # the true effect selected, or named by the report as supported as well as the selected one
        # (a record that cannot tell two candidates apart: report.EQUIVALENT_DIC)
        "named_share": share([c["selected"][:1] == c["effects"] or
                              (len(c["selected"]) == 1 and c["effects"][0] in c.get("equivalent", [])) for c in one]),
        "two_effects_found_share": share([sorted(c["selected"]) == sorted(c["effects"]) for c in two]),
        # one-effect cases that select a second effect as well (the record holds one)
        "extra_effect_share": share([len(c["selected"]) > 1 for c in one]),
        "false_reports_share": share([bool(c["selected"]) for c in noise]),
        # noise-only runs whose residual was still structured against the floor (the monitor's own
        # form error): no effect named, but the verdict says the residual is unexplained
        "unexplained_noise_share": share([c["verdict"] == UNEXPLAINED for c in noise]),
        "wall_time_s": {"min": float(min(times)), "median": float(np.median(times)), "max": float(max(times))}
        if times else None,
        # what a user of `eha-health discrepancy` waits for: the start diagnosis and the loop
        "with_diagnosis_s": {"min": float(min(whole)), "median": float(np.median(whole)), "max": float(max(whole))}
        if whole else None,
        # the affected channel's held-out excess over noise and floor after <= 1/3 of before, where
        # the true effect was selected
        "third_share": share(third),
        "max_err_after_found": float(max(c["err_after"] for c in found)) if found else None,
        "err_within_0_03_share": share([c["err_after"] <= 0.03 for c in found]),
        # RMS over the found cases of error / stated standard error, per coefficient (1: honest bars)
        "z_rms_after_found": {k: float(np.sqrt(np.mean([c["z_after"][k] ** 2 for c in found])))
                              for k in (found[0]["z_after"] if found else {})
                              if all(c["z_after"].get(k) is not None for c in found)},
    }


def all_found(cases: list[dict]) -> list[dict]:
    """The cases with effects whose every effect was selected (single- and two-effect ones)."""
    return [c for c in cases if c["effects"] and set(c["effects"]) <= set(c["selected"])]


def fault_error_sd(res: dict, current: dict[str, float] | None = None) -> dict[str, float]:
    """The constant 1-sd term per fault coefficient that, added in quadrature to the stated standard
    errors, makes the RMS of error / standard error 1 over the cases where the true effects were all
    selected (0 where it is <= 1 already). ``current``: the term the run's stated errors already
    held (``Settings.fault_error``), taken out first."""
    found = all_found(res["cases"])
    out = {}
    for k in FAULT_NAMES:
        err = np.array([c["errors_after"][k] for c in found])
        cur = (current or {}).get(k, 0.0)
        std = np.sqrt(np.maximum(np.array([c["std_after"][k] for c in found]) ** 2 - cur ** 2, 1e-300))

        def excess(s0):
            return float(np.sqrt(np.mean((err / np.hypot(std, s0)) ** 2))) - 1.0
        out[k] = float(brentq(excess, 0.0, 1.0)) if len(found) and excess(0.0) > 0 else 0.0
    return out


#: Where the ``fault_error_sd`` block (its comment first) begins in data/discrepancy.yaml.
FAULT_ERROR_MARK = "# fault_error_sd:"


def with_fault_error_block(text: str, old: str) -> str:
    """``text`` (a settings file written by ``bench floor``) with the ``fault_error_sd`` block of
    ``old`` (the file it replaces) kept: that block is measured by ``bench discrepancy``."""
    return text + FAULT_ERROR_MARK + old.split(FAULT_ERROR_MARK, 1)[1] if FAULT_ERROR_MARK in old else text


def fault_error_yaml(text: str, sd: dict[str, float], command: str, n_cases: int) -> str:
    """``text`` (data/discrepancy.yaml) with its ``fault_error_sd`` block replaced by ``sd``."""
    keep = text.split(FAULT_ERROR_MARK)[0].rstrip("\n")
    lines = [FAULT_ERROR_MARK + " 1 sd per fault coefficient added in quadrature to the loop's stated error",
             "#        once an effect is in the model (its fits err more than the whole-test fit whose",
             f"#        measured terms the error already holds): RMS of error / error = 1 over the {n_cases}",
             "#        bench cases whose effects were all found. Made by:",
             f"#        {command}", "fault_error_sd:"] + [f"  {k}: {v:.3g}" for k, v in sd.items()]
    return keep + "\n" + "\n".join(lines) + "\n"


def format_synthetic(res: dict) -> str:
    lines = [f"{'effect':31s} {'faults (gm,fsj,bkl)':20s} {'ranked first':21s} {'selected':33s} "
             f"{'held-out excess before->after':>31s} {'max|dK| before->after':>22s} {'runs':>5s} {'time s':>7s}"]
    for c in res["cases"]:
        f = ",".join(f"{v:.2f}" for v in c["faults"].values())
        ch = c["channels"][0]
        k, u = DISPLAY_UNITS[ch]
        lines.append(f"{c['effect'] or '(noise only)':31s} {f:20s} {c['ranked_first'] or '-':21s} "
                     f"{','.join(c['selected']) or '-':33s} {ch[:3]} {c['excess_held_before'][ch] * k:10.3g} -> "
                     f"{c['excess_held_after'][ch] * k:8.3g} {u:4s}"
                     f"   {c['err_before']:9.4f} -> {c['err_after']:7.4f} {c['runs']:5d} {c['wall_time_s']:7.1f}")
    pct = lambda v: "-" if v is None else f"{100 * v:.0f} %"   # noqa: E731
    w = res["wall_time_s"] or {"min": 0, "median": 0, "max": 0}
    if res.get("without"):
        lines.append(f"records without {', '.join(res['without'])} (the recording effects on it left out)")
    lines.append(f"true effect ranked first: {pct(res['ranked_first_share'])} (target >= 95 %); "
                 f"selected: {pct(res['selected_share'])} (target >= 90 %); selected or named as equally "
                 f"supported: {pct(res.get('named_share'))}; two effects both found: "
                 f"{pct(res['two_effects_found_share'])}; a second effect added to one: "
                 f"{pct(res.get('extra_effect_share'))}; noise-only runs: false 'missing effect' "
                 f"{pct(res['false_reports_share'])} (target <= 5 %), 'unexplained' "
                 f"{pct(res.get('unexplained_noise_share'))} (target <= 5 %)")
    lines.append(f"time per analysis (the loop, the diagnosis it starts from excluded): min {w['min']:.1f} s, median "
                 f"{w['median']:.1f} s, max {w['max']:.1f} s (target <= 10 s)")
    if res.get("with_diagnosis_s"):
        d = res["with_diagnosis_s"]
        over = sum(c.get("with_diagnosis_s", 0.0) > 10.0 for c in res["cases"])
        lines.append(f"time per analysis with the diagnosis it starts from (what `eha-health discrepancy` takes, "
                     f"reading the record aside): min {d['min']:.1f} s, median {d['median']:.1f} s, max "
                     f"{d['max']:.1f} s; over 10 s in {over} of {len(res['cases'])}")
    if res.get("monitor_run_s"):
        m = res["monitor_run_s"]
        lines.append(f"this machine: one monitor run of the FDI test {1e3 * m['start']:.2f} ms at the start, "
                     f"{1e3 * m['end']:.2f} ms at the end (best of 15; the time figures of two machines compare by it)"
                     + (f"; timed after one untimed analysis ({res['warm_up_s']:.1f} s) that loads or compiles "
                        f"the kernels" if res.get("warm_up_s") is not None else ""))
    if res.get("third_share") is not None:
        lines.append(f"where the true effect was selected: affected channel's held-out excess after <= 1/3 of "
                     f"before in {pct(res['third_share'])}; coefficients within 0.03 in "
                     f"{pct(res['err_within_0_03_share'])}, max error after {res['max_err_after_found']:.4f}")
    if res.get("z_rms_after_found"):
        lines.append("their error / stated standard error after, RMS (1: honest error bars): "
                     + ", ".join(f"{k} {v:.2f}" for k, v in res["z_rms_after_found"].items()))
    return "\n".join(lines)
