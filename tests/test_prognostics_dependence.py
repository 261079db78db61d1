"""Faults that wear together: the test on their increments finds a common wear process and not
independent ones (accelerating ones included), and the overall RUL interval then holds for any
positive dependence -- its median and P(failure before the next check) stay independence's."""
import numpy as np
import pytest

from eha_health.prognostics import prognose
from eha_health.prognostics.config import load_settings
from eha_health.prognostics.dependence import shared_groups, shared_wear_p
from eha_health.prognostics.records import HealthRecord, history_from_records
from eha_health.prognostics.thresholds import threshold_values

THR = threshold_values(load_settings())


def two_faults(rng, common: bool, law: str = "linear", noise: float = 0.005, interval_h: float = 50.0,
               cut=(0.4, 0.85)):
    """Test times [h], K of gm and fsj (gamma processes to their thresholds, lives within 15 %
    of each other, volatility nu 0.002-0.006 per h), and the true overall RUL at the last test [h].
    ``common``: one gamma process drives both (comonotone wear)."""
    life = 1000.0 * np.exp(rng.normal(0, 0.3))
    lives = {"gm": life, "fsj": life * np.exp(rng.uniform(-0.15, 0.15))}
    nu = np.exp(rng.uniform(np.log(0.002), np.log(0.006))) * 1000.0
    n = int(3 * max(lives.values())) + 10
    grid = np.arange(n, dtype=float)
    mean = np.diff(grid ** 2 / 1000.0) if law == "t2" else np.ones(n - 1)
    shared = rng.gamma(mean / nu, nu)
    paths = {}
    for f, lf in lives.items():
        steps = shared if common else rng.gamma(mean / nu, nu)
        paths[f] = THR[f] * np.concatenate([[0.0], np.cumsum(steps)]) / (lf ** 2 / 1000.0 if law == "t2" else lf)
    eol = min(float(np.argmax(p >= THR[f])) for f, p in paths.items())
    t = np.arange(0.0, rng.uniform(*cut) * eol, interval_h)
    t[1:] += rng.uniform(-0.2, 0.2, len(t) - 1) * interval_h
    k = {f: np.clip(p[t.astype(int)] + rng.normal(0, noise, len(t)), 0, 1.5) for f, p in paths.items()}
    return t, k["gm"], k["fsj"], eol - t[-1]


@pytest.mark.parametrize("law", ["linear", "t2"])
def test_a_common_wear_process_is_found_and_independent_ones_are_not(law):
    """200 units per case (seeded): independent processes -- accelerating ones too, whose
    increments both grow -- are called shared at about the test's level, a common one mostly."""
    found = {}
    for common in (True, False):
        rng = np.random.default_rng(11)
        ps = [shared_wear_p(*two_faults(rng, common, law)[:3]) for _ in range(200)]
        ps = np.array([p for p in ps if p is not None])
        assert len(ps) > 150
        found[common] = np.mean(ps < 0.05)
    assert found[False] <= 0.10, found
    assert found[True] >= (0.6 if law == "linear" else 0.35), found


def test_the_test_needs_six_increments_and_scatter():
    t = np.arange(7.0) * 50
    assert shared_wear_p(t[:6], t[:6] * 1e-3, t[:6] * 2e-3) is None
    assert shared_wear_p(t, t * 1e-3, t * 2e-3) is None                 # straight lines: nothing to test
    groups, tested = shared_groups({"gm": (t, t * 1e-3), "bkl": (t[:3], t[:3])}, 0.05)
    assert groups == [] and tested == {}


def _history(units, common, seed):
    rng = np.random.default_rng(seed)
    recs, truth = [], {}
    for u in range(units):
        t, gm, fsj, rul = two_faults(rng, common)
        a = f"U{u:03d}"
        recs += [HealthRecord(a, float(ti), (float(g), float(f), 0.02), (0.005,) * 3) for ti, g, f in zip(t, gm, fsj)]
        truth[a] = rul
    return history_from_records(recs, [], 0.002), truth


