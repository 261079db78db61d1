"""Messages <-> numbers. SI units throughout; stamps are integer nanoseconds.

The ``*_from_msg`` readers only use attribute access, so they accept rclpy
messages and the objects the MCAP decoder (``mcap_ros2``) returns alike: offline
tools read bags without ROS installed. The ``*_msg`` builders import the rclpy
message classes on first use.
"""
from __future__ import annotations

import numpy as np

NS = 1_000_000_000


# --------------------------------------------------------------------------- time
def stamp_ns(stamp) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    return int(stamp.sec) * NS + int(stamp.nanosec)


def _stamp(ns: int):
    from builtin_interfaces.msg import Time
    ns = int(ns)
    if ns < 0:
        raise ValueError(f"stamp must be >= 0 ns, got {ns}")
    return Time(sec=ns // NS, nanosec=ns % NS)


def _header(ns: int, frame_id: str = ""):
    from std_msgs.msg import Header
    return Header(stamp=_stamp(ns), frame_id=frame_id)


# --------------------------------------------------------------------------- samples
def command_msg(ns: int, position_m: float, joint: str):
    from sensor_msgs.msg import JointState
    return JointState(header=_header(ns), name=[joint], position=[float(position_m)])


def joint_state_msg(ns: int, position_m: float, velocity_m_s: float | None, joint: str,
                    load_n: float | None = None):
    """Measured position [m] and velocity [m/s]; a rig without a velocity sensor leaves velocity
    empty (None), a rig with a load cell puts the measured force [N], opposing +x, in effort."""
    from sensor_msgs.msg import JointState
    return JointState(header=_header(ns), name=[joint], position=[float(position_m)],
                      velocity=[] if velocity_m_s is None else [float(velocity_m_s)],
                      effort=[] if load_n is None else [float(load_n)])


def pressure_msg(ns: int, pressure_pa: float, frame: str):
    from sensor_msgs.msg import FluidPressure
    return FluidPressure(header=_header(ns, frame), fluid_pressure=float(pressure_pa), variance=0.0)


def current_msg(ns: int, current_a: float, joint: str):
    from sensor_msgs.msg import JointState
    return JointState(header=_header(ns), name=[joint + "/torque_motor"], effort=[float(current_a)])


def _first(seq, what: str) -> float:
    if len(seq) < 1:
        raise ValueError(f"{what} is empty")
    return float(seq[0])


def command_from_msg(msg) -> tuple[int, float]:
    return stamp_ns(msg.header.stamp), _first(msg.position, "JointState.position (command)")


def joint_state_from_msg(msg) -> tuple[int, float, float]:
    return (stamp_ns(msg.header.stamp), _first(msg.position, "JointState.position"),
            _first(msg.velocity, "JointState.velocity"))


def joint_state_record_from_msg(msg) -> tuple[int, float, float, float]:
    """(stamp, position, velocity or NaN if not measured, load force or NaN if not measured)."""
    opt = (lambda seq: float(seq[0]) if len(seq) else float("nan"))
    return (stamp_ns(msg.header.stamp), _first(msg.position, "JointState.position"),
            opt(msg.velocity), opt(msg.effort))


def pressure_from_msg(msg) -> tuple[int, float]:
    return stamp_ns(msg.header.stamp), float(msg.fluid_pressure)


def current_from_msg(msg) -> tuple[int, float]:
    return stamp_ns(msg.header.stamp), _first(msg.effort, "JointState.effort (current)")


#: topic -> reader returning (stamp_ns, value, ...) in the order of contract.CHANNELS
READERS = {"eha/command": command_from_msg, "eha/joint_state": joint_state_from_msg,
           "eha/pressure": pressure_from_msg, "eha/current": current_from_msg}


# --------------------------------------------------------------------------- test window marks
def window_msg(ns: int, event: str, test_id: int):
    if event not in ("start", "end"):
        raise ValueError(f"window event must be 'start' or 'end', got {event!r}")
    return _header(ns, f"{event}:{int(test_id)}")


def window_from_msg(msg) -> tuple[int, str, int]:
    """-> (stamp_ns, 'start'|'end', test id); ``ValueError`` for any other frame_id."""
    event, _, tid = str(msg.frame_id).partition(":")
    if event not in ("start", "end") or not tid.lstrip("-").isdigit():
        raise ValueError(f"test_window frame_id must be 'start:<id>' or 'end:<id>', got {msg.frame_id!r}")
    return stamp_ns(msg.stamp), event, int(tid)


# --------------------------------------------------------------------------- health out
HEALTH_LABELS = ("k_gm", "k_fsj", "k_bkl")


def health_msg(values, stds):
    """2x3 ``Float64MultiArray``: row 0 the coefficients, row 1 their standard errors."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout
    data = [float(v) for v in values] + [float(s) for s in stds]
    dims = [MultiArrayDimension(label="estimate,std", size=2, stride=6),
            MultiArrayDimension(label=",".join(HEALTH_LABELS), size=3, stride=3)]
    return Float64MultiArray(layout=MultiArrayLayout(dim=dims, data_offset=0), data=data)


def health_from_msg(msg) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(msg.data, float)
    if d.size != 6:
        raise ValueError(f"health array must hold 6 values, got {d.size}")
    return d[:3], d[3:]


LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


def rul_msg(obj: dict):
    """``std_msgs/String`` holding one actuator's prognosis as JSON (contract topic ``eha/rul``)."""
    import json

    from std_msgs.msg import String
    return String(data=json.dumps(obj, default=float))


def diagnostic_array(ns: int, name: str, hardware_id: str, level: str, message: str, values: dict):
    """One ``DiagnosticStatus`` in a ``DiagnosticArray``; values become strings (KeyValue)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    kv = [KeyValue(key=str(k), value=(f"{v:.6g}" if isinstance(v, float) else str(v))) for k, v in values.items()]
    st = DiagnosticStatus(level=bytes([LEVELS[level]]), name=name, message=message, hardware_id=hardware_id,
                          values=kv)
    return DiagnosticArray(header=_header(ns), status=[st])
