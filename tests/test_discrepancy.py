"""Discrepancy loop: residual analysis, attribution, augmentation, import, rig data (issue 5)."""
import copy
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from eha_health import simulate
from eha_health.discrepancy.candidates import (BY_NAME, CANDIDATES, COMMAND_CHAIN, IN_LOOP_CANDIDATES, STRUCTURAL,
                                               overlapping)
from eha_health.discrepancy.evidence import projection_share
from eha_health.discrepancy.loop import analyse_fdi_test
from eha_health.discrepancy.report import EQUIVALENT_DIC, NO_MISSING_EFFECT, UNEXPLAINED, format_report
from eha_health.discrepancy.settings import fdi_settings
from eha_health.identification.knobs import FAULT_KNOBS
from eha_health.identification.local import least_squares
from eha_health.identification.problem import KnobModel, Problem
from eha_health.identification.record import Record
from eha_health.identification.residual import Residual
from eha_health.io.importer import ImportError_, import_text
from eha_health.physics.faults import FAULT_NAMES, Faults
from eha_health.physics.params import load
from eha_health.signals.residuals import analyse, ljung_box, noise_level, rest_noise_level

ROOT = Path(__file__).resolve().parents[1]
BAGS = ROOT / "bags"
TRUTH = yaml.safe_load((ROOT / "tests/data/undeclared.yaml").read_text())
MTS = ROOT.parent / "shared/data/mts_servohydraulic_chirp/0A.txt"
CLI = [sys.executable, "-m", "eha_health.cli"]


# ----------------------------------------------------------------------------- residual statistics
def test_noise_level_and_whiteness_on_known_signals():
    rng = np.random.default_rng(1)
    t = np.arange(5000) / 1000.0
    smooth = 1e-3 * np.sin(2 * np.pi * 2.0 * t)
    y = smooth + 5e-6 * rng.standard_normal(len(t))
    assert noise_level(y) == pytest.approx(5e-6, rel=0.1)
    _, p_white, _ = ljung_box(rng.standard_normal(4000), 20)
    _, p_col, _ = ljung_box(np.sin(2 * np.pi * 7.0 * t[:4000]), 20)
    assert p_white > 0.01 and p_col < 1e-6


def test_coloured_noise_is_measured_where_the_command_rests():
    # a logger's interference is coloured: second differences see only its top, the rest periods
    # (command still, here 3 s before and after a 2 Hz sine) show all of it
    from scipy.signal import butter, sosfiltfilt
    rng = np.random.default_rng(3)
    t = np.arange(11000) / 1000.0
    cmd = np.where((t >= 3.0) & (t < 8.0), 2e-3 * np.sin(2 * np.pi * 2.0 * (t - 3.0)), 0.0)
    cmd = cmd + 5e-6 * rng.standard_normal(len(t))          # the command channel's own interference
    n = sosfiltfilt(butter(2, 30.0, fs=1000.0, output="sos"), rng.standard_normal(len(t)))
    y = 0.9 * cmd + 20e-6 * n / n.std()
    assert noise_level(y) < 0.5 * 20e-6
    assert rest_noise_level(y, cmd, 1000.0) == pytest.approx(20e-6, rel=0.1)
    assert rest_noise_level(y, cmd + t, 1000.0) == 0.0        # never at rest: no estimate
    a = analyse(t, {"position": y}, {"position": 0.9 * cmd}, noise={"position": rest_noise_level(y, cmd, 1000.0)})
    assert a.channels["position"].noise_sd == pytest.approx(20e-6, rel=0.1) and a.verdict == "noise"


def test_analysis_tells_noise_from_structure():
    rng = np.random.default_rng(2)
    t = np.arange(3500) / 1000.0
    meas = {"position": 1e-3 * np.sin(2 * np.pi * t) + 5e-6 * rng.standard_normal(len(t))}
    clean = {"position": 1e-3 * np.sin(2 * np.pi * t)}
    assert analyse(t, meas, clean).verdict == "noise"
    shifted = {"position": 1e-3 * np.sin(2 * np.pi * (t - 0.005))}
    a = analyse(t, meas, shifted, {"all": np.ones(len(t), bool)})
    assert a.verdict == "structured" and "Ljung-Box" in a.evidence[0]


def test_projection_share_finds_the_right_column():
    rng = np.random.default_rng(3)
    J = rng.standard_normal((500, 3))
    s_true, s_other = rng.standard_normal(500), rng.standard_normal(500)
    r = J @ [0.1, -0.2, 0.3] + 2.0 * s_true + 0.01 * rng.standard_normal(500)
    assert projection_share(J, s_true[:, None], r) > 0.99
    assert projection_share(J, s_other[:, None], r) < 0.05


# ----------------------------------------------------------------------------- the loop, synthetic
def _noisy_run(params, faults, seed):
    return simulate(params=params.with_effect_names(["sensor_noise"]), faults=faults, seed=seed)


@pytest.mark.parametrize("name,plant,faults,knob,value", [
    ("sensor_delay", lambda p: p.with_effect_names(["sensor_delay"]), Faults(0.3, 0.4, 0.2), "delay", 1e-3),
    ("load_stiffness", lambda p: p.updated("surface", hinge_stiffness=1.6e5), Faults(0.5, 0.0, 0.3),
     "extra_stiffness", 8e4),
    # shows on the ramp, hardly on the held-out sines: selected on the held-out power above noise
    ("sensor_bias", lambda p: p.with_effects(sensor_calibration={"enabled": True, "bias": 2e-4}),
     Faults(0.3, 0.4, 0.3), "bias", 2e-4),
    # the reference's pilot stage slows with the supply: the candidate carries that physics
    ("supply_pressure", lambda p: p.updated("hydraulics", supply_pressure=14e6), Faults(0.4, 0.5, 0.0),
     "sag", (20.7e6 - 14e6) / (20.7e6 - 0.3e6)),
    ("flow_asymmetry", lambda p: p.updated("hydraulics", flow_asymmetry=0.1), Faults(0.3, 0.4, 0.3),
     "asymmetry", 0.1),
    # no candidate of that name: a clogged first-stage filter drops the pilot supply, which the
    # supply candidate's pilot-flow physics explains, sized as the pilot pressure drop (the slower
    # spool explains it as well: the report names both)
    ("supply_pressure", lambda p: p.updated("flapper_nozzle", clogging=0.3), Faults(0.3, 0.4, 0.2), "sag", 0.3),
    # a spool 1.6x slower (its end area): beyond what a supply sag can mimic, whose pressure limit
    # would then bind (it was named sensor_delay, the faults 0.06 off, before valve_response)
    ("valve_response", lambda p: p.updated("flapper_nozzle", spool_end_area=p.flapper_nozzle.spool_end_area * 1.6),
     Faults(0.3, 0.4, 0.3), "valve_slowdown", 0.6),
    # a two-knob mechanism (null shift per unit vibration, null bias at rest) with backlash impacts
    ("vibration_null_shift", lambda p: p.with_effects(vibration_null_shift={"enabled": True, "gain": 1e-4}),
     Faults(0.3, 0.4, 0.3), "null_shift_per_accel", 1e-4),
    # the loop's nominal parameters: a heavier load, a position gain set high, a velocity feedback set high
    ("load_mass", lambda p: p.updated("surface", mass=22.5), Faults(0.2, 0.5, 0.1), "extra_load_mass", 7.5),
    ("controller_gain", lambda p: p.updated("controller", kp=p.controller.kp * 1.15), Faults(0.2, 0.5, 0.1),
     "position_gain_error", 0.15),
])
def test_undeclared_effect_is_found_sized_and_unbiases_the_faults(name, plant, faults, knob, value):
    r = _noisy_run(plant(load("reference")), faults, seed=21)
    truth = dict(zip(FAULT_NAMES, faults.as_tuple()))
    rep = analyse_fdi_test(r, max_effects=1, truth=truth)
    assert rep.residual_before.verdict == "structured"
    assert rep.candidates[0].name == name and rep.selected == [name]
    assert rep.candidates[0].parameters[knob] == pytest.approx(value, rel=0.1)
    assert rep.after.rms["position"] <= rep.before.rms["position"] / 3
    assert max(rep.after.errors.values()) <= 0.03
    assert max(rep.before.errors.values()) > max(rep.after.errors.values())
    # an equally supported alternative may only be a candidate that shares the physics
    alike = rep.candidates[0].equivalent
    assert set(alike) <= set(overlapping(name, CANDIDATES))
    assert rep.verdict == f"model lacks: {name}" + (
        f" ({name} or {', '.join(alike)}: as well supported, the record does not tell them apart)" if alike else "")


