"""The node graph with real rclpy nodes on real executors, real MCAP files, real DDS.

Every Graph runs in its own rclpy Context (isolated; torn down in the order the
ros2-from-pypi notes give). The identification tolerance on clean data is 0.01.
"""
import os
import shutil

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from eha_health.io.bagrun import read_run
from eha_health.io.mcaplog import read_bag
from eha_health.physics.faults import FAULT_NAMES as NAMES
from eha_health.physics.faults import Faults
from eha_health.ros.graph import Graph
from eha_health.ros.launch import launch
from eha_health.ros.replay import replay

pytestmark = pytest.mark.graph

TOL = 0.01


def errors(result, truth: Faults):
    d = result["diagnosis"]
    assert d is not None, result["message"]
    return np.abs(np.array(d.faults.as_tuple()) - np.array(truth.as_tuple()))


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """One logged run of gm=0.4, fsj=0.6, bkl=0.4, shared by the log/replay tests."""
    log = tmp_path_factory.mktemp("live") / "live.mcap"
    faults = Faults(0.4, 0.6, 0.4)
    with Graph(faults=faults, log_path=log) as g:
        r = g.run_test()
    return {"log": log, "result": r, "faults": faults}


def test_graph_diagnoses_injected_faults_and_follows_a_parameter_change(tmp_path):
    first, second = Faults(0.4, 0.6, 0.4), Faults(0.0, 0.2, 0.4)
    with Graph(faults=first, log_path=tmp_path / "two.mcap") as g:
        r1 = g.run_test()
        # degrade/repair the actuator between two tests through the standard parameter service
        g.set_plant(k_gm=0.0, k_fsj=0.2)
        r2 = g.run_test()
    assert errors(r1, first).max() <= TOL
    assert errors(r2, second).max() <= TOL
    assert r1["diagnosis"].faults.k_fsj - r2["diagnosis"].faults.k_fsj > 0.35
    assert r1["truth"]["k_fsj"] == 0.6 and r2["truth"]["k_fsj"] == 0.2
    assert r1["level"] == "WARN" and "K_FSJ" in r1["message"]


def test_plant_refuses_bad_parameters_and_keeps_running(tmp_path):
    with Graph(faults=Faults(0.0, 0.3, 0.0), log_path="") as g:
        with pytest.raises(ValueError, match="k_gm"):
            g.set_plant(k_gm=2.0)          # outside the declared 0..1.5 range
        with pytest.raises(ValueError, match="unknown effect 'oil_foam'"):
            g.set_plant(effects=["oil_foam"])
        assert g.plant.plant.faults == Faults(0.0, 0.3, 0.0)
        r = g.run_test()
    assert errors(r, Faults(0.0, 0.3, 0.0)).max() <= TOL


