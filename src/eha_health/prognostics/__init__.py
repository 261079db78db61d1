"""Prognostics: from a history of diagnoses to a remaining useful life with an interval.

Nothing here imports ROS.
"""
