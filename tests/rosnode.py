"""One rclpy node on a single-threaded executor in a context of its own, for a test to talk to
other nodes or processes with (torn down in the order the ros2-from-pypi notes give)."""
from __future__ import annotations

from contextlib import contextmanager

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions


@contextmanager
def node_on_executor(name: str):
    """(node, executor); no signal handlers (the test process's Ctrl-C stays pytest's)."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(name, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    try:
        yield node, ex
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
