"""Run the plant, command and monitor nodes: in one process (:class:`Graph`) or as
three OS processes talking over DDS (:func:`launch`).

>>> with Graph(faults=Faults(0.4, 0.6, 0.4), log_path="out/run.mcap") as g:
...     r = g.run_test()                 # one FDI test through the graph
...     g.set_plant(k_fsj=0.2)           # through the plant's parameter service
...     r2 = g.run_test()
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from ..params import Faults
from . import teardown


class GraphTimeout(RuntimeError):
    pass


class Graph:
    """Plant + command + monitor on one executor in an isolated rclpy context.

    Parameters
    ----------
    faults, effects, seed : the simulated actuator (plant node parameters).
    rate : command playback speed (0 = as fast as the graph allows).
    method, fitness, monitor_seed : identification settings of the monitor.
    log_path : MCAP log of the monitor ('' = none).
    executor : 'single' (``SingleThreadedExecutor``) or 'events' (``EventsExecutor``).
    truth : write the plant's fault parameters into the log metadata (False: an
        "undeclared" recording whose truth stays with whoever made it).
    """

    def __init__(self, faults: Faults = Faults(), effects: tuple[str, ...] = (), seed: int = 0, rate: float = 0.0,
                 method: str = "hybrid", fitness: str = "lsq", monitor_seed: int = 0, log_path: str | Path = "",
                 executor: str = "single", actuator_id: str = "eha", namespace: str = "", truth: bool = True,
                 params_file: str = "", discrepancy: bool = False):
        import rclpy
        from rclpy.parameter import Parameter
        from rclpy.signals import SignalHandlerOptions

        from .command import CommandNode
        from .monitor import MonitorNode
        from .plant import PlantNode
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        P = Parameter
        ns = {"namespace": namespace} if namespace else {}
        self.nodes = []
        try:
            self.plant = PlantNode(context=self.ctx, parameter_overrides=[
                P("k_gm", value=float(faults.k_gm)), P("k_fsj", value=float(faults.k_fsj)),
                P("k_bkl", value=float(faults.k_bkl)), P("effects", value=list(effects) or [""]),
                P("seed", value=int(seed)), P("actuator_id", value=actuator_id),
                P("params_file", value=str(params_file))], **ns)
            self.command = CommandNode(context=self.ctx, parameter_overrides=[
                P("rate", value=float(rate)), P("actuator_id", value=actuator_id)], **ns)
            plant_fqn = self.plant.get_fully_qualified_name()
            self.monitor = MonitorNode(context=self.ctx, parameter_overrides=[
                P("method", value=method), P("fitness", value=fitness), P("seed", value=int(monitor_seed)),
                P("log_path", value=str(log_path)), P("plant_node", value=plant_fqn if truth else ""),
                P("actuator_id", value=actuator_id), P("discrepancy", value=bool(discrepancy))], **ns)
            self.nodes = [self.plant, self.command, self.monitor]
            if executor == "events":
                from rclpy.experimental import EventsExecutor
                self.ex = EventsExecutor(context=self.ctx)
            elif executor == "single":
                from rclpy.executors import SingleThreadedExecutor
                self.ex = SingleThreadedExecutor(context=self.ctx)
            else:
                raise ValueError(f"executor must be 'single' or 'events', got {executor!r}")
            for n in self.nodes:
                self.ex.add_node(n)
        except BaseException:
            self.close()
            raise

    # ---------------------------------------------------------------- driving
    def spin_until(self, predicate, timeout_s: float, what: str) -> None:
        end = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > end:
                raise GraphTimeout(f"graph: {what} not reached within {timeout_s:g} s")
            self.ex.spin_once(timeout_sec=0.01)

    def _wait_truth_service(self) -> None:
        c = self.monitor._truth_client
        if c is not None:
            self.spin_until(c.service_is_ready, 10.0, "plant parameter service discovered")

    def run_test(self, timeout_s: float = 120.0) -> dict:
        """Play one FDI test, wait for the monitor's verdict, return it (see ``MonitorNode.results``)."""
        self._wait_truth_service()
        n = len(self.monitor.results)
        ok, why = self.command.start_test()
        if not ok:
            raise RuntimeError(f"graph: could not start a test: {why}")
        self.spin_until(lambda: len(self.monitor.results) > n, timeout_s, "monitor verdict")
        return self.monitor.results[-1]

    def set_plant(self, timeout_s: float = 10.0, **values) -> None:
        """Change plant parameters through its standard ``set_parameters`` service."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        client = self.monitor.create_client(SetParameters, f"{self.plant.get_fully_qualified_name()}/set_parameters")
        try:
            self.spin_until(client.service_is_ready, timeout_s, "plant set_parameters service")
            req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
            fut = client.call_async(req)
            self.spin_until(fut.done, timeout_s, "set_parameters answer")
            bad = [r.reason for r in fut.result().results if not r.successful]
            if bad:
                raise ValueError(f"plant refused the parameters: {'; '.join(bad)}")
        finally:
            self.monitor.destroy_client(client)

    # ---------------------------------------------------------------- teardown
    def close(self) -> None:
        teardown(getattr(self, "ex", None), getattr(self, "nodes", ()), self.ctx)
        self.nodes = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# --------------------------------------------------------------------------- separate processes
def _ros_args(params: dict) -> list[str]:
    out = ["--ros-args"]
    for k, v in params.items():
        if isinstance(v, bool):
            v = "true" if v else "false"
        elif isinstance(v, float):
            v = repr(v)
        elif isinstance(v, (list, tuple)):
            v = "[" + ",".join(f"'{x}'" for x in v) + "]"
        out += ["-p", f"{k}:={v}"]
    return out


def _stop(procs: list[subprocess.Popen], grace_s: float = 10.0) -> None:
    """SIGINT (a clean rclpy shutdown), then SIGKILL whatever is left."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    end = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.1, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def log_results(log_path: str | Path) -> list[dict]:
    """The monitor's verdicts recorded in an MCAP log (metadata 'diagnosis/test_<id>', 'truth/test_<id>')."""
    import json

    from ..bagrun import truth_values
    from ..mcaplog import read_bag
    meta = read_bag(log_path, topics=[]).metadata
    out = []
    for name, rec in sorted(meta.items()):
        if name.startswith("diagnosis/test_"):
            tid = int(name.rsplit("_", 1)[1])
            d = {k: json.loads(v) for k, v in rec.items()}
            out.append({"test_id": tid, "diagnosis": d, "truth": truth_values(meta.get(f"truth/test_{tid}"))})
    return sorted(out, key=lambda r: r["test_id"])