def test_a_slower_spool_and_a_supply_sag_are_both_named_where_the_record_cannot_tell_them_apart():
    """A spool 1.4x slower at (0.4, 0.5, 0): a supply sag slows the spool alike (its pilot flow),
    and the sagged supply's pressure limit is not reached -- the two refits fit within dIC 2. The
    report names both, each with its fitted faults, and the faults are right with either."""
    faults = Faults(0.4, 0.5, 0.0)
    ref = load("reference")
    r = _noisy_run(ref.updated("flapper_nozzle", spool_end_area=ref.flapper_nozzle.spool_end_area * 1.4), faults,
                   seed=149)
    rep = analyse_fdi_test(r, max_effects=1, truth=faults.as_dict())
    ev = {e.name: e for e in rep.candidates}
    first = rep.candidates[0]
    assert {first.name, *first.equivalent} == {"valve_response", "supply_pressure"}
    assert rep.selected == [first.name] and "the record does not tell them apart" in rep.verdict
    other = ev[first.equivalent[0]]
    assert abs(other.delta_ic - first.delta_ic) <= EQUIVALENT_DIC and other.refit
    assert "as well supported as the selected" in other.note and "k_gm" in other.note
    assert ev["valve_response"].parameters["valve_slowdown"] == pytest.approx(0.4, rel=0.1)
    assert max(rep.after.errors.values()) <= 0.03 < max(rep.before.errors.values())
    assert f"{first.name} is not the only explanation" in format_report(rep)


def test_two_undeclared_effects_are_both_found_and_sized():
    p = load("reference").with_effects(sensor_delay={"enabled": True, "delay": 5e-4}).updated("controller", null_bias=2e-4)
    faults = Faults(0.3, 0.4, 0.2)
    rep = analyse_fdi_test(_noisy_run(p, faults, seed=78), max_effects=2, truth=dict(zip(FAULT_NAMES, faults.as_tuple())))
    assert sorted(rep.selected) == ["sensor_delay", "valve_null_bias"]
    assert rep.after.values["delay"] == pytest.approx(5e-4, rel=0.1)
    assert rep.after.values["null_bias"] == pytest.approx(2e-4, rel=0.1)
    assert max(rep.after.errors.values()) <= 0.03 < max(rep.before.errors.values())


def test_no_second_effect_invented_after_the_true_one():
    # at K_BKL = 0.7 the monitor's own form error is larger than the floor: a small flow
    # asymmetry (0.0017) used to bend to it in round 2; the held-out data must now show it too
    p = load("reference").updated("controller", null_bias=1e-4)
    faults = Faults(0.2, 0.3, 0.7)
    rep = analyse_fdi_test(_noisy_run(p, faults, seed=77), max_effects=2, truth=dict(zip(FAULT_NAMES, faults.as_tuple())))
    assert rep.selected == ["valve_null_bias"]
    assert rep.after.values["null_bias"] == pytest.approx(1e-4, rel=0.1)
    # K_BKL's error bar carries the measured error of a whole-test fit (a saw-tooth in K_BKL: ~0.002
    # at K_BKL 0.7, 3-5x the Gauss-Newton term) and covers the truth (measured: error 0.0016, Gauss-
    # Newton alone said 0.0001)
    from eha_health.identification.uncertainty import model_error
    x = [rep.after.values[n] for n in FAULT_NAMES]
    assert rep.after.std["k_bkl"] >= model_error(estimate=x, method="deterministic")[2] > 0.0015
    assert rep.after.errors["k_bkl"] <= 2 * rep.after.std["k_bkl"], (rep.after.errors, rep.after.std)


def test_a_nested_candidate_whose_extra_knob_is_zero_gives_way_to_the_simpler_one():
    # a plain null bias with backlash: vibration_null_shift (a null bias at rest plus a shift with
    # the vibration) refitted to a shift 0.2 sd from zero and ranked first by its refit's path
    # (held-out x0.020 against x0.036); with no shift it *is* valve_null_bias, which is named
    p = load("reference").updated("controller", null_bias=3e-4)
    faults = Faults(0.3, 0.4, 0.3)
    rep = analyse_fdi_test(_noisy_run(p, faults, seed=120), max_effects=1, truth=dict(zip(FAULT_NAMES, faults.as_tuple())))
    assert rep.selected == ["valve_null_bias"] and rep.candidates[0].name == "valve_null_bias"
    assert rep.after.values["null_bias"] == pytest.approx(3e-4, rel=0.05)
    assert max(rep.after.errors.values()) <= 0.03
    nested = next(c for c in rep.candidates if c.name == "vibration_null_shift")
    assert abs(nested.parameters["null_shift_per_accel"]) <= 2 * nested.std["null_shift_per_accel"]
    assert "valve_null_bias" in nested.note and not rep.candidates[0].note


def test_no_missing_effect_on_noise_only_data():
    for seed, faults in ((31, Faults(0.2, 0.6, 0.1)), (32, Faults(0.0, 0.0, 0.0))):
        rep = analyse_fdi_test(_noisy_run(load("reference"), faults, seed), max_effects=1)
        assert rep.selected == [] and rep.verdict == NO_MISSING_EFFECT
        assert rep.after.values == rep.before.values


