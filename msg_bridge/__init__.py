"""Conversions between ROS 2 messages and the numpy arrays used by eha_health (filled in by the node-graph work)."""
