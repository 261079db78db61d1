"""Lossy relay node: republishes the plant's samples and drops a seeded fraction of them.

A stand-in for a lossy link (radio, overloaded switch) between a rig and the monitor, for
the message-loss scenario of docs/interfaces.md: the plant publishes on ``lossy/joint_state``,
``lossy/pressure`` and ``lossy/current`` (remapped), the relay forwards each message (the CDR
bytes, untouched) to the contract topics with probability 1 - ``drop_fraction``, each topic
drawing from its own seeded generator. ``best_effort`` publishes BEST_EFFORT, as a lossy link's
QoS would be (the monitor must then subscribe BEST_EFFORT: parameter ``best_effort``).
"""
from __future__ import annotations

from collections import Counter

import numpy as np
from rclpy.node import Node

from msg_bridge import contract as C

from . import msg_class, qos, run_node
from .params import INT_MAX, Param, declare

#: The plant outputs the relay carries, and the prefix they are remapped to upstream.
RELAYED = (C.JOINT_STATE, C.PRESSURE, C.CURRENT)
UPSTREAM = "lossy/"

PARAMS = (
    Param("drop_fraction", 0.01, "fraction of the samples dropped, each independently [-]", 0.0, 1.0),
    Param("seed", 0, "seed of the drops", 0, INT_MAX),
    Param("best_effort", True, "publish BEST_EFFORT (a lossy link) instead of RELIABLE"),
)


def upstream(topic) -> str:
    """Where the plant publishes ``topic`` when a relay sits in between (``eha/x`` -> ``lossy/x``)."""
    return UPSTREAM + topic.name.split("/", 1)[1]


class LossyRelayNode(Node):
    def __init__(self, name: str = "eha_lossy_relay", **kw):
        super().__init__(name, **kw)
        declare(self, PARAMS)
        be = bool(self.get_parameter("best_effort").value)
        seed = int(self.get_parameter("seed").value)
        self.passed: Counter = Counter()
        self.dropped: Counter = Counter()
        self._subs = []
        for i, t in enumerate(RELAYED):
            pub = self.create_publisher(msg_class(t), t.name, qos(t, best_effort=be))
            rng = np.random.default_rng([seed, i])
            self._subs.append(self.create_subscription(msg_class(t), upstream(t), self._forward(t, pub, rng),
                                                       qos(t), raw=True))

    def _forward(self, topic, pub, rng):
        def cb(data: bytes) -> None:
            if rng.random() < float(self.get_parameter("drop_fraction").value):
                self.dropped[topic.name] += 1
                return
            self.passed[topic.name] += 1
            pub.publish(data)
        return cb


def main(args=None) -> int:
    return run_node(LossyRelayNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