def _summary(results: list[dict]) -> str:
    lines = []
    for r in results:
        d, t = r["diagnosis"], r["truth"]
        est = "  ".join(f"{k.upper()}={d[k]:.3f}" + (f" (truth {t[k]:.3f})" if t else "") for k in ("k_gm", "k_fsj", "k_bkl"))
        lines.append(f"test {r['test_id']}: {est}; {d['wall_time_s']:.2f} s")
    return "\n".join(lines) or "no diagnosis recorded"


def launch(faults: Faults = Faults(), effects=(), seed: int = 0, tests: int = 1, rate: float = 1.0,
           method: str = "hybrid", log_path: str | Path = "out/launch.mcap", domain_id: int | None = None,
           timeout_s: float = 300.0, namespace: str = "") -> dict:
    """Run plant, command and monitor as three OS processes over DDS until ``tests`` are diagnosed.

    The children inherit the environment (the ROS wheels need it); ``domain_id``
    isolates them from other graphs on the machine.
    """
    if tests < 1:
        raise ValueError(f"tests must be >= 1, got {tests}")
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ValueError(f"domain id must be in 0..232, got {domain_id}")
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    log_path.unlink(missing_ok=True)
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    ns = ["-r", f"__ns:={namespace}"] if namespace else []
    plant_fqn = (namespace.rstrip("/") + "/eha_plant") if namespace else "/eha_plant"
    # the monitor asks for each test once the plant's answers reach it (matched, not only
    # discovered) and the previous verdict is in: no test starts into a half-connected graph
    cmds = {
        "monitor": {"exit_after": tests, "log_path": str(log_path), "plant_node": plant_fqn, "method": method,
                    "request_tests": tests},
        "plant": {"k_gm": float(faults.k_gm), "k_fsj": float(faults.k_fsj), "k_bkl": float(faults.k_bkl),
                  "seed": int(seed), **({"effects": list(effects)} if effects else {})},
        "command": {"max_tests": tests, "rate": float(rate)},
    }
    procs = {name: subprocess.Popen([sys.executable, "-m", f"eha_health.nodes.{name}", *_ros_args(p), *ns], env=env)
             for name, p in cmds.items()}
    end = time.monotonic() + timeout_s
    try:
        # the monitor exits after `tests` verdicts (the command node, done playing, may exit
        # before it); a child that fails (e.g. a plant refusing its parameters) ends the run at once
        while procs["monitor"].poll() is None and time.monotonic() < end:
            if any(p.poll() not in (None, 0) for p in procs.values()):
                break
            time.sleep(0.1)
        ok = procs["monitor"].returncode == 0
    finally:
        _stop(list(procs.values()))
    results = log_results(log_path) if log_path.exists() else []
    ok = ok and len(results) == tests
    summary = _summary(results) + f"\nlog: {log_path}" + ("" if ok else f"\nlaunch: FAILED ({len(results)}/{tests} tests diagnosed)")
    return {"ok": ok, "results": results, "log": str(log_path), "summary": summary,
            "returncodes": {k: p.returncode for k, p in procs.items()}}