def test_log_decodes_with_rosbags_every_topic_type_and_count(live):
    counts, types = {}, {}
    with AnyReader([live["log"]], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            types[conn.topic] = conn.msgtype
            if conn.topic == "/eha/health":
                health = np.asarray(msg.data)
            if conn.topic == "/eha/pressure":
                assert msg.fluid_pressure == msg.fluid_pressure   # decodes to a number
    assert types == {"/eha/command": "sensor_msgs/msg/JointState", "/eha/joint_state": "sensor_msgs/msg/JointState",
                     "/eha/pressure": "sensor_msgs/msg/FluidPressure", "/eha/current": "sensor_msgs/msg/JointState",
                     "/eha/test_window": "std_msgs/msg/Header", "/eha/health": "std_msgs/msg/Float64MultiArray",
                     "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
    for t in ("/eha/command", "/eha/joint_state", "/eha/pressure", "/eha/current"):
        assert counts[t] == 3500, t
    assert counts["/eha/test_window"] == 2 and counts["/eha/health"] == 1 and counts["/diagnostics"] >= 1
    d = live["result"]["diagnosis"]
    np.testing.assert_allclose(health[:3], d.faults.as_tuple())
    meta = read_bag(live["log"], topics=[]).metadata
    assert meta["truth/test_1"]["k_fsj"] == "0.6"
    assert set(meta["diagnosis/test_1"]) >= {"k_gm", "k_fsj", "k_bkl", "std", "method", "wall_time_s"}


def test_offline_and_replayed_diagnosis_equal_the_live_one(live, tmp_path):
    d_live = live["result"]["diagnosis"]
    run = read_run(live["log"])
    np.testing.assert_array_equal(run.response.position, live["result"]["response"].position)
    out = replay(live["log"], rate=0.0, log_path=tmp_path / "replayed.mcap", history=tmp_path / "h.sqlite",
                 actuator_id="ACT-R")
    assert out["sent"] == 4 * 3500 + 2
    (r,) = out["results"]
    for n in NAMES:
        assert r["diagnosis"][n] == getattr(d_live.faults, n)
    # the replay's monitor appended its diagnosis to the history it was given
    from eha_health.prognostics.store import HistoryStore
    with HistoryStore(tmp_path / "h.sqlite") as st:
        (row,) = st.list_tests()
    assert row["actuator_id"] == "ACT-R" and row["k_gm"] == d_live.faults.k_gm
    assert r["truth"] == dict(zip(NAMES, live["faults"].as_tuple()))
    # the replay's own log holds the same samples
    assert read_bag(tmp_path / "replayed.mcap", topics=["/eha/pressure"]).messages["/eha/pressure"]


def test_latched_health_reaches_a_late_subscriber():
    from msg_bridge import contract as C
    with Graph(faults=Faults(0.0, 0.0, 0.5)) as g:
        d = g.run_test()["diagnosis"]
        got = g.listen(C.HEALTH, "late_subscriber")
        g.spin_until(lambda: got, 120.0, "latched health")
    np.testing.assert_allclose(got[0].data[:3], d.faults.as_tuple())
    np.testing.assert_allclose(got[0].data[3:], [d.std[n] for n in NAMES])


def _trigger(g):
    from std_srvs.srv import Trigger
    cli = g.monitor.create_client(Trigger, "eha/start_test")
    g.spin_until(cli.service_is_ready, 120.0, "start_test service")
    fut = cli.call_async(Trigger.Request())
    g.spin_until(fut.done, 120.0, "trigger answer")
    return fut.result()


def test_trigger_service_and_samples_independent_of_playback_speed():
    runs = {}
    for rate in (0.0, 4.0):
        with Graph(faults=Faults(0.2, 0.5, 0.3), effects=("sensor_noise",), seed=3, rate=rate) as g:
            first = _trigger(g)
            again = _trigger(g)       # refused: the first test still plays
            g.spin_until(lambda: g.monitor.results, 600.0, "verdict")
            runs[rate] = g.monitor.results[0]
        assert first.success and "test 1 started" in first.message
        assert not again.success and "still playing" in again.message
    a, b = runs[0.0]["response"], runs[4.0]["response"]
    for c in ("command", "position", "velocity", "pressure", "current"):
        np.testing.assert_array_equal(getattr(a, c), getattr(b, c))
    assert runs[0.0]["diagnosis"].faults == runs[4.0]["diagnosis"].faults


def test_log_cut_off_mid_run_keeps_every_complete_window(tmp_path):
    log = tmp_path / "open.mcap"
    with Graph(faults=Faults(0.6, 0.0, 0.0), log_path=log) as g:
        g.run_test()
        snapshot = tmp_path / "crashed.mcap"
        shutil.copyfile(log, snapshot)      # as if the process died now: no summary, no footer
        size = snapshot.stat().st_size
        with open(snapshot, "ab") as f:      # and a half-written chunk at the end
            f.write(b"\x06" + os.urandom(40))
    bag = read_bag(snapshot)
    assert bag.truncated
    assert len(bag.messages["/eha/command"]) == 3500
    run = read_run(snapshot)
    assert len(run.response) == 3500 and run.truth["k_gm"] == "0.6"
    assert size < log.stat().st_size


def test_three_processes_over_dds_with_an_isolated_domain(tmp_path):
    domain = 1 + (int(os.environ["ROS_DOMAIN_ID"]) + 50) % 200   # not the in-process tests' domain
    res = launch(Faults(0.4, 0.6, 0.4), rate=0.0, log_path=tmp_path / "launch.mcap", domain_id=domain,
                 timeout_s=900,      # a deadline for a stuck graph (one test took 120 s at load 20), not a speed check
                 history=tmp_path / "h.sqlite", actuator_id="ACT-3")
    assert res["ok"], res["summary"]
    assert all(rc is not None for rc in res["returncodes"].values())   # nobody left behind
    (r,) = res["results"]
    est = np.array([r["diagnosis"][n] for n in NAMES])
    assert np.abs(est - [0.4, 0.6, 0.4]).max() <= TOL
    assert r["truth"] == {"k_gm": 0.4, "k_fsj": 0.6, "k_bkl": 0.4}
    # the monitor process appended its diagnosis to the history it was given
    from eha_health.prognostics.store import HistoryStore
    with HistoryStore(tmp_path / "h.sqlite") as st:
        (row,) = st.list_tests()
    assert row["actuator_id"] == "ACT-3" and abs(row["k_fsj"] - est[1]) < 1e-9


def _history_to_1000_h(db):
    """A history whose actuator ACT-7 has tests up to 1000 h (an operating clock no stamp reaches)."""
    from eha_health.prognostics.records import HealthRecord
    from eha_health.prognostics.store import HistoryStore
    with HistoryStore(db) as st:
        st.add_tests([HealthRecord("ACT-7", t, (0.01, 0.02, 0.0), (0.002,) * 3) for t in (100.0, 500.0, 1000.0)])
        return st.list_tests()


def test_launch_says_what_went_into_the_history_and_fails_when_nothing_could(tmp_path, capsys):
    """Probe 11: the tests' times were their simulated stamps in hours, every append refused, and
    the command exited 0 with a summary that never named the history."""
    from eha_health.cli import main
    from eha_health.prognostics.store import HistoryStore
    db = tmp_path / "h.sqlite"
    stored = _history_to_1000_h(db)
    domain = 1 + (int(os.environ["ROS_DOMAIN_ID"]) + 60) % 200
    argv = ["launch", "--faults", "gm=0.1,fsj=0.78,bkl=0.1", "--rate", "0", "--domain-id", str(domain),
            "--history", str(db), "--actuator", "ACT-7", "--log", str(tmp_path / "launch.mcap"), "--timeout", "900"]
    assert main(argv + ["--tests", "2"]) == 1
    out = capsys.readouterr().out
    assert f"history {db} (actuator ACT-7): 0 of 2 diagnosed test(s) appended, 2 refused (first: test 1: " in out
    assert "times out of order" in out and "--operating-hours" in out
    with HistoryStore(db, readonly=True) as st:
        assert st.list_tests() == stored
    # one operating time is one test's: two would give the second the first's time
    assert main(argv + ["--tests", "2", "--operating-hours", "1100"]) == 2
    assert "one test's time" in capsys.readouterr().err
    assert main(argv + ["--tests", "1", "--operating-hours", "1100"]) == 0
    assert f"history {db} (actuator ACT-7): 1 of 1 diagnosed test(s) appended\n" in capsys.readouterr().out
    with HistoryStore(db, readonly=True) as st:
        assert [t["time_h"] for t in st.list_tests()] == [100.0, 500.0, 1000.0, 1100.0]


def test_replay_says_what_went_into_the_history_and_takes_operating_hours(live, tmp_path, capsys):
    from eha_health.cli import main
    from eha_health.prognostics.store import HistoryStore
    db = tmp_path / "h.sqlite"
    stored = _history_to_1000_h(db)
    argv = ["replay", str(live["log"]), "--rate", "0", "--history", str(db), "--actuator", "ACT-7"]
    assert main(argv) == 1
    out = capsys.readouterr().out
    assert f"history {db} (actuator ACT-7): 0 of 1 diagnosed test(s) appended, 1 refused (first: test 1: " in out
    with HistoryStore(db, readonly=True) as st:
        assert st.list_tests() == stored
    assert main(argv + ["--operating-hours", "1100"]) == 0
    assert f"history {db} (actuator ACT-7): 1 of 1 diagnosed test(s) appended" in capsys.readouterr().out
    with HistoryStore(db, readonly=True) as st:
        (last,) = st.list_tests()[3:]
    assert last["time_h"] == 1100.0 and last["sim_time_s"] is not None
    # the same recording again: already in the history, not a failure
    assert main(argv + ["--operating-hours", "1100"]) == 0
    assert "0 of 1 diagnosed test(s) appended, 1 already in it" in capsys.readouterr().out


def test_periodic_tests_play_back_to_back_and_each_is_diagnosed():
    from rclpy.parameter import Parameter
    truth = np.array([0.3, 0.5, 0.2])
    with Graph(faults=Faults(*truth)) as g:
        g.command.set_parameters([Parameter("period_s", value=4.0), Parameter("max_tests", value=2)])
        g.spin_until(lambda: len(g.monitor.results) >= 2, 900.0, "two periodic verdicts")   # deadline, busy machine
        assert g.command.done
    a, b = g.monitor.results
    assert (a["test_id"], b["test_id"]) == (1, 2)
    # the second test starts one period after the first, in simulated time
    assert b["start_ns"] - a["start_ns"] == 4_000_000_000
    # the sequence ends at -5 mm; in the settle time the command node brought the actuator back
    # to the start, where dry friction stopped it: a few um off, holding a load pressure, the jack
    # against one side of its play -- not the rest the first test started from
    assert abs(a["response"].position[-1]) > 4e-3
    assert abs(b["response"].position[0]) < 5e-5 and abs(b["response"].velocity[0]) < 1e-3
    assert abs(b["response"].pressure[0]) > 10 * max(abs(a["response"].pressure[0]), 1.0)
    # the monitor fits the first from rest and the second from the sequence's preamble
    assert a["diagnosis"].guard == "passed" and b["diagnosis"].guard == "after a test", b["diagnosis"].warnings
    for r in (a, b):
        assert np.abs(np.array(r["diagnosis"].faults.as_tuple()) - truth).max() <= TOL, r["diagnosis"].faults


def test_launch_ends_at_once_when_a_node_refuses_its_parameters(tmp_path):
    import time
    domain = 1 + (int(os.environ["ROS_DOMAIN_ID"]) + 60) % 200
    t0 = time.monotonic()
    timeout_s = 900.0
    res = launch(Faults(0.4, 0.0, 0.0), effects=["oil_foam"], rate=0.0, log_path=tmp_path / "x.mcap",
                 domain_id=domain, timeout_s=timeout_s)
    assert not res["ok"]
    assert res["returncodes"]["plant"] == 2          # refused at start, one line, no traceback
    # ended by the plant's exit, not by the timeout (a long one, so a busy machine cannot reach it:
    # a logical check, not a speed check)
    assert time.monotonic() - t0 < timeout_s
    assert all(rc is not None for rc in res["returncodes"].values())


def test_start_test_is_refused_until_a_plant_is_matched():
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from std_srvs.srv import Trigger

    from eha_health.ros import teardown
    from eha_health.ros.command import CommandNode
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = CommandNode(context=ctx)
    try:
        res = node._on_trigger(Trigger.Request(), Trigger.Response())
        assert not res.success and "no plant matched" in res.message
        assert node.tests_started == 0
    finally:
        teardown(None, [node], ctx)


def test_a_stop_while_a_tests_samples_arrive_warns_that_the_window_is_dropped(tmp_path, capfd):
    """Probe 11: a monitor stopped (Ctrl-C; run_node's teardown calls the same close) with a test's
    samples still arriving dropped its window without a word, though the docs promise a warning.
    The window is dropped with a warning naming the test and the log's metadata saying why; its
    samples are in the log."""
    log = tmp_path / "mon.mcap"
    g = Graph(rate=1.0, method="deterministic", log_path=log)
    try:
        g._wait_truth_service()
        ok, why = g.command.start_test()
        assert ok, why
        mon = g.monitor

        def streaming():   # the start mark is in, no end mark, and samples of the test are arriving
            ws = [w for w in mon.windows.windows.values() if w.start is not None and w.end is None]
            return ws and mon.windows.last["command"] >= ws[0].start + 100 * 10**6
        g.spin_until(streaming, 600.0, "the test streaming in")
        tid = next(iter(mon.windows.windows))
    finally:
        g.close()
    err = capfd.readouterr().err
    assert (f"test {tid}: not diagnosed, the monitor stopped while its samples were still arriving (no end "
            f"mark); the samples that came are in the log") in err, err[-2000:]
    bag = read_bag(log)
    assert bag.metadata[f"dropped/test_{tid}"]["reason"] == ("the monitor stopped while its samples were still "
                                                             "arriving (no end mark)"), bag.metadata
    assert len(bag.messages["/eha/command"]) >= 100 and not any(k.startswith("diagnosis/") for k in bag.metadata)
