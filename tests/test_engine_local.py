"""The engine's bounded least squares keeps a start that lies on a bound where it is; a run cut at
the samples an objective reads is the whole run's."""
import dataclasses

import numpy as np
import pytest

from eha_health import simulate
from eha_health.discrepancy.candidates import BY_NAME
from eha_health.identification.knobs import FAULT_KNOBS
from eha_health.identification.jacobian import jacobian, jacobian_at, residual
from eha_health.identification.local import least_squares
from eha_health.identification.problem import KnobModel, Problem
from eha_health.identification.record import Record
from eha_health.identification.residual import Residual
from eha_health.physics.faults import Faults
from eha_health.physics.params import load
from eha_health.physics.sequence import FDISequence

TRUE_LEAK = 5e-12       # m^3/(s Pa): the leakage knob's typical value


@pytest.fixture(scope="module")
def leaky():
    f = Faults(0.2, 0.3, 0.1)
    mon = load("monitor")
    rec = Record.from_response(simulate(kind="monitor", faults=f,
                                        params=mon.updated("hydraulics", leakage=mon.hydraulics.leakage + TRUE_LEAK)))
    m = KnobModel(mon, FAULT_KNOBS + BY_NAME["leakage"].knobs, rec)
    return m, Residual(rec), [*f.as_tuple(), 0.0]          # the leakage knob starts on its 0 bound


def test_first_point_the_solver_evaluates_is_a_start_on_a_bound(leaky):
    # scipy moves a start on a bound inside it by 1e-10 of its variable: in m^3/(s Pa) that is 20x
    # the leakage's typical value (cost 317 there against 0.98 at the start)
    m, res, x0 = leaky
    start = res.cost(m.run(x0)[0])
    assert res.cost(m.run([*x0[:3], 1e-10])[0]) > 100 * start
    history = []
    f = least_squares(Problem(m, res), x0, history=history, max_nfev=3)
    assert history[0] == pytest.approx(start, rel=1e-12)
    assert f.cost <= start and 0.0 <= f.x[3] <= 2 * TRUE_LEAK


def test_fit_leaves_a_start_on_a_bound(leaky):
    # TRF's first trust radius is the norm of the scaled start: a knob alone at ~0 never moved
    m, res, x0 = leaky
    start = res.cost(m.run(x0)[0])
    f = least_squares(Problem(m, res, free=[3]), x0, max_nfev=20)
    assert 0.0 < f.x[3] < TRUE_LEAK and f.cost < 0.8 * start
    assert list(f.x[:3]) == x0[:3]
    assert np.isfinite(f.std()["extra_leakage"])


def test_start_on_upper_bounds_is_accepted(leaky):
    # (bound - origin) / scale must not round a start on an upper bound outside the solver's box
    m, res, _ = leaky
    x0 = list(m.upper)
    for x in (x0, [0.3, 0.4, 1.5, 0.02 * 5e-12 + 1e-10 - 0.02 * 5e-12]):
        f = least_squares(Problem(m, res), x, max_nfev=1)
        assert np.all(f.x <= m.upper) and np.all(f.x >= m.lower)


def test_a_trial_point_costs_one_run_and_its_jacobian_is_the_batched_one(leaky):
    # a point TRF rejects needs no Jacobian: only the accepted ones get their perturbed rows, and
    # those give the numbers of the batch that simulates the point with them (the fit is the same)
    m, res, x0 = leaky
    p = Problem(m, res)
    x = np.array([0.25, 0.3, 0.12, 2e-12])
    r, J, _ = jacobian(p, x)
    r1, out, sim = residual(p, x)
    assert np.array_equal(r1, r) and np.array_equal(jacobian_at(p, x, r1, sim), J)
    history = []
    f = least_squares(p, x0, history=history, max_nfev=25)
    accepted = sum(h < min(history[:i]) for i, h in enumerate(history) if i)
    n = len(p.free)
    assert accepted < len(history) - 1          # the solver rejected some trials
    # the start's batch, one run per trial, n per accepted point (+1: the output at the solution)
    assert f.runs <= (n + 1) + (len(history) - 1) + n * accepted + 1 < (n + 1) * len(history)


def test_a_recording_knobs_jacobian_column_reuses_the_trial_points_simulation(leaky):
    m0, res, _ = leaky
    m = KnobModel(m0.base, FAULT_KNOBS + BY_NAME["position_skew"].knobs, m0.record)
    p = Problem(m, res)
    x = np.array([0.25, 0.3, 0.12, 1e-3])
    r, J, _ = jacobian(p, x)
    runs = m.runs
    r1, out, sim = residual(p, x)
    J1 = jacobian_at(p, x, r1, sim)
    assert np.array_equal(r1, r) and np.array_equal(J1, J)
    assert m.runs - runs == 1 + 3            # the trial point, then the three fault columns only


@pytest.mark.parametrize("kind", ["1 kHz", "logged at 500 Hz", "after a test"])
def test_a_run_cut_at_a_horizon_is_the_whole_runs_first_samples(leaky, kind):
    # the kernel is causal: simulating the first n samples gives those of the whole run to the bit
    # (a record below the command rate too: upsampled whole, then cut; and after a preamble), NaN
    # after them, one run counted with the model's
    m0, _, x0 = leaky
    rec = m0.record
    if kind == "logged at 500 Hz":
        rec = dataclasses.replace(rec, t=rec.t[::2], command=rec.command[::2],
                                  channels={c: y[::2] for c, y in rec.channels.items()})
    elif kind == "after a test":
        rec = dataclasses.replace(rec, preroll=FDISequence().preamble(rec.sample_rate))
    m = KnobModel(m0.base, m0.knobs, rec)
    assert (m.oversample > 1) == (kind == "logged at 500 Hz")
    n = int(0.43 * len(rec))
    X = np.array([x0, [0.5, 0.1, 0.7, 3e-12]])
    whole = m.run(X)
    cut = m.until(n)
    runs = m.runs
    part = cut.run(X)
    assert m.runs - runs == 2 and cut.runs == m.runs
    assert np.array_equal(part[:, :n], whole[:, :n]) and np.isnan(part[:, n:]).all()
    res = Residual(rec, np.arange(len(rec)) < n)
    assert res.horizon == n and res.costs(part).tolist() == res.costs(whole).tolist()
    assert m.until(None) is m and m.until(len(rec)) is m
    # a measurement-chain knob acts on the whole recorded output: such a model is not cut
    mr = KnobModel(m0.base, FAULT_KNOBS + BY_NAME["position_skew"].knobs, rec)
    assert mr.until(n) is mr
