"""Bridge between the eha_health libraries and ROS 2 messages.

* :mod:`msg_bridge.contract` -- topic names, types and QoS of the graph (plain data).
* :mod:`msg_bridge.convert` -- message <-> number conversions (SI, stamps in ns).
"""
from . import contract, convert  # noqa: F401