def test_limit_cycle_effect_is_found_from_the_base_re_identified_with_it():
    # compressibility with backlash: a ~43 Hz limit cycle whose phase only matches near the true
    # faults, while the diagnosis without compressibility sits at K_BKL ~0.01; no local refit from
    # there passes, so round 1 re-identifies the faults with each candidate in the model
    faults = Faults(0.3, 0.4, 0.3)
    rep = analyse_fdi_test(_noisy_run(load("reference").with_effect_names(["compressibility"]), faults, seed=5),
                           max_effects=1, truth=dict(zip(FAULT_NAMES, faults.as_tuple())))
    assert max(rep.before.errors.values()) > 0.2
    assert rep.selected == ["compressibility"]
    assert max(rep.after.errors.values()) <= 0.03
    assert rep.after.rms["position"] <= rep.before.rms["position"] / 3
    assert rep.after.values["oil_compliance"] == pytest.approx(1.0, rel=0.15)


def test_structured_residual_no_candidate_explains_is_said_not_hidden():
    # the surface's hinge friction 200 N instead of 300 N at (0.3, 0.4, 0.3) (tools/unlisted_effects.py's
    # case, noise seed 777): no candidate holds it -- a known miss; the residual is structured, so
    # the verdict must not read as if it were noise. (Until the refits' healthy corners the case
    # here was a soft mount without faults, noise seed 130: its refit now reaches K_BKL 0 and it
    # is found.)
    rep = analyse_fdi_test(_noisy_run(load("reference").updated("surface", hinge_friction=200.0), Faults(0.3, 0.4, 0.3),
                                      seed=777), max_effects=1)
    assert rep.residual_before.structured
    assert rep.selected == [] and rep.verdict == UNEXPLAINED
    # the verdict says where the structure lives and which coefficients it is likely to bias
    where = rep.unexplained["where"]
    assert any(w.startswith(c) for w in where for c in rep.residual_before.channels
               if rep.residual_before.channels[c].structured)
    shifts, undetermined = rep.unexplained["segment_shifts"], rep.unexplained["undetermined"]
    assert set(shifts) == set(FAULT_NAMES)
    # every segment either moves a coefficient (a finite shift within its range) or is said not to determine it
    assert all(set(v) | set(undetermined.get(k, [])) == {"ramp", "step", "return", "sine_low", "sine_high"} for k, v in shifts.items())
    assert all(abs(d) <= 1.5 for v in shifts.values() for d in v.values())
    assert rep.unexplained["bias"] and rep.as_dict()["unexplained"] == rep.unexplained


def test_a_segment_blind_to_a_knob_does_not_size_its_bias():
    # the step segment holds no reversal: backlash's column there is finite-difference noise
    # (3.8e-11 on the coloured-noise probe of tools/unlisted_effects.py), and its linearised shift
    # had read K_BKL +2.2e8 in the report
    from eha_health.discrepancy.loop import fdi_segments
    from eha_health.discrepancy.structure import locate
    from eha_health.identification.result import FitResult
    from eha_health.signals.residuals import ResidualAnalysis
    rec = Record.from_response(simulate(kind="monitor", faults=Faults(0.3, 0.4, 0.3)))
    res, segs = Residual(rec), fdi_segments(rec)
    nc, rows = len(res.channels), int(res.mask.sum()) * len(res.channels)
    rng = np.random.default_rng(4)
    J, r = rng.normal(size=(rows, 3)), 0.01 * rng.normal(size=rows)
    step = np.repeat(segs["step"][res.mask], nc)
    J[step, 2] = 1e-12 * rng.normal(size=int(step.sum()))      # K_BKL invisible on the step
    fit = FitResult(x=np.zeros(3), names=tuple(FAULT_NAMES), free=np.arange(3), cost=float(r @ r), runs=0,
                    residual=r, jacobian=J)
    out = locate(res, fit, ResidualAnalysis({}, "structured"), segs, 3,
                 spans={n: 1.5 for n in FAULT_NAMES})
    assert out["undetermined"] == {"k_bkl": ["step"]}
    assert "step" not in out["segment_shifts"]["k_bkl"] and "step" in out["segment_shifts"]["k_gm"]
    assert all(abs(v) < 1.5 for d in out["segment_shifts"].values() for v in d.values())


def test_same_input_same_report():
    r = _noisy_run(load("reference").with_effect_names(["sensor_delay"]), Faults(0.2, 0.2, 0.2), seed=5)
    a, b = (analyse_fdi_test(r, max_effects=1) for _ in range(2))
    assert [c.name for c in a.candidates] == [c.name for c in b.candidates]
    assert a.after.values == b.after.values


def test_fit_recovers_an_effect_parameter_on_a_model_generated_record():
    mon = load("monitor")
    truth = mon.with_effects(sensor_delay={"enabled": True, "delay": 1.5e-3})
    r = simulate(kind="monitor", params=truth, faults=Faults(0.2, 0.3, 0.0))
    rec = Record.from_response(r)
    m = KnobModel(mon, FAULT_KNOBS, rec).extended(BY_NAME["sensor_delay"].knobs)
    # a local method: started where the loop starts it (faults near a diagnosis, the knob in its basin: the loop's grid scan finds the basin)
    f = least_squares(Problem(m, Residual(rec)), [0.18, 0.28, 0.0, 1.4e-3], max_nfev=100)
    assert f.values()["delay"] == pytest.approx(1.5e-3, abs=2e-5)
    assert f.values()["k_fsj"] == pytest.approx(0.3, abs=5e-3)


def test_fit_never_returns_worse_than_its_start():
    # stick-slip at K_FSJ ~0.94 makes the cost so rough in the leakage that the trust region
    # walks off; the fit must then hand back its start, not the far worse last iterate
    f = Faults(0.9584188147186233, 0.9424981549525219, 0.20057359524226082)
    rec = Record.from_response(simulate(params=load("reference").updated("hydraulics", leakage=5e-12), faults=f))
    m = KnobModel(load("monitor"), FAULT_KNOBS + BY_NAME["leakage"].knobs, rec)
    res = Residual(rec)
    x0 = [*f.as_tuple(), 4.96e-12]
    start = res.cost(m.run(x0)[0])
    got = least_squares(Problem(m, res), x0, max_nfev=40)
    assert np.isfinite(got.cost) and got.cost <= start
    assert got.cost == pytest.approx(res.cost(m.run(got.x)[0]))
    held = least_squares(Problem(m, res, free=[]), x0)       # nothing free: the model evaluated where it stands
    assert list(held.x) == x0 and held.cost == pytest.approx(start) and held.jacobian.shape[1] == 0


