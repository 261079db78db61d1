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
import signal
import sys
import threading

import rclpy
from rclpy._rclpy_pybind11 import RCLError, UnknownROSArgsError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
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


class StopOnSignal:
    """SIGINT and SIGTERM ask the spin loop to stop (``requested``). A second one, or one after the
    loop (``spinning`` False: a node's ``close`` waiting at teardown), raises KeyboardInterrupt.

    rclpy's own handler shuts the context down from a thread of its own, whatever the main thread is
    doing: 1 of 200 small nodes given SIGINT hung for good in ``rclpy.shutdown``
    (``uninstall_signal_handlers`` waiting on that thread), another printed a traceback, and CI saw
    a plant die of SIGSEGV (2026-12-07; ``tools/sigint_probe.py``: with this handler 400 runs
    clean). Here the main thread does the whole shutdown, in teardown's order.
    """

    def __init__(self):
        self.requested = False
        self.spinning = True
        self._old = {}
        if threading.current_thread() is threading.main_thread():   # signal.signal's own rule
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame):
        if self.requested or not self.spinning:   # stuck in a callback, or in a close: break out of it
            raise KeyboardInterrupt
        self.requested = True

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


def run_node(factory, args=None) -> int:
    """``main`` of a console script: spin one node until Ctrl-C (SIGINT or SIGTERM) or until it asks
    to stop.

    Ctrl-C shuts the context down first (so a node's ``close`` knows nothing more can be delivered),
    then tears down. Exit codes: 0 done or interrupted, 1 a node's own error, 2 an argument or a
    parameter it refused at start.
    """
    why = bad_arguments(sys.argv if args is None else list(args))
    if why:
        print(f"error: {why}", file=sys.stderr)
        return 2
    stop = StopOnSignal()
    try:
        return _spin_node(factory, args, stop)
    finally:
        stop.restore()


def _spin_node(factory, args, stop: StopOnSignal) -> int:
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as e:       # unparsable --ros-args: one line, not a traceback
        print(f"error: {str(e).split(', at ')[0]}", file=sys.stderr)
        return 2
    try:
        node = factory()
    except (ValueError, OSError) as e:     # bad parameter or unreadable file: one line, not a traceback
        print(f"error: {e}", file=sys.stderr)
        teardown(None, [])
        return 2
    except KeyboardInterrupt:   # a second Ctrl-C while the node was being made
        teardown(None, [])
        return 0
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    rc = 0
    try:
        while not stop.requested and rclpy.ok() and not getattr(node, "done", False):
            ex.spin_once(timeout_sec=0.1)
        if stop.requested:
            rclpy.try_shutdown()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as e:
        # the context shut down by someone else between the loop's ok() and spin_once making its
        # timeout timer or wait set raises RCLError: an interrupt like the others
        if not (isinstance(e, RCLError) and not rclpy.ok()):   # else a node's own bug: one line, non-zero
            node.get_logger().error(f"{type(e).__name__}: {e}")
            rc = 1
    finally:
        stop.spinning = False
        teardown(ex, [node])
    return rc
