"""Parameters: YAML defaults, validation with clear messages, packing."""
import math

import numpy as np
import pytest

from eha_health import Faults, load, simulate
from eha_health.physics import layout as L
from eha_health.physics.packing import pack
from eha_health.physics.params import field_table


def test_layout_indices_match_names():
    for i, name in enumerate(L.P_NAMES):
        assert i < L.N_P
    consts = {k: v for k, v in vars(L).items() if k.startswith("P_") and isinstance(v, int)}
    assert sorted(consts.values()) == list(range(L.N_P))
    s_consts = {k: v for k, v in vars(L).items() if k.startswith("S_") and isinstance(v, int)}
    assert sorted(s_consts.values()) == list(range(L.N_S))


@pytest.mark.parametrize("kind", ["reference", "monitor"])
def test_defaults_load_and_every_value_is_documented(kind):
    p = load(kind)
    rows = field_table(p)
    assert len(rows) > 60
    for name, value, unit, doc in rows:
        assert doc, f"{name} has no doc"
        assert unit, f"{name} has no unit"
    v = pack(p)
    assert v.shape == (L.N_P,) and np.isfinite(v).all()


@pytest.mark.parametrize("override, match", [
    ({"jack": {"mass": -1.0}}, "jack.mass"),
    ({"jack": {"mass": float("nan")}}, "jack.mass"),
    ({"hydraulics": {"supply_pressure": 0.0}}, "supply_pressure"),
    ({"flapper_nozzle": {"clogging": 1.5}}, "clogging"),
    ({"jack": {"bogus": 1.0}}, "bogus"),
    ({"controller": {"kp": "fast"}}, "kp"),
])
def test_bad_parameters_raise_value_error_naming_them(override, match):
    with pytest.raises(ValueError, match=match):
        load("reference", overrides=override)


@pytest.mark.parametrize("faults, match", [
    (dict(k_gm=-0.1), "k_gm"), (dict(k_fsj=math.nan), "k_fsj"), (dict(k_bkl=-1), "k_bkl"),
])
def test_bad_fault_coefficients(faults, match):
    with pytest.raises(ValueError, match=match):
        Faults(**faults)


def test_beyond_limit_damage_allowed_but_not_total_gain_loss():
    simulate(faults=Faults(k_fsj=1.5, k_bkl=1.2))
    with pytest.raises(ValueError, match="k_gm"):
        pack(load("reference"), Faults(k_gm=2.0))


def test_fault_spec_parsing():
    f = Faults.parse("gm=0.4, fsj=0.6,k_bkl=0.2")
    assert f.as_tuple() == (0.4, 0.6, 0.2)
    with pytest.raises(ValueError, match="unknown fault"):
        Faults.parse("xx=1")


def test_user_yaml_overrides(tmp_path):
    y = tmp_path / "p.yaml"
    y.write_text("jack:\n  mass: 7.5\n")
    assert load("reference", path=y).jack.mass == 7.5
    y.write_text("jack: [1, 2\n")
    with pytest.raises(ValueError, match="YAML"):
        load("reference", path=y)
    # a key written twice: PyYAML kept the last without a word; refused, both lines named
    y.write_text("jack:\n  mass: 7.5\njack:\n  mass: 9.0\n")
    with pytest.raises(ValueError, match=r"key 'jack' written twice \(lines 1 and 3\)"):
        load("reference", path=y)
    # a merge key's values may still be overridden (YAML's << merge)
    y.write_text("base: &b {mass: 7.5}\njack:\n  <<: *b\n  mass: 8.0\n")
    with pytest.raises(ValueError, match="base"):       # the anchor's own key is unknown to the parameters
        load("reference", path=y)


def test_dt_must_divide_sample_period():
    with pytest.raises(ValueError, match="dt"):
        pack(load("reference", overrides={"integration": {"dt": 3e-5}}))