# --------------------------------------------------------------------------- replay
def replay(bag: str | Path, rate: float = 1.0, with_monitor: bool = True, log_path: str | Path = "",
           domain_id: int | None = None, method: str = "hybrid", timeout_s: float = 600.0) -> dict:
    """Republish ``bag`` into the graph; with ``with_monitor`` also diagnose it here.

    Returns the monitor's verdicts (with the bag's own truth metadata where it has
    some) and a printable summary.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from ..bagrun import complete_windows, resolve_topics, truth_values
    from ..mcaplog import read_bag
    from .monitor import MonitorNode
    from .replay import ReplayNode
    from msg_bridge import contract as C
    if domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    win_topic = resolve_topics(read_bag(bag, topics=[]).types, bag).get(C.TEST_WINDOW.name)
    marks = read_bag(bag, topics=[win_topic] if win_topic else [])   # the marks and the metadata
    n_windows = len(complete_windows(marks, win_topic)) if with_monitor else 0
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    nodes = []
    ex = SingleThreadedExecutor(context=ctx)
    try:
        rep = ReplayNode(bag, context=ctx, parameter_overrides=[Parameter("rate", value=float(rate))])
        nodes.append(rep)
        mon = None
        if with_monitor:
            mon = MonitorNode(context=ctx, parameter_overrides=[Parameter("log_path", value=str(log_path)),
                                                                 Parameter("method", value=method)])
            nodes.append(mon)
        for n in nodes:
            ex.add_node(n)
        end = time.monotonic() + timeout_s

        def finished():
            if not rep.done:
                return False
            return mon is None or (len(mon.results) >= n_windows and not mon.busy)
        while not finished() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)
        linger = time.monotonic() + 1.0   # let reliable deliveries to other processes complete
        while mon is None and time.monotonic() < linger:
            ex.spin_once(timeout_sec=0.01)
        results = [{"test_id": r["test_id"], "level": r["level"], "message": r["message"],
                    "diagnosis": r["diagnosis"].as_dict() if r["diagnosis"] else None,
                    "truth": truth_values(marks.metadata.get(f"truth/test_{r['test_id']}"))}
                   for r in (mon.results if mon else [])]
        sent = rep.sent
    finally:
        teardown(ex, nodes, ctx)
    ok = [r for r in results if r["diagnosis"]]
    summary = f"replayed {sent} messages from {bag} at rate {rate:g}"
    if with_monitor:
        summary += "\n" + _summary(ok)
        summary += "".join(f"\ntest {r['test_id']}: {r['level']}: {r['message']}" for r in results if not r["diagnosis"])
    return {"sent": sent, "results": results, "summary": summary}
