"""Plant node: the reference EHA, stepped by the command stream.

Each command sample (``eha/command``, stamped) advances the model to that stamp
(zero-order hold of the previous command over any gap, at most ``max_gap_s``
simulated) and is answered by one sample on ``eha/joint_state``, ``eha/pressure``
and ``eha/current`` carrying the same stamp. Nothing depends on wall time, so the
same parameters and commands give the same samples at any playback speed.

Parameters (all changeable at run time through the standard parameter services;
a change rebuilds the model at rest before the next command):
``k_gm``, ``k_fsj``, ``k_bkl`` (fault coefficients, 0 healthy, 1 limit),
``effects`` (names of optional effects, e.g. ``['sensor_noise']``), ``seed`` (noise),
``params_file`` (YAML overrides, '' = shipped), ``actuator_id``, ``max_gap_s``.
"""
from __future__ import annotations

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from msg_bridge import contract as C
from msg_bridge import convert as cv

from ..physics.faults import FAULT_NAMES, FAULT_UPPER, Faults
from ..physics.layout import O_CUR, O_P12, O_POS, O_VEL
from ..physics.model import Plant
from ..physics.params import load
from . import msg_class, qos, run_node
from .params import INT_MAX, Param, declare


#: The plant node's parameters (docs/interfaces.md): defaults, units, ranges.
PARAMS = (
    *(Param(k, 0.0, f"fault coefficient {k.upper()} (0 healthy, 1 limit) [-]", 0.0, FAULT_UPPER) for k in FAULT_NAMES),
    Param("effects", [""], "optional effects to switch on"),
    Param("seed", 0, "seed of the sensor/command noise", 0, INT_MAX),
    Param("params_file", "", "YAML parameter overrides ('' = shipped)"),
    Param("actuator_id", "eha", "joint/hardware name"),
    Param("max_gap_s", 2.0, "longest idle time simulated between two command samples [s]", 0.0, 3600.0),
)


class PlantNode(Node):
    def __init__(self, name: str = "eha_plant", **kw):
        super().__init__(name, **kw)
        declare(self, PARAMS)
        self.plant = self._build({})
        # compile the kernels now, before any endpoint exists, so the first answer is not late
        self.plant.step(np.zeros(1))
        self.plant.reset()
        self.add_on_set_parameters_callback(self._on_set)
        self.pub_js = self.create_publisher(msg_class(C.JOINT_STATE), C.JOINT_STATE.name, qos(C.JOINT_STATE))
        self.pub_p = self.create_publisher(msg_class(C.PRESSURE), C.PRESSURE.name, qos(C.PRESSURE))
        self.pub_i = self.create_publisher(msg_class(C.CURRENT), C.CURRENT.name, qos(C.CURRENT))
        self.create_subscription(msg_class(C.COMMAND), C.COMMAND.name, self._on_command, qos(C.COMMAND))
        self.last_ns: int | None = None
        self.last_u = 0.0
        self.samples = 0
        self.rejected = 0

    # ---------------------------------------------------------------- parameters
    def _value(self, changes: dict, name: str):
        return changes[name] if name in changes else self.get_parameter(name).value

    def _build(self, changes: dict) -> Plant:
        """A new model at rest from the current parameters updated by ``changes``; ValueError if invalid."""
        faults = Faults(*(float(self._value(changes, k)) for k in FAULT_NAMES))
        path = self._value(changes, "params_file") or None
        params = load("reference", path=path)
        effects = [e for e in (self._value(changes, "effects") or []) if e]
        params = params.with_effect_names(effects)
        seed = int(self._value(changes, "seed"))
        return Plant(params, faults, seed=seed)

    def _on_set(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        if not set(changes) & {*FAULT_NAMES, "effects", "seed", "params_file"}:
            return SetParametersResult(successful=True)
        try:
            self.plant = self._build(changes)
        except (ValueError, OSError) as e:
            return SetParametersResult(successful=False, reason=str(e))
        self.last_ns = None      # the new actuator starts at rest at the next command
        self.get_logger().info(f"plant rebuilt: faults {self.plant.faults.as_tuple()}, "
                               f"effects {list(self.plant.params.enabled_effects())}")
        return SetParametersResult(successful=True)

    # ---------------------------------------------------------------- samples
    def _on_command(self, msg) -> None:
        try:
            ns, u = cv.command_from_msg(msg)
        except (ValueError, AttributeError) as e:
            return self._reject(f"bad command message: {e}")
        if not np.isfinite(u):
            return self._reject(f"non-finite command at stamp {ns} ns")
        dt_ns = round(1e9 / self.plant.sample_rate)
        if self.last_ns is None:
            n = 1
        else:
            if ns <= self.last_ns:
                return self._reject(f"command stamp {ns} ns not after the previous {self.last_ns} ns")
            n = max(1, round((ns - self.last_ns) / dt_ns))
        if n > 1:   # idle between samples/tests: hold the last command (bounded)
            hold = min(n - 1, int(self.get_parameter("max_gap_s").value * self.plant.sample_rate))
            self.plant.step(np.full(hold, self.last_u))
        row = self.plant.step(np.array([u]))[0]
        self.last_ns, self.last_u = ns, u
        self.samples += 1
        joint = self.get_parameter("actuator_id").value
        self.pub_js.publish(cv.joint_state_msg(ns, row[O_POS], row[O_VEL], joint))
        self.pub_p.publish(cv.pressure_msg(ns, row[O_P12], joint))
        self.pub_i.publish(cv.current_msg(ns, row[O_CUR], joint))

    def _reject(self, why: str) -> None:
        self.rejected += 1
        self.get_logger().warning(why, throttle_duration_sec=1.0)


def main(args=None) -> int:
    return run_node(PlantNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
