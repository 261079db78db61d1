"""Window assembly and message conversions (no executor needed)."""
import numpy as np
import pytest

from eha_health.io.window import Samples, WindowError, assemble
from eha_health.physics.model import simulate
from msg_bridge import convert as cv

NS = 1_000_000_000


@pytest.fixture(scope="module")
def run():
    return simulate()


def channels(r, start=5 * NS):
    st = start + np.round(r.t * NS).astype(np.int64)
    return {c: Samples(st.copy(), getattr(r, c).copy()) for c in ("command", "position", "velocity", "pressure",
                                                                   "current")}, st


def test_assemble_rebuilds_the_response(run):
    ch, st = channels(run)
    r = assemble(ch, int(st[0]), int(st[-1]))
    assert len(r) == len(run)
    np.testing.assert_allclose(r.t, run.t, atol=1e-12)
    for c in ("command", "position", "velocity", "pressure", "current"):
        np.testing.assert_array_equal(getattr(r, c), getattr(run, c))


@pytest.mark.parametrize("damage, phrase", [
    ("nan", "pressure: 1 NaN"), ("drop", "current: 1 sample(s) missing"), ("dup", "position: duplicate stamp"),
    ("order", "velocity: stamps out of order"), ("gap", "command: gap"), ("short", "window too short"),
    ("extra", "pressure: 1 sample(s) at stamps with no command")])
def test_assemble_names_the_damage(run, damage, phrase):
    ch, st = channels(run)
    end = int(st[-1])
    if damage == "nan":
        ch["pressure"].values[1234] = np.nan
    elif damage == "drop":
        ch["current"] = Samples(np.delete(ch["current"].stamps, 2000), np.delete(ch["current"].values, 2000))
    elif damage == "dup":
        ch["position"].stamps[1001] = ch["position"].stamps[1000]
    elif damage == "order":
        s = ch["velocity"].stamps
        s[[1500, 1501]] = s[[1501, 1500]]
    elif damage == "gap":
        ch = {c: Samples(np.delete(s.stamps, range(100, 110)), np.delete(s.values, range(100, 110)))
              for c, s in ch.items()}
    elif damage == "short":
        end = int(st[2000])
    elif damage == "extra":
        s = ch["pressure"]
        ch["pressure"] = Samples(np.append(s.stamps, s.stamps[-1] - 1), np.append(s.values, 0.0))
        ch["pressure"] = Samples(np.sort(ch["pressure"].stamps), ch["pressure"].values)
    with pytest.raises(WindowError, match=phrase.replace("(", r"\(").replace(")", r"\)")):
        assemble(ch, int(st[0]), end)


def test_conversions_round_trip():
    ns = 12 * NS + 345
    assert cv.command_from_msg(cv.command_msg(ns, 0.01, "a")) == (ns, 0.01)
    assert cv.joint_state_from_msg(cv.joint_state_msg(ns, 0.002, -0.1, "a")) == (ns, 0.002, -0.1)
    assert cv.pressure_from_msg(cv.pressure_msg(ns, 3.5e6, "a")) == (ns, 3.5e6)
    assert cv.current_from_msg(cv.current_msg(ns, 0.004, "a")) == (ns, 0.004)
    assert cv.window_from_msg(cv.window_msg(ns, "start", 7)) == (ns, "start", 7)
    k, s = cv.health_from_msg(cv.health_msg([0.1, 0.2, 0.3], [0.01, 0.02, 0.03]))
    assert list(k) == [0.1, 0.2, 0.3] and list(s) == [0.01, 0.02, 0.03]
    d = cv.diagnostic_array(ns, "m: eha", "eha", "WARN", "degraded", {"k_gm": 0.5, "method": "hybrid"})
    st = d.status[0]
    assert st.level == b"\x01" and st.hardware_id == "eha"
    assert {kv.key: kv.value for kv in st.values} == {"k_gm": "0.5", "method": "hybrid"}


def test_conversions_reject_bad_messages():
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header
    with pytest.raises(ValueError, match="velocity is empty"):
        cv.joint_state_from_msg(JointState(position=[0.0]))
    with pytest.raises(ValueError, match="frame_id must be"):
        cv.window_from_msg(Header(frame_id="begin"))
    with pytest.raises(ValueError, match="'start' or 'end'"):
        cv.window_msg(0, "middle", 1)