def test_settings_floor_grows_with_the_effects_added():
    st = fdi_settings()
    # bench floor measured every candidate: in-loop ones in the plant, recording ones (the recorded
    # command's chain too) on the record altered after the test. A recording effect changes no
    # simulated physics, but undone on the record it leaves a form error of its own (a time base
    # resampled: 2x the base floor on the current; the command off its zero moves the operating point)
    assert set(st.effect_floor) == {c.name for c in CANDIDATES}
    assert st.floor_with(["time_base"])["current"] > st.floor["current"]
    assert st.floor_with(list(COMMAND_CHAIN))["position"] > st.floor["position"]
    base = st.floor_with([])
    assert base == st.floor
    both = st.floor_with(["compressibility", "sensor_delay"])
    for c in base:
        assert both[c] == max(base[c], st.effect_floor["compressibility"][c], st.effect_floor["sensor_delay"][c])


def test_candidate_library_covers_the_mechanisms():
    names = {c.name for c in CANDIDATES}
    assert {"compressibility", "sensor_delay", "sensor_bias", "sensor_gain", "supply_pressure", "viscous_friction",
            "stribeck", "valve_null_bias", "load_stiffness", "leakage", "load_mass", "controller_gain",
            "velocity_feedback", "valve_response"} <= names
    assert all(set(c.overlaps) <= names - {c.name} for c in CANDIDATES)
    p = load("monitor")
    for c in IN_LOOP_CANDIDATES + STRUCTURAL:   # every knob value in range builds a valid model
        for k in c.knobs:
            assert k.lo <= k.typical <= k.hi
            k.apply(p, k.typical)
            k.apply(p, k.lo)
            k.apply(p, k.hi)


