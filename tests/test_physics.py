"""Physics sanity on real simulations of the reference and monitor models."""
import numpy as np
import pytest

from eha_health import Faults, FDISequence, Plant, load, simulate
from eha_health.physics.friction import stick_slip_velocity
from eha_health.physics.packing import effective


def run(kind, cmd, faults=Faults(), params=None, seed=None):
    plant = Plant(params, faults, seed, kind)
    out = plant.step(np.asarray(cmd, float))
    return plant, out


@pytest.mark.parametrize("kind", ["reference", "monitor"])
def test_zero_command_stays_at_rest(kind):
    _, out = run(kind, np.zeros(500), Faults(0.5, 0.5, 0.5))
    assert np.abs(out[:, 1]).max() < 1e-9   # position
    assert np.abs(out[:, 6]).max() < 1e-9   # jack position
    assert np.abs(out[:, 3]).max() < 1e-3   # P12 [Pa]


@pytest.mark.parametrize("kind", ["reference", "monitor"])
def test_step_settles_on_command(kind):
    _, out = run(kind, np.full(800, 5e-3))
    pos = out[:, 1]
    # settled within 2 % of the step (friction + hinge load leave a small error)
    assert abs(pos[-100:].mean() - 5e-3) < 0.02 * 5e-3
    assert np.ptp(pos[-100:]) < 1e-5


def test_stick_slip_function_sticks_below_and_breaks_away_above_static_friction():
    m, c, dt, fs, fd = 5.0, 3000.0, 1e-5, 400.0, 267.0
    # at rest, active force below static friction: stays stuck
    assert stick_slip_velocity(0.0, 0.0, 0.0, 1e9, 399.0, c, m, fs, fd, 0.0, dt) == 0.0
    assert stick_slip_velocity(0.0, 0.0, 0.0, 1e9, -399.0, c, m, fs, fd, 0.0, dt) == 0.0
    # above it: breaks away in the direction of the force
    assert stick_slip_velocity(0.0, 0.0, 0.0, 1e9, 401.0, c, m, fs, fd, 0.0, dt) > 0.0
    assert stick_slip_velocity(0.0, 0.0, 0.0, 1e9, -401.0, c, m, fs, fd, 0.0, dt) < 0.0
    # moving slowly against a braking force: clean stop at the reversal (no sign flip)
    v = stick_slip_velocity(1e-6, 0.0, 0.0, 1e9, -350.0, c, m, fs, fd, 0.0, dt)
    assert v == 0.0


def test_jack_stays_stuck_until_hydraulic_force_exceeds_static_friction():
    faults = Faults(k_fsj=1.0)
    params = load("reference")
    fs = effective(params, faults)["f_s"]
    r = simulate(faults=faults)
    moving = np.flatnonzero(np.abs(np.diff(r.jack_position)) > 1e-9)
    i0 = moving[0]
    area = params.jack.area
    # before breakaway the force never exceeded static friction (small tolerance: one sample)
    assert (r.pressure[:i0] * area).max() <= fs * 1.02
    # the breakaway pressure reached close to F_s / A (it was stuck until then)
    assert r.pressure[: i0 + 2].max() * area > 0.9 * fs


def test_backlash_dead_band_jack_moves_before_surface():
    params = load("reference")
    b = effective(params, Faults(k_bkl=1.0))["backlash"]
    r = simulate(faults=Faults(k_bkl=1.0))
    i = np.argmax(r.position > 2e-6)      # surface starts moving
    # the jack has already crossed half the total play
    assert r.jack_position[i] == pytest.approx(b / 2, rel=0.25)
    healthy = simulate()
    j = np.argmax(healthy.position > 2e-6)
    assert healthy.jack_position[j] < 0.1 * b / 2


def test_end_stops_hold():
    params = load("reference")
    stroke = params.jack.stroke
    _, out = run("reference", np.full(600, 0.08))   # command beyond the stroke
    assert out[:, 6].max() <= stroke + 1e-12
    assert out[-1, 6] == pytest.approx(stroke, abs=1e-9)


def test_signature_trends_are_monotonic():
    from eha_health.identification.signatures import signatures
    levels = (0.0, 0.4, 0.8)
    ov = [signatures(simulate(faults=Faults(k_gm=k))).overshoot for k in levels]
    pk = [signatures(simulate(faults=Faults(k_fsj=k))).pressure_peak for k in levels]
    sb = [signatures(simulate(faults=Faults(k_bkl=k))) for k in levels]
    assert ov[0] > ov[1] > ov[2] > 0
    assert pk[0] < pk[1] < pk[2]
    assert sb[0].motion_start < sb[1].motion_start < sb[2].motion_start
    assert sb[0].current_peak < sb[1].current_peak < sb[2].current_peak
    assert sb[0].velocity_peak < sb[1].velocity_peak < sb[2].velocity_peak


