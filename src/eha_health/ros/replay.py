"""Replay node: republish a recorded bag's input topics into a live graph.

The messages go out byte for byte as recorded (raw CDR), in log-time order, paced
at ``rate`` times the recorded speed (0: as fast as ``max_msgs_per_s`` allows, a cap
that keeps a monitor in another process lossless). A monitor anywhere in the graph
then diagnoses the recorded tests as if they were live.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from msg_bridge import contract as C
from msg_bridge.convert import NS

from ..identification.diagnose import DEFAULT_METHOD
from ..io.bagrun import complete_windows, resolve_topics, truth_values, window_marks
from ..io.mcaplog import BagError, read_bag
from ..monitoring.health import results_summary
from ..monitoring.prognosis import history_summary
from .launch import HOURS_HINT, check_operating_hours
from .params import Param, declare
from . import msg_class, qos, run_node, teardown
from .monitor import MonitorNode


def recorded_inputs(path: str | Path) -> list[tuple[int, str, bytes]]:
    """(log time [ns], topic, raw CDR bytes) of every input topic, in log-time order."""
    names = resolve_topics(read_bag(path, topics=[]).types, path)
    if C.COMMAND.name not in names:
        raise BagError(f"{path}: missing topic {C.COMMAND.name}: nothing to replay")
    bag = read_bag(path, topics=list(names.values()), raw=True)
    # published under the contract's relative names, so a namespace remap applies
    rows = [(int(t), name, data) for name, topic in names.items()
            for t, data in zip(bag.log_times[topic], bag.messages[topic])]
    rows.sort(key=lambda r: r[0])
    return rows


#: The replay node's parameters (besides ``bag``): defaults, units, ranges.
PARAMS = (
    Param("rate", 1.0, "playback speed: 1 real time, 0 as fast as the reader takes them", 0.0, 1000.0),
    Param("max_msgs_per_s", 5000.0, "pace when publishing to another process [messages/s]", 1.0, 1e6),
    Param("max_burst_s", 0.05, "largest catch-up burst, in seconds of max_msgs_per_s [s]", 0.001, 10.0),
    Param("max_in_flight", 1000, "own monitor: messages ahead of what it has taken", 1, C.SAMPLE_DEPTH),
    Param("wait_for_subscribers_s", 10.0, "wait up to this long for the subscribers [s]", 0.0, 3600.0),
)


class ReplayNode(Node):
    """Publishes a bag's input topics in log-time order.

    ``delivered`` (optional): a count of the replayed messages a subscriber in this process has
    taken; the node then keeps at most ``max_in_flight`` messages ahead of it. Without it the
    pace is ``max_msgs_per_s``, with bursts bounded to ``max_burst_s`` of that rate: a reader that
    falls behind must not be flooded (measured: bursts of thousands of samples overflowed the DDS
    transport under load, and the dropped samples came back only seconds later).
    """

    def __init__(self, path: str | Path | None = None, name: str = "eha_replay",
                 delivered: Callable[[], int] | None = None, **kw):
        super().__init__(name, **kw)
        declare(self, (Param("bag", str(path or ""), "the MCAP file to replay"), *PARAMS))
        self.delivered = delivered
        bag = self.get_parameter("bag").value
        if not bag:
            raise ValueError("replay: parameter 'bag' (the MCAP file) is required")
        self.rows = recorded_inputs(bag)
        self.pubs = {t.name: self.create_publisher(msg_class(t), t.name, qos(t)) for t in C.INPUTS}
        self.sent = 0
        self._budget = 0.0           # messages the pace allows now
        self._last_wall = None
        self._created = time.monotonic()
        self.timer = self.create_timer(0.002, self._tick)

    @property
    def done(self) -> bool:
        return self.sent >= len(self.rows)

    def _ready(self) -> bool:
        waited = time.monotonic() - self._created
        return waited > self.get_parameter("wait_for_subscribers_s").value or \
            self.pubs[C.COMMAND.name].get_subscription_count() >= 1 and \
            self.pubs[C.TEST_WINDOW.name].get_subscription_count() >= 1

    def _tick(self) -> None:
        if self.done:
            return
        now = time.monotonic()
        if self._last_wall is None:
            if not self._ready():
                return
            self._t0_wall = self._last_wall = now
        rate = float(self.get_parameter("rate").value)
        n = len(self.rows)
        if rate > 0:
            horizon = self.rows[0][0] + (now - self._t0_wall) * rate * NS
            end = self.sent
            while end < n and self.rows[end][0] <= horizon:
                end += 1
        else:
            pace = float(self.get_parameter("max_msgs_per_s").value)
            self._budget = min(self._budget + (now - self._last_wall) * pace,
                               max(pace * float(self.get_parameter("max_burst_s").value), 1.0))
            end = min(n, self.sent + int(self._budget))
            if self.delivered is not None:
                end = min(end, self.delivered() + int(self.get_parameter("max_in_flight").value))
            self._budget -= max(end - self.sent, 0)
        self._last_wall = now
        for _, topic, data in self.rows[self.sent:end]:
            self.pubs[topic].publish(data)
        self.sent = max(end, self.sent)

def replay(bag: str | Path, rate: float = 1.0, with_monitor: bool = True, log_path: str | Path = "",
           domain_id: int | None = None, method: str = DEFAULT_METHOD, timeout_s: float = 600.0,
           wait_for_subscribers_s: float = 10.0, history: str | Path | None = None,
           actuator_id: str = "eha", prognostics_settings: str | Path | None = None,
           operating_hours: float | None = None) -> dict:
    """Republish ``bag`` into the graph; with ``with_monitor`` also diagnose it here, and with a
    ``history`` append each diagnosis of ``actuator_id`` to it (operating time: ``operating_hours``
    for a bag of one test, else the window's start stamp in hours, as the monitor does) and
    publish the RUL (``prognostics_settings``: a YAML merged over data/prognostics.yaml for it);
    the result's ``history`` says what went in.

    Publishing starts once a subscriber takes the commands and the marks, or after
    ``wait_for_subscribers_s`` (a monitor process that is still starting on a busy machine
    needs longer than the default: measured, over 10 s at load 18).

    Returns the monitor's verdicts (with the bag's own truth metadata where it has
    some) and a printable summary.
    """
    if domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    win_topic = resolve_topics(read_bag(bag, topics=[]).types, bag).get(C.TEST_WINDOW.name)
    marks = read_bag(bag, topics=[win_topic] if win_topic else [])   # the marks and the metadata
    n_windows = len(complete_windows(window_marks(marks, win_topic))) if with_monitor else 0
    check_operating_hours(operating_hours, history if with_monitor else None, max(n_windows, 1))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    nodes = []
    ex = SingleThreadedExecutor(context=ctx)
    try:
        mon = None
        if with_monitor:
            prog = [Parameter("history", value=str(Path(history).resolve())),
                    Parameter("actuator_id", value=str(actuator_id))] if history else []
            if history and operating_hours is not None:
                prog.append(Parameter("operating_hours", value=float(operating_hours)))
            if history and prognostics_settings:
                prog.append(Parameter("prognostics_settings", value=str(Path(prognostics_settings).resolve())))
            mon = MonitorNode(context=ctx, parameter_overrides=[Parameter("log_path", value=str(log_path)),
                                                                 Parameter("method", value=method),
                                                                 Parameter("keep_verdicts", value=0),   # returns all
                                                                 *prog])
            nodes.append(mon)
        # with the monitor here, pace by what it has taken (flow control), not by a fixed rate
        delivered = (lambda: sum(mon.received.values())) if mon is not None else None
        rep = ReplayNode(bag, context=ctx, delivered=delivered, parameter_overrides=[
            Parameter("rate", value=float(rate)),
            Parameter("wait_for_subscribers_s", value=float(wait_for_subscribers_s))])
        nodes.insert(0, rep)
        for n in nodes:
            ex.add_node(n)
        end = time.monotonic() + timeout_s

        def finished():
            if not rep.done:
                return False
            return mon is None or (mon.verdicts >= n_windows and not mon.busy)
        while not finished() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)
        linger = time.monotonic() + 1.0   # let reliable deliveries to other processes complete
        while mon is None and time.monotonic() < linger:
            ex.spin_once(timeout_sec=0.01)
        results = [{"test_id": r["test_id"], "level": r["level"], "message": r["message"],
                    "diagnosis": r["diagnosis"].as_dict() if r["diagnosis"] else None,
                    "truth": truth_values(marks.metadata.get(f"truth/test_{r['test_id']}"))}
                   for r in (mon.results if mon else [])]
        hist = None
        if mon is not None and history:
            hist = history_summary(history, actuator_id, [
                {"test_id": r["test_id"], "appended": r["prognosis"].appended, "error": r["prognosis"].error}
                for r in mon.results if r.get("prognosis") is not None], HOURS_HINT if operating_hours is None else None)
        sent = rep.sent
    finally:
        teardown(ex, nodes, ctx)
    ok = [r for r in results if r["diagnosis"]]
    summary = f"replayed {sent} messages from {bag} at rate {rate:g}"
    if with_monitor:
        summary += "\n" + results_summary(ok)
        summary += "".join(f"\ntest {r['test_id']}: {r['level']}: {r['message']}" for r in results if not r["diagnosis"])
    if hist:
        summary += "\n" + hist["line"]
    return {"sent": sent, "results": results, "summary": summary, "history": hist}


def main(args=None) -> int:
    return run_node(ReplayNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
