"""The monitor's logic, without ROS: which test windows are ready, what is diagnosed, what is said.

:mod:`.windows` (per-channel sample buffers and the window queue), :mod:`.analysis` (the
diagnosis of one window, and the discrepancy loop after it), :mod:`.health` (the OK / WARN
/ ERROR policy and the verdict's text and key values). The ROS node
(:mod:`eha_health.ros.monitor`) only wires topics, parameters, timers and services to these.
"""