def _coverage(out, truth):
    inside = [o["rul_p05_h"] <= r <= (o["rul_p95_h"] or np.inf) for a, r in truth.items()
              for o in [out[a]["overall"]] if o["rul_p05_h"] is not None]
    return np.mean(inside), len(inside)


def test_the_overall_interval_of_faults_wearing_together_holds(tmp_path):
    """120 units whose gm and fsj share one gamma process: independence put the first crossing
    too early and its 90 % interval covered 81 %; with the shared wear found (in 70 units), 88 %
    (another seed: 81 -> 90 %). Where found, the overall p95 is the lesser of the two faults'
    (the comonotone first crossing), and the median and P(failure before the next check) are
    independence's."""
    hist, truth = _history(120, True, 1)
    indep = load_settings(overrides={"prognosis": {"shared_wear_alpha": 0.0}})
    before = prognose(hist, settings=indep)["actuators"]
    after = prognose(hist)["actuators"]
    cov0, n0 = _coverage(before, truth)
    cov1, n1 = _coverage(after, truth)
    assert n0 == n1 == 120
    assert cov0 < 0.85 <= cov1 and cov1 - cov0 >= 0.05, (cov0, cov1)
    shared = [a for a in truth if after[a]["overall"].get("shared_wear")]
    assert len(shared) >= 60
    for a in shared:
        o, o0, F = after[a]["overall"], before[a]["overall"], after[a]["faults"]
        assert o["shared_wear"] == [["fsj", "gm"]] and "shared_wear" not in o0
        assert o["rul_p95_h"] == min(F["gm"]["rul_p95_h"], F["fsj"]["rul_p95_h"]) >= o0["rul_p95_h"]
        assert (o["rul_median_h"], o["rul_p05_h"], o["p_fail_next"]) == \
            (o0["rul_median_h"], o0["rul_p05_h"], o0["p_fail_next"])
    for a in set(truth) - set(shared):
        assert after[a] == before[a]


def test_independent_faults_keep_their_interval():
    """120 units of independent gm and fsj wear: a few are called shared (7, about the test's
    level), and the coverage does not move beyond them (90.0 -> 90.8 %)."""
    hist, truth = _history(120, False, 1)
    before = prognose(hist, settings=load_settings(overrides={"prognosis": {"shared_wear_alpha": 0.0}}))["actuators"]
    after = prognose(hist)["actuators"]
    shared = [a for a in truth if after[a]["overall"].get("shared_wear")]
    assert len(shared) <= 12
    assert abs(_coverage(after, truth)[0] - _coverage(before, truth)[0]) <= len(shared) / 120


def test_shared_wear_alpha_is_checked():
    with pytest.raises(ValueError, match="shared_wear_alpha must be within"):
        load_settings(overrides={"prognosis": {"shared_wear_alpha": 1.0}})


def test_the_table_says_which_faults_wear_together(tmp_path, capsys):
    from eha_health.cli import main
    hist, truth = _history(12, True, 1)
    rows = ["actuator_id,time_h,k_gm,k_fsj,k_bkl,std_gm,std_fsj,std_bkl"]
    for a, h in hist.actuators.items():
        rows += [f"{a},{t!r},{k[0]!r},{k[1]!r},{k[2]!r},0.005,0.005,0.005" for t, k in zip(h.time_h.tolist(), h.k.tolist())]
    (tmp_path / "h.csv").write_text("\n".join(rows) + "\n")
    assert main(["prognose", "--history", str(tmp_path / "h.csv")]) == 0
    out = capsys.readouterr().out
    assert "fsj and gm wear together" in out


def test_the_monitor_status_says_which_faults_wear_together():
    from eha_health.monitoring.prognosis import Outcome, rul_values
    hist, truth = _history(12, True, 1)
    out = prognose(hist)["actuators"]
    shared = [a for a in truth if out[a]["overall"].get("shared_wear")]
    assert shared and len(shared) < len(truth)
    assert rul_values(Outcome(True, out[shared[0]], time_h=1.0))["shared_wear"] == "fsj+gm"
    alone = next(a for a in truth if a not in shared)
    assert "shared_wear" not in rul_values(Outcome(True, out[alone], time_h=1.0))
