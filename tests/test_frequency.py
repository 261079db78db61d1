"""Empirical frequency response (H1) of position over command, measured against modelled."""
import numpy as np
import pytest
from scipy.signal import lfilter

from eha_health.signals.frequency import compare, estimate, response_error

FS = 1000.0


def _broadband(n=40000, seed=3):
    rng = np.random.default_rng(seed)
    # band-limited random command: white noise through a 2nd-order low pass at ~40 Hz
    a = np.exp(-2 * np.pi * 40 / FS)
    u = lfilter([(1 - a) ** 2], [1, -2 * a, a * a], rng.standard_normal(n))
    return u / np.std(u) * 1e-3, rng


def test_first_order_lag_gain_and_phase():
    u, rng = _broadband()
    fc = 8.0
    a = np.exp(-2 * np.pi * fc / FS)
    y = lfilter([1 - a], [1, -a], u) + 1e-6 * rng.standard_normal(len(u))
    r = estimate(u, y, FS)
    band = (r.f > 1) & (r.f < 30)
    assert band.sum() > 50 and np.all(r.coherence[band] > 0.99)
    # discrete first-order lag: H = (1-a) / (1 - a z^-1)
    z = np.exp(-2j * np.pi * r.f[band] / FS)
    exact = (1 - a) / (1 - a * z)
    assert np.max(np.abs(r.H[band] / exact - 1)) < 0.03


def test_a_missing_delay_shows_as_phase_error_and_no_gain_error():
    u, rng = _broadband()
    d = 5                                   # samples: 5 ms
    y = np.concatenate([np.zeros(d), u[:-d]]) + 2e-6 * rng.standard_normal(len(u))
    bands = compare(u, y, {"with_delay": np.concatenate([np.zeros(d), u[:-d]]), "without": u}, FS, n_bands=6)
    assert len(bands) == 6
    for b in bands:
        fmid = (b["f_lo"] + b["f_hi"]) / 2
        assert b["gain_ratio"]["with_delay"] == pytest.approx(1.0, abs=0.01)
        assert b["phase_error_deg"]["with_delay"] == pytest.approx(0.0, abs=0.5)
        assert b["gain_ratio"]["without"] == pytest.approx(1.0, abs=0.01)
        # the model without the delay leads the measurement by 360 f T (mean over the band)
        assert b["phase_error_deg"]["without"] == pytest.approx(360 * fmid * d / FS, rel=0.1, abs=1.0)


@pytest.mark.parametrize("u,y,expect", [
    (np.zeros(100), np.zeros(100), "too short"),
    (np.r_[np.zeros(999), np.nan], np.zeros(1000), "NaN"),
    (np.zeros(1000), np.zeros(999), "one length"),
])
def test_bad_input_is_named(u, y, expect):
    with pytest.raises(ValueError, match=expect):
        estimate(u, y, FS)


def test_response_error_is_structure_only_beyond_the_estimates_own_scatter():
    # measured: a first-order lag with output noise (coherence 0.9-0.99 over the kept band). The
    # right model's error power is the estimate's own scatter, as (1 - g2) / (n_d g2) predicts; a
    # 15 % gain error adds its 0.0225 on top and is structure
    u, rng = _broadband()
    a = np.exp(-2 * np.pi * 8.0 / FS)
    clean = lfilter([1 - a], [1, -a], u)
    y = clean + 0.25 * np.std(clean) * rng.standard_normal(len(u))
    right, low = response_error(u, y, clean, FS), response_error(u, y, 0.85 * clean, FS)
    assert len(right.f) > 20 and np.all(right.sigma > 0)
    assert 0.5 < right.power / right.noise_power < 2.0 and not right.significant()
    assert low.power == pytest.approx(0.0225 + right.power, rel=0.15) and low.significant()
    assert abs(np.median(low.rel.real) + 0.15) < 0.02      # the relative error is -15 % bin by bin
    with pytest.raises(ValueError, match="NaN"):
        response_error(u, y, np.r_[clean[:-1], np.nan], FS)
