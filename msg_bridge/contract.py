"""The topic contract of the eha_health graph, as plain data (no ROS import).

A rig, a hardware-in-the-loop bench or another simulator that publishes these
topics with these types is monitored unchanged; ``docs/interfaces.md`` is the
human-readable version of this table. Names are relative, so one graph per
actuator is a namespace (``--ros-args -r __ns:=/left_aileron``).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Topic:
    name: str        # relative topic name
    type: str        # ROS 2 type, 'pkg/msg/Type'
    depth: int       # KEEP_LAST history depth (all topics are RELIABLE)
    latched: bool    # TRANSIENT_LOCAL durability
    doc: str


#: Samples a subscriber can hold before it drops one: 10 s at 1 kHz, so that a
#: whole 3.5 s test fits even when the subscriber is busy (no loss at rate 0).
SAMPLE_DEPTH = 10000

COMMAND = Topic("eha/command", "sensor_msgs/msg/JointState", SAMPLE_DEPTH, False,
                "position command: position[0] [m], one message per sample, stamped in (simulated) time")
JOINT_STATE = Topic("eha/joint_state", "sensor_msgs/msg/JointState", SAMPLE_DEPTH, False,
                    "measured surface position[0] [m] and velocity[0] [m/s], stamp = the command's stamp; "
                    "a rig record may leave velocity empty and carry its load cell's force [N, opposing +x] "
                    "in effort[0]")
PRESSURE = Topic("eha/pressure", "sensor_msgs/msg/FluidPressure", SAMPLE_DEPTH, False,
                 "jack differential (load) pressure P1 - P2 [Pa] in fluid_pressure, same stamp")
CURRENT = Topic("eha/current", "sensor_msgs/msg/JointState", SAMPLE_DEPTH, False,
                "servovalve torque-motor current effort[0] [A], same stamp")
TEST_WINDOW = Topic("eha/test_window", "std_msgs/msg/Header", 100, False,
                    "test window marks: frame_id 'start:<id>' at the first sample's stamp, "
                    "'end:<id>' at the last sample's stamp")
HEALTH = Topic("eha/health", "std_msgs/msg/Float64MultiArray", 1, True,
               "latest estimate, 2x3 array [[K_GM, K_FSJ, K_BKL], [std K_GM, std K_FSJ, std K_BKL]] (dimensionless)")
RUL = Topic("eha/rul", "std_msgs/msg/String", 1, True,
            "latest prognosis of this actuator, JSON: the prognose --json object of one actuator "
            "({\"actuator_id\", \"time_h\", \"faults\": {gm, fsj, bkl: F}, \"overall\": F}, F with rul_median_h, "
            "rul_p05_h, rul_p95_h [h], p_fail_next, threshold, n_tests, model, reason)")
DIAGNOSTICS = Topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", 100, False,
                    "one DiagnosticStatus per actuator, re-published every diagnostics_period_s")

#: What the monitor needs from a rig (and records as received).
INPUTS = (COMMAND, JOINT_STATE, PRESSURE, CURRENT, TEST_WINDOW)
#: What a rig record needs (``eha-health import``, ``discrepancy``): pressure and current topics
#: may be absent, velocity empty.
RECORD_INPUTS = (COMMAND, JOINT_STATE)
#: Measured channels: topic -> Response channel(s) it carries.
CHANNELS = {COMMAND.name: ("command",), JOINT_STATE.name: ("position", "velocity"),
            PRESSURE.name: ("pressure",), CURRENT.name: ("current",)}
