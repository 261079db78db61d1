"""Kinematic consistency of the recorded velocity and the recorded position's derivative."""
import numpy as np
import pytest

from eha_health import simulate
from eha_health.bench.discrepancy import lagged, late, scaled
from eha_health.physics.faults import Faults
from eha_health.physics.params import load
from eha_health.signals.kinematics import kinematics


def _run(seed=21):
    return simulate(params=load("reference").with_effect_names(["sensor_noise"]), faults=Faults(0.3, 0.4, 0.3),
                    seed=seed)


def _kin(r):
    return kinematics(r.position, r.velocity, r.command, r.sample_rate)


def test_unaltered_recordings_agree_to_their_noise():
    for seed in (21, 22):
        k = _kin(_run(seed))
        # the white noise of both channels through the pipeline is the whole mismatch
        assert 0.7 < k.mismatch() / k.noise_power < 2.0 and not k.significant


@pytest.mark.parametrize("alter,kind,value", [
    (lambda r: scaled(r, "velocity", 0.03), "scale", 0.03),
    (lambda r: late(r, "velocity", 4e-3), "skew", 4e-3),
    (lambda r: lagged(r, "velocity", 3e-3), "lag", 3e-3),
])
def test_a_velocity_recording_effect_breaks_v_equals_dx_dt_and_its_own_kind_restores_it(alter, kind, value):
    k = _kin(alter(_run()))
    assert k.significant and k.mismatch() > 50 * k.noise_power
    base = k.mismatch()
    own = k.mismatch(kind, value) / base
    assert own < 0.02
    # the other kinds of effect do not restore it as well (a lag and a skew are told apart)
    others = {o: min(k.mismatch(o, v) for v in grid) / base for o, grid in (
        ("scale", np.linspace(-0.1, 0.1, 41)), ("skew", np.linspace(-8e-3, 8e-3, 81)),
        ("lag", np.linspace(1e-4, 8e-3, 80)), ("offset", np.linspace(-1e-2, 1e-2, 41))) if o != kind}
    assert all(v > own for v in others.values()), others


def test_too_short_or_damaged_records_give_no_kinematics():
    r = _run()
    n = int(0.5 * r.sample_rate)
    assert kinematics(r.position[:n], r.velocity[:n], r.command[:n], r.sample_rate) is None
    v = r.velocity.copy()
    v[10] = np.nan
    assert kinematics(r.position, v, r.command, r.sample_rate) is None