def test_calibrated_monitor_tracks_healthy_reference():
    # measured 1.4 um position RMS with the shipped calibration (docs/model.md)
    ref, mon = simulate("reference"), simulate("monitor")
    rms = np.sqrt(np.mean((ref.position - mon.position) ** 2))
    assert rms < 1e-5
    rms_spool = np.sqrt(np.mean((ref.spool - mon.spool) ** 2))
    assert rms_spool < 2e-6


def test_same_seed_identical_other_seed_differs():
    p = load("reference").with_effects(sensor_noise={"enabled": True}, command_noise={"enabled": True})
    a = simulate(params=p, seed=7)
    b = simulate(params=p, seed=7)
    c = simulate(params=p, seed=8)
    assert np.array_equal(a.position, b.position) and np.array_equal(a.current, b.current)
    assert not np.array_equal(a.position, c.position)


def test_noise_requires_seed():
    p = load("reference").with_effects(sensor_noise={"enabled": True})
    with pytest.raises(ValueError, match="seed"):
        simulate(params=p)


def test_chunked_plant_equals_one_shot():
    seq = FDISequence()
    cmd = seq.command(seq.times(1000))
    p = load("reference").with_effects(command_noise={"enabled": True}, sensor_noise={"enabled": True})
    a = Plant(p, Faults(0.4, 0.6, 0.4), seed=3).step(cmd)
    pl = Plant(p, Faults(0.4, 0.6, 0.4), seed=3)
    b = np.vstack([pl.step(cmd[i:i + 137]) for i in range(0, len(cmd), 137)])
    assert np.array_equal(a, b)


def test_command_calibration_drives_the_actuator_with_the_command_it_received():
    # a command recorded (1 + e) c + o: simulated from the recorded command with the calibration on,
    # every output equals the plain run of c, and the command column holds what was recorded
    seq = FDISequence()
    c = seq.command(seq.times(1000))
    f = Faults(0.3, 0.4, 0.3)
    plain = Plant(load("reference"), f).step(c)
    p = load("reference").with_effects(command_calibration={"enabled": True, "offset": 2e-4, "gain_error": 0.03})
    rec = 1.03 * c + 2e-4
    out = Plant(p, f).step(rec)
    assert np.array_equal(out[:, 0], rec)
    # (float rounding of (1.03 c + o - o) / 1.03 only: 1e-9 of each column's range)
    assert np.all(np.abs(out[:, 1:] - plain[:, 1:]) <= 1e-9 * np.ptp(plain[:, 1:], axis=0))


@pytest.mark.parametrize("effect, change", [
    ("compressibility", {"enabled": True}),
    ("sensor_delay", {"enabled": True}),
    ("stribeck", {"enabled": True}),
    ("sensor_calibration", {"enabled": True, "bias": 1e-4}),
    ("quantization", {"enabled": True}),
])
def test_each_effect_runs_and_changes_the_response(effect, change):
    base = simulate()
    p = load("reference").with_effects(**{effect: change})
    r = simulate(params=p)
    assert np.isfinite(r.position).all() and np.isfinite(r.pressure).all()
    assert not np.array_equal(r.position, base.position) or not np.array_equal(r.pressure, base.pressure)
    # still a working servo: tracks the step
    step = FDISequence().mask("step", r.t)
    assert abs(r.position[step][-50:].mean() - 0.01) < 5e-4


def test_compressibility_gives_hydraulic_resonance_on_the_step():
    p = load("reference").with_effects(compressibility={"enabled": True, "bulk_modulus": 3e8})
    r, b = simulate(params=p), simulate()
    step = FDISequence().mask("step", r.t)
    assert np.std(np.diff(r.pressure[step])) > np.std(np.diff(b.pressure[step]))


def test_vibration_null_shift_moves_the_position_by_the_vibration_level():
    # a P loop on an integrating jack holds zero valve current: x = x_cmd + i_null / kp, so a null
    # that shifts by g <|a|> moves the jack by g <|a|> / kp where it accelerates, and not elsewhere
    p, g = load("monitor"), 1e-4
    base = simulate(params=p)
    r = simulate(params=p.with_effects(vibration_null_shift={"enabled": True, "gain": g}))
    seq = FDISequence()
    acc = np.abs(np.gradient(np.gradient(base.position, base.t), base.t))
    sine, ramp = seq.mask("sine", base.t), seq.mask("ramp", base.t)
    shift = np.mean((r.position - base.position)[sine])
    assert shift == pytest.approx(g * acc[sine].mean() / p.controller.kp, rel=0.15)
    assert shift > 5e-6                       # and it is well above the 1 um scale of the check below
    assert abs(np.mean((r.position - base.position)[ramp])) < 1e-6   # a ramp hardly accelerates
