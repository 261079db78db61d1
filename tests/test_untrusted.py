"""Files and parameters are untrusted data (issue 18, item 8).

* No code path can run what a file says: no ``yaml.load`` without the safe loader, no
  pickle/marshal/shelve, no ``eval``/``exec``, no ``numpy.load(allow_pickle=True)``, no shell
  command lines (read from the sources' syntax trees, lazy imports included).
* Every numeric ROS parameter of every node has a declared range; out-of-range, NaN and
  wrong-choice values are refused through the real ``set_parameters`` service and at start.
"""
import ast
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from eha_health.ros import command, monitor, plant, relay, replay, teardown
from eha_health.ros.params import markdown_table

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted(p for d in ("src", "msg_bridge", "tools") for p in (ROOT / d).rglob("*.py"))
UNSAFE_MODULES = {"pickle", "cPickle", "dill", "marshal", "shelve", "joblib", "cloudpickle"}


def _name(node) -> str:
    """Dotted name of a call's function (``yaml.load``, ``np.load``, ``eval``)."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
    return ".".join(reversed(parts))


def unsafe_uses(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    out = []
    for node in ast.walk(tree):
        where = f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', 0)}"
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            out += [f"{where}: imports {m}" for m in mods if m.split(".")[0] in UNSAFE_MODULES]
        if not isinstance(node, ast.Call):
            continue
        name, kw = _name(node.func), {k.arg: k.value for k in node.keywords}
        if name in ("eval", "exec", "compile", "__import__"):
            out.append(f"{where}: {name}()")
        elif name.endswith(("yaml.load", "yaml.load_all", "yaml.unsafe_load", "yaml.full_load")):
            loader = kw.get("Loader", node.args[1] if len(node.args) > 1 else None)
            if loader is None or "Safe" not in _name(loader):
                out.append(f"{where}: {name} without a safe loader")
        elif name.endswith(".load") and isinstance(kw.get("allow_pickle"), ast.Constant) and kw["allow_pickle"].value:
            out.append(f"{where}: {name}(allow_pickle=True)")
        elif isinstance(kw.get("shell"), ast.Constant) and kw["shell"].value:
            out.append(f"{where}: {name}(shell=True)")
    return out


def test_the_scanner_finds_each_unsafe_construct(tmp_path):
    bad = ROOT / "tests" / "_unsafe_sample.py"
    bad.write_text("import pickle\nimport yaml\nimport numpy as np\nimport subprocess\n"
                   "yaml.load(open('x'))\nyaml.load(t, Loader=yaml.SafeLoader)\neval('1')\n"
                   "np.load('a.npy', allow_pickle=True)\nsubprocess.run('ls', shell=True)\n")
    try:
        found = unsafe_uses(bad)
    finally:
        bad.unlink()
    assert [f.split(": ", 1)[1] for f in found] == [
        "imports pickle", "yaml.load without a safe loader", "eval()", "np.load(allow_pickle=True)",
        "subprocess.run(shell=True)"]


def test_no_source_can_execute_file_contents():
    assert len(SOURCES) > 50
    found = [u for p in SOURCES for u in unsafe_uses(p)]
    assert not found, "\n".join(found)


NODES = {"plant": (plant.PlantNode, plant.PARAMS), "command": (command.CommandNode, command.PARAMS),
         "monitor": (monitor.MonitorNode, monitor.PARAMS)}


def test_every_numeric_parameter_has_a_documented_range():
    docs = (ROOT / "docs" / "interfaces.md").read_text()
    for table in (plant.PARAMS, command.PARAMS, monitor.PARAMS, replay.PARAMS, relay.PARAMS):
        for p in table:
            numeric = isinstance(p.default, (int, float)) and not isinstance(p.default, bool)
            assert not numeric or (p.lo is not None and p.lo <= p.default <= p.hi), p.name
            assert not p.choices or p.default in p.choices, p.name
    for mod in (plant, command, monitor, replay, relay):
        assert markdown_table(mod.PARAMS) in docs, f"{mod.__name__}: parameter table of docs/interfaces.md is stale"


def _bad_values(p):
    if p.choices:
        return [p.default + "_unknown"]
    if p.lo is None:
        return []
    if isinstance(p.default, int):
        return [int(p.lo) - 1, int(p.hi) + 1]
    return [p.lo - 1e-3 * max(1.0, abs(p.lo)), p.hi * 1.001 + 1e-9, math.nan, math.inf]


@pytest.fixture(scope="module")
def nodes():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    made = {}
    try:
        for key, (cls, _) in NODES.items():
            made[key] = cls(context=ctx, **({"parameter_overrides": [Parameter("log_path", value="")]}
                                            if key == "monitor" else {}))
        client_node = rclpy.create_node("param_prober", context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        for n in (*made.values(), client_node):
            ex.add_node(n)
        yield made, client_node, ex
    finally:
        teardown(locals().get("ex"), [*made.values(), *([client_node] if "client_node" in locals() else [])], ctx)


def _set(ex, client_node, node, name, value):
    """One ``set_parameters`` call through the node's real service; the result message."""
    client = client_node.create_client(SetParameters, f"{node.get_fully_qualified_name()}/set_parameters")
    try:
        end = 60.0           # a generous deadline (busy machine), not a speed check
        t0 = time.monotonic()
        while not client.service_is_ready():
            assert time.monotonic() - t0 < end, "set_parameters service not discovered"
            ex.spin_once(timeout_sec=0.05)
        fut = client.call_async(SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()]))
        while not fut.done():
            assert time.monotonic() - t0 < end, "no set_parameters answer"
            ex.spin_once(timeout_sec=0.05)
        return fut.result().results[0]
    finally:
        client_node.destroy_client(client)


