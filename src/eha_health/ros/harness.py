"""The real monitor and plant nodes driven through their subscription callbacks, without an executor.

For fuzzing the nodes' inputs (``eha-health bench fuzz --target messages``): a private rclpy
context, the two nodes in it (monitor without a log), their loggers silenced (thousands of
refusals: the counts are the report). :meth:`NodeHarness.feed` hands CDR bytes to a topic's
callback as DDS would, a command also to the plant; :meth:`NodeHarness.settle` takes every
window with both marks and waits for the monitor's worker. All rclpy and message types stay here.
"""
from __future__ import annotations

import rclpy
from builtin_interfaces.msg import Time
from rclpy.logging import LoggingSeverity
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Header

from msg_bridge import contract as C

from . import teardown
from .monitor import MonitorNode
from .plant import PlantNode


def message(topic: str, stamp_ns: int, *fields):
    """The ROS message of one of the monitor's topics: ``eha/pressure`` (pressure),
    ``eha/test_window`` (the mark, e.g. ``start:1``), else a JointState (position, velocity, effort)."""
    t = Time(sec=int(stamp_ns // 10**9) % 2**31, nanosec=int(stamp_ns % 10**9))
    if topic == "eha/pressure":
        p = FluidPressure(fluid_pressure=fields[0])
        p.header.stamp = t
        return p
    if topic == "eha/test_window":
        return Header(stamp=t, frame_id=fields[0])
    js = JointState(position=fields[0], velocity=fields[1], effort=fields[2])
    js.header.stamp = t
    return js


class NodeHarness:
    """A monitor and a plant node in a context of their own, fed by hand."""

    def __init__(self, monitor_params: dict | None = None):
        """``monitor_params``: further monitor parameters (name -> value)."""
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        params = {"log_path": "", **(monitor_params or {})}
        self.monitor = MonitorNode(context=self.ctx,
                                   parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
        self.plant = PlantNode(context=self.ctx)
        for n in (self.monitor, self.plant):
            n.get_logger().set_level(LoggingSeverity.FATAL)
        self._subs = {s.topic_name.lstrip("/"): s for s in self.monitor._subs}

    def feed(self, topic: str, data: bytes, msg=None) -> None:
        """CDR ``data`` into the monitor's ``topic`` callback; a command ``msg`` also to the plant."""
        self._subs[topic].callback(data)
        if topic == C.COMMAND.name and msg is not None:
            self.plant._on_command(msg)

    @staticmethod
    def serialize(msg) -> bytes:
        """CDR bytes of a message, as DDS delivers them."""
        return serialize_message(msg)

    def settle(self, timeout_s: float) -> None:
        """Every window with both marks taken now (refused with a reason, or diagnosed), and the
        monitor's worker done with it."""
        mon = self.monitor
        for w in mon.windows.ready(float("inf"), 0.0):
            mon._start_diagnosis(w)
        mon._worker.submit(lambda: None).result(timeout=timeout_s)
        mon._poll()

    def close(self) -> None:
        # a logger's level is global to the process, by name: left at FATAL it silenced every later
        # monitor's warnings in the same process (the full test suite, after the fuzzing of messages)
        for n in (self.monitor, self.plant):
            n.get_logger().set_level(LoggingSeverity.UNSET)
        teardown(None, [self.monitor, self.plant], self.ctx)
