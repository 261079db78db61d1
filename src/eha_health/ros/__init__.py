"""ROS 2 nodes: thin rclpy shells over the eha_health libraries.

* :mod:`.plant` -- the reference EHA driven by the command stream.
* :mod:`.command` -- plays the FDI test sequence (Trigger service, optional period).
* :mod:`.monitor` -- records the test window, diagnoses it, publishes health and logs MCAP.
* :mod:`.replay` -- republishes a recorded bag into a live graph.
* :mod:`.graph` -- runs the nodes in one process (demo, tests, bench) or as processes (launch).

Topic names, types and QoS come from :mod:`msg_bridge.contract`; see docs/interfaces.md.
"""
from __future__ import annotations

import importlib
import sys

import rclpy
from rclpy._rclpy_pybind11 import RCLError, UnknownROSArgsError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from msg_bridge.contract import Topic


def qos(topic: Topic, best_effort: bool = False):
    """RELIABLE (BEST_EFFORT for a lossy link), KEEP_LAST(depth), TRANSIENT_LOCAL when latched."""
    rel = ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=topic.depth, reliability=rel,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if topic.latched else DurabilityPolicy.VOLATILE)


def msg_class(topic: Topic):
    """The rclpy message class of a contract topic."""
    pkg, _, name = topic.type.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def teardown(executor, nodes, context=None) -> None:
    """Stop in the order rclpy 7.1.6 needs (ros2-from-pypi notes): executor, then each
    node (its own ``close`` first: worker, log), then the context."""
    if executor is not None:
        executor.shutdown()
    for n in nodes:
        if hasattr(n, "close"):
            n.close()
        n.destroy_node()
    if rclpy.ok(context=context):
        rclpy.shutdown(context=context)


def bad_arguments(argv: list[str]) -> str | None:
    """Why a node's command line is refused (one line), or None: a node takes ROS arguments only."""
    try:
        extra = remove_ros_args(argv)[1:]
    except UnknownROSArgsError as e:    # rclpy raises it with a traceback from rclpy.init (probe 11)
        return f"unknown ROS argument(s) {str(e).strip('[]')} after --ros-args (a parameter is -p name:=value)"
    except RCLError as e:               # unparsable --ros-args
        return str(e).split(", at ")[0]
    if extra:   # rclpy would ignore them: a setting meant for the node would silently not apply
        return (f"unexpected argument(s) {' '.join(extra)}: the node's settings are ROS parameters "
                f"(--ros-args -p name:=value)")
    return None


def run_node(factory, args=None) -> int:
    """``main`` of a console script: spin one node until Ctrl-C or until it asks to stop.

    Exit codes: 0 done or interrupted, 1 a node's own error, 2 an argument or a parameter it refused
    at start.
    """
    why = bad_arguments(sys.argv if args is None else list(args))
    if why:
        print(f"error: {why}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args)
    except RCLError as e:       # unparsable --ros-args: one line, not a traceback
        print(f"error: {str(e).split(', at ')[0]}", file=sys.stderr)
        return 2
    try:
        node = factory()
    except (ValueError, OSError) as e:     # bad parameter or unreadable file: one line, not a traceback
        print(f"error: {e}", file=sys.stderr)
        teardown(None, [])
        return 2
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    rc = 0
    try:
        while rclpy.ok() and not getattr(node, "done", False):
            ex.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as e:
        # Ctrl-C: rclpy's signal handler shuts the context down from its own thread, which can fall
        # between the loop's ok() and spin_once making its timeout timer or wait set: that raises
        # RCLError ("failed to initialize wait set", about 1 run in 6), an interrupt like the others
        if not (isinstance(e, RCLError) and not rclpy.ok()):   # else a node's own bug: one line, non-zero
            node.get_logger().error(f"{type(e).__name__}: {e}")
            rc = 1
    finally:
        teardown(ex, [node])
    return rc
