"""Coarse detector (20 % damage thresholds) and monitor calibration."""
import numpy as np
import pytest

from eha_health import Faults, simulate
from eha_health.identification.calibrate import calibrate
from eha_health.identification.signatures import Detector, signatures


@pytest.fixture(scope="module")
def det():
    return Detector.build()


def test_detector_healthy_flags_nothing(det):
    assert not any(det.detect(signatures(simulate())).values())


@pytest.mark.parametrize("faults, expect", [
    (Faults(k_gm=0.4), {"gm"}), (Faults(k_fsj=0.4), {"fsj"}), (Faults(k_bkl=0.4), {"bkl"}),
    (Faults(0.6, 0.6, 0.6), {"gm", "fsj", "bkl"}), (Faults(0.0, 1.0, 0.6), {"fsj", "bkl"}),
])
def test_detector_finds_the_faults_present(det, faults, expect):
    found = {f for f, v in det.detect(signatures(simulate(faults=faults))).items() if v}
    assert found == expect


def test_calibration_recovers_a_good_first_stage_from_a_poor_start():
    from eha_health import load
    poor = load("monitor").updated("first_stage", natural_frequency=900.0, damping_ratio=1.5,
                                   spool_time_constant=1.5e-3, static_gain=0.05)
    res = calibrate(monitor=poor)
    assert res.rms_after["position"] < 0.2 * res.rms_before["position"]
    assert res.rms_after["position"] < 1e-5
    assert np.isfinite(list(res.values.values())).all()
