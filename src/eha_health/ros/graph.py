"""Run the plant, command and monitor nodes in one process, on one executor (:class:`Graph`).

The same nodes as three OS processes over DDS: :func:`eha_health.ros.launch.launch`.

>>> with Graph(faults=Faults(0.4, 0.6, 0.4), log_path="out/run.mcap") as g:
...     r = g.run_test()                 # one FDI test through the graph
...     g.set_plant(k_fsj=0.2)           # through the plant's parameter service
...     r2 = g.run_test()
"""
from __future__ import annotations

import time
from pathlib import Path

import rclpy
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from ..identification.diagnose import DEFAULT_METHOD
from ..physics.faults import Faults
from . import teardown
from .command import CommandNode
from .monitor import MonitorNode
from .plant import PlantNode
from .relay import RELAYED, LossyRelayNode, upstream


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
    loss : a :class:`~eha_health.ros.relay.LossyRelayNode` between plant and monitor dropping this
        fraction of the samples (None: no relay); ``loss_seed`` seeds it, ``best_effort`` makes the
        link (relay publisher and monitor subscriptions) BEST_EFFORT.
    max_fill : the monitor's ``max_fill_samples`` (gap fill; 0 refuses any gap).
    plant : False runs no plant in this process (one in another process, e.g. to kill it).
    monitor_params : more monitor parameters by name (e.g. ``history``, ``operating_hours``).
    """

    def __init__(self, faults: Faults = Faults(), effects: tuple[str, ...] = (), seed: int = 0, rate: float = 0.0,
                 method: str = DEFAULT_METHOD, fitness: str = "lsq", monitor_seed: int = 0, log_path: str | Path = "",
                 executor: str = "single", actuator_id: str = "eha", namespace: str = "", truth: bool = True,
                 params_file: str = "", discrepancy: bool = False, loss: float | None = None, loss_seed: int = 0,
                 best_effort: bool = False, max_fill: int = 0, plant: bool = True, monitor_params: dict | None = None):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        P = Parameter
        ns = {"namespace": namespace} if namespace else {}
        self.nodes = []
        # with a relay the plant (and the command node's flow control) use the upstream topics
        lossy = {"cli_args": ["--ros-args", *(a for t in RELAYED for a in ("-r", f"{t.name}:={upstream(t)}"))]} \
            if loss is not None else {}
        self.plant = self.relay = None
        try:
            if plant:
                self.plant = PlantNode(context=self.ctx, parameter_overrides=[
                    P("k_gm", value=float(faults.k_gm)), P("k_fsj", value=float(faults.k_fsj)),
                    P("k_bkl", value=float(faults.k_bkl)), P("effects", value=list(effects) or [""]),
                    P("seed", value=int(seed)), P("actuator_id", value=actuator_id),
                    P("params_file", value=str(params_file))], **ns, **lossy)
            self.command = CommandNode(context=self.ctx, parameter_overrides=[
                P("rate", value=float(rate)), P("actuator_id", value=actuator_id)], **ns, **lossy)
            if loss is not None:
                self.relay = LossyRelayNode(context=self.ctx, parameter_overrides=[
                    P("drop_fraction", value=float(loss)), P("seed", value=int(loss_seed)),
                    P("best_effort", value=bool(best_effort))], **ns)
            plant_fqn = self.plant.get_fully_qualified_name() if plant else ""
            self.monitor = MonitorNode(context=self.ctx, parameter_overrides=[
                P("method", value=method), P("fitness", value=fitness), P("seed", value=int(monitor_seed)),
                P("log_path", value=str(log_path)), P("plant_node", value=plant_fqn if truth else ""),
                P("actuator_id", value=actuator_id), P("discrepancy", value=bool(discrepancy)),
                P("best_effort", value=bool(best_effort)), P("max_fill_samples", value=int(max_fill)),
                *(P(k, value=v) for k, v in (monitor_params or {}).items())], **ns)
            self.nodes = [n for n in (self.plant, self.command, self.relay, self.monitor) if n is not None]
            if executor == "events":
                self.ex = EventsExecutor(context=self.ctx)
            elif executor == "single":
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
            self.spin_until(c.service_is_ready, 120.0, "plant parameter service discovered")

    def run_test(self, timeout_s: float = 600.0) -> dict:
        """Play one FDI test, wait for the monitor's verdict, return it (see ``MonitorNode.results``).

        ``timeout_s`` is a deadline for a graph that is stuck, not a speed target: on a busy 2-core
        machine one test took up to 120 s (measured, load 20), so the default is 600 s."""
        self._wait_truth_service()
        n = self.monitor.verdicts
        ok, why = self.command.start_test()
        if not ok:
            raise RuntimeError(f"graph: could not start a test: {why}")
        self.spin_until(lambda: self.monitor.verdicts > n, timeout_s, "monitor verdict")
        return self.monitor.results[-1]

    def set_plant(self, timeout_s: float = 120.0, **values) -> None:
        """Change plant parameters through its standard ``set_parameters`` service."""
        self.set_parameters(self.plant, timeout_s, **values)

    def set_parameters(self, node, timeout_s: float = 120.0, **values) -> None:
        """Change ``node``'s parameters through its standard ``set_parameters`` service, as
        ``ros2 param set`` does (ValueError: the node refused them)."""
        client = self.command.create_client(SetParameters, f"{node.get_fully_qualified_name()}/set_parameters")
        try:
            self.spin_until(client.service_is_ready, timeout_s, f"{node.get_name()} set_parameters service")
            req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
            fut = client.call_async(req)
            self.spin_until(fut.done, timeout_s, "set_parameters answer")
            bad = [r.reason for r in fut.result().results if not r.successful]
            if bad:
                raise ValueError(f"{node.get_name()} refused the parameters: {'; '.join(bad)}")
        finally:
            self.command.destroy_client(client)

    def listen(self, topic, node_name: str) -> list:
        """Messages of contract ``topic`` received by a new, independent node on this executor (the list fills
        as the graph spins; a latched topic delivers its last message to it)."""
        from . import msg_class, qos
        node = rclpy.create_node(node_name, context=self.ctx)
        got: list = []
        node.create_subscription(msg_class(topic), topic.name, got.append, qos(topic))
        self.nodes.append(node)
        self.ex.add_node(node)
        return got

    # ---------------------------------------------------------------- teardown
    def close(self) -> None:
        teardown(getattr(self, "ex", None), getattr(self, "nodes", ()), self.ctx)
        self.nodes = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