# ----------------------------------------------------------------------------- bags without truth
def _cli_json(*args, timeout=300):
    p = subprocess.run(CLI + list(args), capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


#: Measured misses on a committed bag, with the figures in docs/discrepancy.md; any other miss fails.
#: Compressibility: the position residual before is only ~2x the 5 um sensor noise (the effect shows
#: in pressure and current), so after/before cannot reach 1/3. (The compliance, once 20 % low from a
#: local minimum of the whole-record fit, is now sized within 15 %: the final re-scan finds 1.04.)
KNOWN_MISSES = {"undeclared_compressibility.mcap": ("position RMS",)}


@pytest.mark.parametrize("bag", sorted(TRUTH))
def test_committed_undeclared_bags(bag, tmp_path):
    t = TRUTH[bag]
    png = tmp_path / "d.png"
    out = _cli_json("discrepancy", str(BAGS / bag), "--json", "--plot", str(png))
    assert "truth" not in out              # the bag does not declare it
    assert out["selected"] == [t["effect"]]   # one effect in the plant: nothing invented beside it
    for k, v in t["faults"].items():
        assert abs(out["after"]["values"][k] - v) <= 0.03, (k, out["after"]["values"][k], v)
    assert png.stat().st_size > 10_000
    before, after = out["before"]["rms"]["position"], out["after"]["rms"]["position"]
    misses = []
    for k, v in t["parameters"].items():
        got = out["after"]["values"][k]
        if got != pytest.approx(v, rel=0.15):
            misses.append(f"{k} {got:.4g} (true {v:.4g}, target within 15 %)")
    if after > before / 3:
        misses.append(f"position RMS {before * 1e6:.2f} -> {after * 1e6:.2f} um (target <= 1/3)")
    known = KNOWN_MISSES.get(bag, ())
    assert not [m for m in misses if not m.startswith(known)], misses
    if misses:
        pytest.xfail("; ".join(misses))


def test_committed_noisy_bag_has_no_missing_effect():
    out = _cli_json("discrepancy", str(BAGS / "combined_noisy.mcap"), "--json", "--max-effects", "1")
    assert out["selected"] == [] and out["verdict"] == NO_MISSING_EFFECT
    assert out["mode"] == "fdi" and "mode_reason" not in out
    assert {"before", "after", "candidates", "selected"} <= set(out)
    assert set(out["before"]["rms"]) == {"position", "velocity", "pressure", "current"}


def test_an_fdi_test_without_a_channel_is_still_an_fdi_analysis(tmp_path):
    # a CSV without the current column, its pressure transducer 0.5 MPa off: the FDI loop on the
    # three channels it has names the offset and gives the faults back; nothing acts on current
    truth = Faults(0.3, 0.4, 0.3)
    r = simulate(faults=truth, params=load("reference").with_effect_names(["sensor_noise"]), seed=11)
    cols = ["t", "command", "position", "velocity", "pressure"]
    data = np.column_stack([getattr(r, c) for c in cols])
    data[:, 4] += 5e5
    csv = tmp_path / "no_current.csv"
    np.savetxt(csv, data, delimiter=",", header=",".join(cols), comments="")
    p = subprocess.run(CLI + ["discrepancy", str(csv), "--json", "--max-effects", "1"], capture_output=True,
                       text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["mode"] == "fdi" and "mode_reason" not in out and out["not_recorded"] == ["current"]
    assert "note: current not in the record" in p.stderr and "rig" not in p.stderr
    assert set(out["before"]["rms"]) == {"position", "velocity", "pressure"}
    assert out["selected"] == ["pressure_offset"]
    assert not [c["name"] for c in out["candidates"] if c["name"].startswith("current_")]
    assert max(abs(out["after"]["values"][n] - v) for n, v in truth.as_dict().items()) <= 0.03
    assert abs(out["after"]["values"]["pressure_offset"] - 5e5) <= 0.05 * 5e5


def test_a_record_whose_command_is_not_the_fdi_sequence_is_a_rig_record():
    from eha_health.cli.analysis import discrepancy_mode
    r = simulate(faults=Faults(0.2, 0.3, 0.1))
    assert discrepancy_mode(r) == ("fdi", "")
    t = np.asarray(r.t)
    chirp = 2e-3 * np.sin(2 * np.pi * (0.5 + 2.0 * t) * t)          # a rig's chirp over the same 3.5 s
    mode, why = discrepancy_mode(dataclasses.replace(r, command=chirp))
    assert mode == "rig" and why.startswith("its command is not the FDI sequence (RMS difference from it ")
    # a late command (3 ms) or a clock 1 % fast is still the FDI test: the loop names them
    late = np.interp(t - 3e-3, t, r.command)
    assert discrepancy_mode(dataclasses.replace(r, command=late))[0] == "fdi"
    assert discrepancy_mode(dataclasses.replace(r, command=np.interp(t * 1.01, t, r.command)))[0] == "fdi"
    # the FDI sequence's command in a record cut short is an FDI test that cannot be analysed, not a rig's
    with pytest.raises(ValueError, match=r"record covers 3\.000 s but the FDI sequence lasts 3\.5 s"):
        discrepancy_mode(r.sliced(slice(0, 3000)))


# ----------------------------------------------------------------------------- import
def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_import_with_a_channel_map_and_units(tmp_path):
    t = np.arange(400) / 500.0
    rows = "\n".join(f"{i},{1e3 * 0.002 * np.sin(ti):.6f},{1e3 * 0.0019 * np.sin(ti - 0.1):.6f},{0.5 * ti:.6f}"
                     for i, ti in enumerate(t))
    data = _write(tmp_path, "rig.txt", "idx,cmd_mm,pos_mm,force_kN\n" + rows + "\n")
    m = _write(tmp_path, "map.yaml", yaml.safe_dump({
        "delimiter": ",", "skip_rows": 1, "header_row": 0, "sample_rate": 500.0,
        "channels": {"command": {"column": "cmd_mm", "unit": "mm"}, "position": {"column": 2, "unit": "mm"},
                     "load": {"column": "force_kN", "unit": "kN"}}}))
    r = import_text(data, m)
    assert len(r.t) == 400 and r.sample_rate == pytest.approx(500.0)
    assert np.max(np.abs(r.command - 0.002 * np.sin(t))) < 1e-8
    assert r.load[-1] == pytest.approx(0.5 * t[-1] * 1e3, rel=1e-5)
    assert np.isnan(r.pressure).all() and r.meta["measured"] == ["position"]
    csv = tmp_path / "run.csv"
    p = subprocess.run(CLI + ["import", str(data), "--map", str(m), "--out", str(csv)], capture_output=True,
                       text=True, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    from eha_health.signals.response import Response
    back = Response.from_csv(csv, required=("t", "command", "position"))
    assert np.allclose(back.position, r.position) and np.allclose(back.load, r.load)
    # a logger's export with a byte-order mark first (the header's first name is not '\ufeffidx')
    bom = tmp_path / "rig_bom.txt"
    bom.write_bytes(b"\xef\xbb\xbf" + data.read_bytes())
    m2 = _write(tmp_path, "map2.yaml", yaml.safe_dump({
        "delimiter": ",", "skip_rows": 1, "header_row": 0, "sample_rate": 500.0,
        "channels": {"command": {"column": "idx", "unit": "mm"}, "position": {"column": "pos_mm", "unit": "mm"}}}))
    assert np.allclose(import_text(bom, m2).command, 1e-3 * np.arange(400))
    # the same record as an MCAP bag: command and joint state only (no pressure or current topic,
    # empty velocity), the load cell in the joint state's effort; read back as a measured record
    bag = tmp_path / "run.mcap"
    p = subprocess.run(CLI + ["import", str(data), "--map", str(m), "--out", str(bag)], capture_output=True,
                       text=True, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    from eha_health.io.bagrun import read_run
    from eha_health.io.mcaplog import read_bag
    assert set(read_bag(bag, topics=[]).types) == {"/eha/command", "/eha/joint_state", "/eha/test_window"}
    run = read_run(bag, record=True)
    assert np.array_equal(run.response.position, r.position) and np.array_equal(run.response.load, r.load)
    assert np.allclose(run.response.t, r.t, atol=1e-12) and np.isnan(run.response.velocity).all()
    with pytest.raises(ValueError, match="missing topic eha/pressure"):   # not an FDI test of the contract
        read_run(bag)
    # a channel measured only in part cannot be written (nothing is invented)
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    r.velocity = np.where(r.t < 0.2, 0.0, np.nan)
    with BagWriter(tmp_path / "part.mcap") as w, pytest.raises(ValueError, match="velocity is measured only in part"):
        write_run(w, r)


@pytest.mark.parametrize("change,expect", [
    ({"channels": {"command": {"column": 1, "unit": "mm"}}}, "channel position is required"),
    ({"channels": {"command": {"column": 1, "unit": "N"}, "position": {"column": 2, "unit": "mm"}}},
     "is not a length unit"),
    ({"channels": {"command": {"column": 1, "unit": "mm"}, "position": {"column": 9, "unit": "mm"}}},
     "channel position is column 9"),
    ({"channels": {"command": {"column": 1}, "position": {"column": 2, "unit": "mm"}}}, "'unit' missing"),
    ({"channels": {"command": {"column": 1, "unit": "mm"}, "position": {"column": "nope", "unit": "mm"}}},
     "is a name but no header_row"),
    ({"sample_rate": -1.0}, "sample_rate must be a positive number"),
    ({"channels": {"command": {"column": 1, "unit": "mm"}, "position": {"column": 2, "unit": "mm"},
                   "torque": {"column": 3, "unit": "N"}}}, "unknown channel 'torque'"),
])
def test_import_bad_map_is_one_clear_line(tmp_path, change, expect):
    rows = "\n".join(f"{i},{i * 0.01},{i * 0.01},{i}" for i in range(200))
    data = _write(tmp_path, "d.txt", rows + "\n")
    base = {"sample_rate": 1000.0, "channels": {"command": {"column": 1, "unit": "mm"},
                                                "position": {"column": 2, "unit": "mm"}}}
    base.update(change)
    m = _write(tmp_path, "m.yaml", yaml.safe_dump(base))
    with pytest.raises(ImportError_, match=expect.replace("(", r"\(").replace("'", ".")):
        import_text(data, m)
    p = subprocess.run(CLI + ["import", str(data), "--map", str(m), "--out", str(tmp_path / "o.csv")],
                       capture_output=True, text=True, cwd=ROOT)
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr


def test_import_bad_numbers_name_the_row(tmp_path):
    rows = [f"{i},{i * 0.01},{i * 0.01}" for i in range(200)]
    rows[57] = "57,abc,0.5"
    data = _write(tmp_path, "d.txt", "\n".join(rows) + "\n")
    m = _write(tmp_path, "m.yaml", yaml.safe_dump({"sample_rate": 1000.0, "channels": {
        "command": {"column": 1, "unit": "mm"}, "position": {"column": 2, "unit": "mm"}}}))
    with pytest.raises(ImportError_, match="data row 58, column 1 \\(command\\): 'abc' is not a number"):
        import_text(data, m)


# ----------------------------------------------------------------------------- real rig data
@pytest.mark.skipif(not MTS.is_file(), reason="../shared/data (real MTS rig data) is not beside the repository")
def test_real_rig_import_and_loop(tmp_path):
    csv = tmp_path / "mts.csv"
    p = subprocess.run(CLI + ["import", str(MTS), "--map", str(ROOT / "maps/mts_servohydraulic.yaml"),
                              "--out", str(csv)], capture_output=True, text=True, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    out = _cli_json("discrepancy", str(csv), "--json", timeout=900)
    assert out["mode"] == "rig"
    assert out["mode_reason"].startswith("its command is not the FDI sequence (RMS difference from it 10")
    bag = tmp_path / "mts.mcap"     # the same record through the MCAP topic contract reads back the same
    p = subprocess.run(CLI + ["import", str(MTS), "--map", str(ROOT / "maps/mts_servohydraulic.yaml"),
                              "--out", str(bag)], capture_output=True, text=True, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    from eha_health.io.bagrun import read_run
    from eha_health.signals.response import Response
    a, b = read_run(bag, record=True).response, Response.from_csv(csv, required=("t", "command", "position"))
    assert np.allclose(a.position, b.position, rtol=0, atol=1e-12) and np.allclose(a.load, b.load, atol=1e-9)
    b = out["before"]
    assert set(b["rms"]) == {"position"}
    # the calibrated nominal loop is physical: a positive loop gain, a valve time constant of ms
    assert 0.1 < b["values"]["loop_gain"] < 100 and 1e-4 < b["values"]["valve_time_constant"] < 0.05
    # it predicts the held-out (unseen, higher-frequency) 30 % to well under the 1.4 mm command RMS
    assert b["rms_held_out"]["position"] < 1e-4
    assert out["after"]["rms_held_out"]["position"] <= b["rms_held_out"]["position"] * 1.0001
    # the calibrated model leaves a structured residual (offset, gain error above the fit band):
    # whatever the loop makes of it, it must not be reported as noise
    assert out["residual_before"]["verdict"] == "structured" and out["verdict"] != NO_MISSING_EFFECT
    # the position channel's noise, measured where the command rests (0-5 s, 59.4-61.5 s), is
    # coloured logger interference of ~25 um, well above its white part (~11 um)
    assert 20e-6 < out["residual_before"]["channels"]["position"]["noise_sd"] < 30e-6
    # the offset between command and position is ~85 um at rest and shrinks as the chirp speeds up:
    # a valve null that shifts with the vibration level. It is found, and it predicts the held-out
    # part (up to 20 Hz, then rest) from the first 70 %. What is left in the time domain is within
    # 1.5x the interference, but the held-out frequency response is not (gain low by 5 % at 19-21 Hz,
    # many times the estimate's scatter): round 2 runs on that evidence and finds the loop's
    # transport delay (ms: it replaces most of the valve lag), after which the held-out excess over
    # noise is at most half of before (issue 15's rig target) and the gain error within 2 % in
    # every coherent band
    assert out["selected"] == ["vibration_null_shift", "sensor_delay"]
    fe = out["frequency_evidence"]
    assert [f["gates"] for f in fe] == ["time domain", "frequency response"] and fe[1]["significant"]
    delay = next(c for c in out["candidates"] if c["round"] == 2 and c["selected"])
    assert delay["frequency_ratio"] <= 0.5 and delay["delta_ic"] < 0
    a = out["after"]["values"]
    assert 1e-3 < a["delay"] < 5e-3
    assert out["after"]["excess_held_out"]["position"] <= 0.5 * b["excess_held_out"]["position"]
    assert all(abs(band["gain_ratio"]["after"] - 1.0) <= 0.02 for band in out["frequency_response"])
    # physically plausible: x - x_cmd = i_null / kp at rest, -85 um measured; a shift of the order
    # of 10 um per m/s^2 of mean |acceleration| (the chirp reaches ~5 m/s^2), toward the command
    assert -120e-6 < a["rest_null_bias"] / a["loop_gain"] < -50e-6
    assert 2e-6 < a["null_shift_per_accel"] / a["loop_gain"] < 3e-5
    # frequency response over the chirp's band: measured gain falls with frequency (a low-pass loop)
    # and the calibrated model, fitted on the first 70 % only, tracks it in gain and phase
    fr = out["frequency_response"]
    assert len(fr) >= 6 and fr[0]["f_lo"] < 2.0 and fr[-1]["f_hi"] > 18.0
    g = [b["gain"]["measured"] for b in fr]
    assert all(a > b for a, b in zip(g, g[1:]))
    assert all(0.9 < b["gain_ratio"]["before"] < 1.1 and abs(b["phase_error_deg"]["before"]) < 5.0 for b in fr)


# ----------------------------------------------------------------------------- monitor node
@pytest.mark.graph
def test_monitor_node_warns_what_the_model_lacks(tmp_path):
    from eha_health.io.mcaplog import read_bag
    from eha_health.ros.graph import Graph
    log = tmp_path / "m.mcap"
    with Graph(faults=Faults(0.0, 0.0, 0.0), effects=("sensor_delay",), log_path=log, discrepancy=True) as g:
        r = g.run_test()
    assert r["level"] == "WARN" and "model lacks: sensor_delay" in r["message"]
    assert r["discrepancy"].after.rms["position"] < r["discrepancy"].before.rms["position"] / 3
    meta = read_bag(log, topics=[]).metadata
    assert json.loads(meta["discrepancy/test_1"]["selected"]) == ["sensor_delay"]


@pytest.mark.graph
def test_monitor_node_warns_when_no_candidate_explains_a_structured_residual(tmp_path):
    from eha_health.ros.graph import Graph
    # undeclared: the surface's hinge friction 200 N, the monitor's 300 N -- no candidate holds it
    # (until the refits' healthy corners this was a soft mount at faults 0, now found)
    hinge = tmp_path / "hinge_friction.yaml"
    hinge.write_text("surface:\n  hinge_friction: 200.0\n")
    with Graph(faults=Faults(0.3, 0.4, 0.3), effects=("sensor_noise",), seed=6, params_file=str(hinge),
               discrepancy=True) as g:
        r = g.run_test()
    assert r["discrepancy"].verdict == UNEXPLAINED
    assert r["level"] == "WARN" and UNEXPLAINED in r["message"] and "may be biased" in r["message"]


@pytest.mark.parametrize("channel, factor, unit", [("pressure", 1e-5, "bar"), ("pressure", 1e-6, "MPa"),
                                                   ("position", 1e3, "mm"), ("velocity", 1e3, "mm/s"),
                                                   ("current", 1e3, "mA")])
def test_a_channel_in_another_unit_is_refused_before_the_loop(channel, factor, unit):
    """A pressure in bar was "explained" as pressure_scale -30 % with K_FSJ 0 for a true 0.4; now the
    record is refused, naming the channel and the unit it looks like, before any fit. The same
    record in SI passes the check (gains near 1 at faults 0.3 / 0.4 / 0.3 with noise)."""
    from eha_health.identification.units import check_units, unit_gains
    r = simulate(faults=Faults(0.3, 0.4, 0.3), params=load("reference").with_effect_names(["sensor_noise"]), seed=5)
    m = KnobModel(load("monitor"), FAULT_KNOBS, Record.from_response(r))
    assert all(1 / 3 < g < 3 for g in unit_gains(m).values()), unit_gains(m)
    check_units(m)
    assert m.runs == 0                                   # a data check, not a model run of a fit
    setattr(r, channel, getattr(r, channel) * factor)
    with pytest.raises(ValueError, match=rf"channel {channel} is .* not in .* -- in {unit}\?"):
        analyse_fdi_test(r, max_effects=1)


def test_an_effect_fitted_onto_its_bound_is_said_in_the_verdict():
    """The pressure recorded at half its size (a transducer's calibration 50 % off, within the units
    check's reach): the nearest candidate, pressure_scale, ends on its -30 % bound; the verdict says so
    and that the coefficients are not to be trusted."""
    r = simulate(faults=Faults(0.3, 0.4, 0.3), params=load("reference").with_effect_names(["sensor_noise"]), seed=5)
    r.pressure = 0.5 * r.pressure
    rep = analyse_fdi_test(r, max_effects=2)
    assert "pressure_scale" in rep.selected
    assert "pressure_scale on its bound -0.3" in rep.verdict and "not to be trusted" in rep.verdict


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_one_chambers_pressure_is_refused_and_the_chamber_pair_imports(tmp_path, sign):
    """One chamber's pressure recorded as P12 (P1 = (Ps + P12) / 2, or P2 = (Ps - P12) / 2) was
    fitted as K_FSJ 1.5 (diagnose, on its bound) or with pressure_scale on its bound (the loop) for a
    true 0.4: refused before any fit, naming it. Both chambers, imported with ``minus``, give P12 and
    the faults back."""
    from eha_health.identification.diagnose import diagnose
    r = simulate(faults=Faults(0.3, 0.4, 0.3), params=load("reference").with_effect_names(["sensor_noise"]), seed=5)
    p12, ps = r.pressure.copy(), load("reference").hydraulics.supply_pressure
    r.pressure = 0.5 * (ps + sign * p12)
    with pytest.raises(ValueError, match=r"one chamber's pressure \(P1 or P2\) recorded as the differential"):
        diagnose(r)
    with pytest.raises(ValueError, match=r"minus: COLUMN"):
        analyse_fdi_test(r, max_effects=1)
    rows = "\n".join(f"{ti:.6f},{c * 1e3:.9f},{x * 1e3:.9f},{v:.9e},{i:.9e},{(ps + q) / 2e5:.9f},{(ps - q) / 2e5:.9f}"
                     for ti, c, x, v, i, q in zip(r.t, r.command, r.position, r.velocity, r.current, p12))
    data = _write(tmp_path, "rig.txt", "t,cmd_mm,pos_mm,vel,cur,p1_bar,p2_bar\n" + rows + "\n")
    m = _write(tmp_path, "map.yaml", yaml.safe_dump({
        "skip_rows": 1, "header_row": 0, "time": {"column": "t", "unit": "s"},
        "channels": {"command": {"column": "cmd_mm", "unit": "mm"}, "position": {"column": "pos_mm", "unit": "mm"},
                     "velocity": {"column": "vel", "unit": "m/s"}, "current": {"column": "cur", "unit": "A"},
                     "pressure": {"column": "p1_bar", "minus": "p2_bar", "unit": "bar"}}}))
    back = import_text(data, m)
    assert np.max(np.abs(back.pressure - p12)) < 1.0                        # Pa: the text's rounding
    d = diagnose(back)
    assert np.max(np.abs(np.array(d.faults.as_tuple()) - (0.3, 0.4, 0.3))) < 0.01


def test_a_channel_recorded_with_its_sign_inverted_is_refused_and_imports_flipped(tmp_path):
    """A channel wired the other way round (a pressure recorded as P2 - P1) was diagnosed K_FSJ 0.0
    for a true 0.4, and the loop called it an unexplained residual: every channel so inverted is
    refused before any fit, naming it; imported with scale -1, the faults come back."""
    from eha_health.identification.diagnose import diagnose
    r = simulate(faults=Faults(0.3, 0.4, 0.3), params=load("reference").with_effect_names(["sensor_noise"]), seed=5)
    for c in ("position", "velocity", "pressure", "current"):
        flipped = copy.copy(r)
        setattr(flipped, c, -getattr(r, c))
        with pytest.raises(ValueError, match=rf"channel {c} is anticorrelated with the healthy model "
                                             r"\(correlation -[01]\.\d+\): its sign is inverted"):
            diagnose(flipped)
        with pytest.raises(ValueError, match=r"scale: -1"):
            analyse_fdi_test(flipped, max_effects=1)
    rows = "\n".join(f"{ti:.6f},{c * 1e3:.9f},{x * 1e3:.9f},{v:.9e},{i:.9e},{-q / 1e5:.9f}"
                     for ti, c, x, v, i, q in zip(r.t, r.command, r.position, r.velocity, r.current, r.pressure))
    data = _write(tmp_path, "rig.txt", "t,cmd_mm,pos_mm,vel,cur,p21_bar\n" + rows + "\n")
    m = _write(tmp_path, "map.yaml", yaml.safe_dump({
        "skip_rows": 1, "header_row": 0, "time": {"column": "t", "unit": "s"},
        "channels": {"command": {"column": "cmd_mm", "unit": "mm"}, "position": {"column": "pos_mm", "unit": "mm"},
                     "velocity": {"column": "vel", "unit": "m/s"}, "current": {"column": "cur", "unit": "A"},
                     "pressure": {"column": "p21_bar", "scale": -1, "unit": "bar"}}}))
    d = diagnose(import_text(data, m))
    assert np.max(np.abs(np.array(d.faults.as_tuple()) - (0.3, 0.4, 0.3))) < 0.01


def test_an_effect_that_moves_the_diagnosis_to_another_basin_is_retried_from_screening():
    """Oil at 0.8 GPa with faults (0.3, 0.4, 0.3): the diagnosis without it lands at K_BKL 0.01 and
    K_FSJ 0.24, where compressibility's screen sees nothing (seventh by dIC, not refitted) and the
    verdict was "unexplained". The in-loop candidates pruned at screening are retried from the base
    re-identified with them: found, faults within 0.03; no selected effect is held at its off value."""
    r = simulate(faults=Faults(0.3, 0.4, 0.3), seed=777, params=load("reference").with_effect_names(["sensor_noise"])
                 .with_effects(compressibility={"enabled": True, "bulk_modulus": 8e8}))
    rep = analyse_fdi_test(r, max_effects=2, truth=Faults(0.3, 0.4, 0.3).as_dict())
    assert rep.selected[0] == "compressibility"
    assert max(rep.after.errors.values()) <= 0.03
    assert rep.after.values["oil_compliance"] == pytest.approx(1.25, rel=0.1)       # 1 / 0.8 GPa
    for name in rep.selected:
        assert any(abs(rep.after.values[k.name] - k.off) > 1e-3 * (k.hi - k.lo) for k in BY_NAME[name].knobs)
    assert "on its bound" not in rep.verdict


def test_a_candidate_strong_held_out_but_weak_on_the_fit_part_is_retried_too():
    """The feedback sensor's gain 3 % high at (0.3, 0.4, 0.3), noise seed 112 (`bench discrepancy
    --seed 1`'s case): sensor_gain screens at fit x0.997 (32nd of 41) but held out x0.815, second by
    rank behind a refitted load_mass that fails the gates, and the four pruned retries in fit-ratio
    order went to others: "unexplained", K_BKL 0.14 off. A pruned in-loop candidate ranked among the
    first three with dIC < 0 is retried too, and first, in the first batch of the pruned retries:
    found, sized, faults within 0.03, and the fit-ratio retries after its batch never run."""
    r = simulate(faults=Faults(0.3, 0.4, 0.3), seed=112, params=load("reference").with_effect_names(["sensor_noise"])
                 .with_effects(sensor_calibration={"enabled": True, "gain_error": 0.03}))
    said = []
    rep = analyse_fdi_test(r, max_effects=1, truth=Faults(0.3, 0.4, 0.3).as_dict(), progress=said.append)
    assert rep.selected == ["sensor_gain"]
    assert rep.after.values["gain_error"] == pytest.approx(0.03, rel=0.1)
    assert max(rep.after.errors.values()) <= 0.03
    retried = {m.split(": ", 1)[1].split(" -- ")[0] for m in said if "base re-identified" in m}
    # (the fit-ratio order's second batch: retried before sensor_gain when it came after them)
    assert "sensor_gain" in retried and not retried & {"viscous_friction", "command_scale"}


def test_a_candidate_refit_stopped_in_a_backlash_ripple_is_taken_to_the_healthy_corner():
    """A spool 1.4x slower, no fault: the start diagnosis reads K_BKL 0.06, and the valve candidate's
    local fit from there stopped in a ripple of the cost at K_BKL 0.028 (fit-part cost 6x that at
    K_BKL = 0); its held-out prediction (x0.19) then lost the ranking to the supply sag. The refit
    tries each fault coefficient within its typical magnitude of 0 at 0, and refits from there
    when that costs less."""
    ref = load("reference")
    r = _noisy_run(ref.updated("flapper_nozzle", spool_end_area=ref.flapper_nozzle.spool_end_area * 1.4),
                   Faults(0, 0, 0), seed=148)
    cands = tuple(c for c in CANDIDATES if c.name in ("valve_response", "supply_pressure"))
    rep = analyse_fdi_test(r, max_effects=1, truth=Faults(0, 0, 0).as_dict(), candidates=cands)
    assert rep.before.values["k_bkl"] > 0.03
    ev = {e.name: e for e in rep.candidates}
    assert rep.candidates[0].name == "valve_response" and rep.selected == ["valve_response"]
    assert ev["valve_response"].held_out_ratio < 0.05 and ev["valve_response"].fit_ratio < 0.01
    assert ev["valve_response"].delta_ic < ev["supply_pressure"].delta_ic - EQUIVALENT_DIC
    assert ev["valve_response"].parameters["valve_slowdown"] == pytest.approx(0.4, rel=0.05)


def test_an_effect_a_fault_coefficient_absorbed_is_screened_with_the_base_re_solved():
    """A supply at 14 MPa with no fault: the diagnosis puts K_GM at 0.11 in its place, and the
    supply's coarse scan, with K_GM held there, lowers the fit part's power to x0.88 only -- three
    candidates screened better, and with two refits it was pruned (sensor_delay selected, the
    faults 0.034 off). The screen's row with the base knobs re-solved on their linearisation
    (variable projection) reaches it: selected, sized, the faults back. The slower spool is left out
    of the library here: at faults 0 the FDI test does not tell it from a supply sag (the pilot-flow
    pair: both refits fit to the noise, held-out x0.057 and x0.060, dIC 3.6 apart with the spool
    ahead, since both reach K_BKL 0 -- before _healthy_corners both stopped short, 2 apart the
    other way)."""
    r = _noisy_run(load("reference").updated("hydraulics", supply_pressure=14e6), Faults(0, 0, 0), seed=127)
    rep = analyse_fdi_test(r, max_effects=1, truth=Faults(0, 0, 0).as_dict(),
                           candidates=tuple(c for c in CANDIDATES if c.name != "valve_response"))
    assert rep.selected == ["supply_pressure"]
    assert rep.after.values["sag"] == pytest.approx((20.7e6 - 14e6) / (20.7e6 - 0.3e6), rel=0.1)
    assert max(rep.after.errors.values()) <= 0.01 < max(rep.before.errors.values())


def test_a_velocity_feedback_gain_off_its_nominal_is_found_and_the_excess_over_noise_goes():
    """gas 30 % high at (0.2, 0.5, 0.1): 15 um of position residual over the 5 um sensor noise, so
    the raw RMS cannot fall to a third (5.15 um after, the noise); the issue's measure is the excess
    over noise and floor, on the held-out part."""
    faults = Faults(0.2, 0.5, 0.1)
    ref = load("reference")
    r = _noisy_run(ref.updated("controller", gas=ref.controller.gas * 1.3), faults, seed=21)
    rep = analyse_fdi_test(r, max_effects=1, truth=faults.as_dict())
    assert rep.candidates[0].name == "velocity_feedback" and rep.selected == ["velocity_feedback"]
    assert rep.after.values["velocity_gain_error"] == pytest.approx(0.3, rel=0.1)
    assert rep.after.excess_held_out["position"] <= rep.before.excess_held_out["position"] / 3
    assert rep.before.excess_held_out["position"] > 5e-6
    assert max(rep.after.errors.values()) <= 0.03 < max(rep.before.errors.values())


def _bench_case(name, faults, seed):
    """A record of `bench discrepancy` (seed 0): ``name``'s effect at ``faults``, noise ``seed``."""
    from eha_health.bench.discrepancy import effect_change, reference_run
    return reference_run(faults, seed, *effect_change(name))


def test_a_further_round_starts_from_the_base_re_identified_with_the_effect():
    """kp 15 % high at (0.3, 0.4, 0.3), up to two effects (the command's default): controller_gain is
    selected with the faults where its refit's local path stopped, the residual is still structured,
    and a second round from there added supply_pressure. Re-identified with controller_gain in the
    model, the base fits the record and no second effect is invented."""
    f = Faults(0.3, 0.4, 0.3)
    said = []
    rep = analyse_fdi_test(_bench_case("controller_gain", f, 144), truth=f.as_dict(), progress=said.append)
    assert rep.selected == ["controller_gain"]
    assert any(m.startswith("base re-identified with controller_gain") for m in said)
    assert max(rep.after.errors.values()) <= 0.01


def test_a_recording_effects_own_form_error_starts_no_further_round():
    """A time base 0.5 % fast at (0.3, 0.4, 0.3): undone by resampling it leaves more than the base
    floor (its effect floor in data/discrepancy.yaml: 2x on the current), and a second round used to
    run on that form error (1215 model runs for nothing). Against its own floor the residual with
    time_base is noise."""
    from eha_health.discrepancy.settings import fdi_settings
    st = fdi_settings()
    assert st.effect_floor["time_base"]["current"] > st.floor["current"]
    f = Faults(0.3, 0.4, 0.3)
    said = []
    rep = analyse_fdi_test(_bench_case("time_base", f, 216), truth=f.as_dict(), progress=said.append)
    assert rep.selected == ["time_base"]
    assert not any(m.startswith("round 2") for m in said)