@pytest.mark.parametrize("key", list(NODES))
def test_out_of_range_parameters_are_refused_through_the_service(nodes, key):
    made, client_node, ex = nodes
    node, table = made[key], NODES[key][1]
    checked = 0
    for p in table:
        before = node.get_parameter(p.name).value
        for bad in _bad_values(p):
            res = _set(ex, client_node, node, p.name, bad)
            assert not res.successful, f"{key}.{p.name} = {bad!r} was accepted"
            assert p.name in res.reason or "range" in res.reason, res.reason
            assert node.get_parameter(p.name).value == before
            checked += 1
        if p.lo is not None and not p.start_only:       # the range's own ends are accepted
            for ok in (p.hi, p.default):
                assert _set(ex, client_node, node, p.name, type(p.default)(ok)).successful, (p.name, ok)
    assert checked >= 3


def test_a_monitor_parameter_read_at_start_only_is_refused_at_run_time(nodes):
    """Probe 11: set_parameters accepted history, prognostics_settings, next_check_h, warn_p_fail,
    error_p_fail (successful=True) and they did nothing; a new actuator_id relabelled the status while
    the tests went on into the old actuator's history. Each such change is refused, naming the
    parameter; warn_level and operating_hours still take effect at run time."""
    made, client_node, ex = nodes
    node = made["monitor"]
    changes = {"actuator_id": "ACT-2", "history": "other.sqlite", "prognostics_settings": "mine.yaml",
               "next_check_h": 50.0, "warn_p_fail": 0.2, "error_p_fail": 0.5, "log_path": "x.mcap",
               "keep_verdicts": 5, "diagnostics_period_s": 2.0, "best_effort": True}
    for name, value in changes.items():
        before = node.get_parameter(name).value
        res = _set(ex, client_node, node, name, value)
        assert not res.successful and name in res.reason, (name, res.reason)
        assert node.get_parameter(name).value == before
        assert node.describe_parameter(name).read_only and "(start only)" in node.describe_parameter(name).description
    assert set(changes) <= {p.name for p in monitor.PARAMS if p.start_only}
    for name, value in (("warn_level", 0.25), ("operating_hours", 120.0), ("usage", 3.0)):
        assert _set(ex, client_node, node, name, value).successful, name
        assert node.get_parameter(name).value == value
        assert _set(ex, client_node, node, name, monitor.PARAMS[[p.name for p in monitor.PARAMS].index(name)].default
                    ).successful


def test_a_node_given_an_out_of_range_parameter_at_start_exits_2_with_one_line():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]))
    out = subprocess.run([sys.executable, "-m", "eha_health.ros.monitor", "--ros-args", "-p", "warn_level:=2.0",
                          "-p", "log_path:=''"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "warn_level" in lines[0] and "range" in lines[0], out.stderr


@pytest.mark.parametrize("module, argv", [
    ("monitor", ["--ros-args", "-p", "actuator_id:=A", "7"]), ("plant", ["--ros-args", "-p", "seed:=1", "7"]),
    ("command", ["--ros-args", "-p", "rate:=1.0", "7"]), ("replay", ["--ros-args", "-p", "bag:=x.mcap", "7"]),
    ("monitor", ["7", "--ros-args", "-p", "log_path:=''"]),
])
def test_a_node_given_a_stray_argument_exits_2_with_one_line(module, argv):
    """Probe 11: a stray '7' after --ros-args ended in rclpy's UnknownROSArgsError traceback, rc 1;
    before --ros-args rclpy ignores it and the node ran without the setting it was meant to be."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]))
    # a deadline for a node that would run on (the one given '7' before --ros-args did)
    out = subprocess.run([sys.executable, "-m", f"eha_health.ros.{module}", *argv], env=env, capture_output=True,
                         text=True, timeout=120)
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert out.returncode == 2 and len(lines) == 1 and "7" in lines[0] and "argument" in lines[0], out.stderr
