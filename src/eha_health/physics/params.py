"""Typed model parameters (SI units) and their packing for the kernels.

Every physical value is a field of a frozen dataclass with its unit in the
field metadata. The defaults live in ``data/params.yaml`` (shipped with the
package, sources in ``docs/model.md``); the calibrated monitor overrides live
in ``data/monitor.yaml``. :func:`load` reads them, :func:`pack` turns a
parameter set plus the fault coefficients into the flat vector the compiled
kernels read (see :mod:`eha_health.physics.layout`).

Fault coefficients map to physics here, and only here:

* ``K_GM``  torque-motor gain ``GM * (1 - gm_loss * K_GM)`` (gm_loss = 0.5)
* ``K_FSJ`` jack dry friction ``F * (1 + friction_gain * K_FSJ)`` (static and
  dynamic, ratio kept: worn seals raise both, paper Fig. 5)
* ``K_BKL`` jack-to-surface backlash ``b0 + backlash * K_BKL`` [m, total play]
"""
from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass, field, fields, is_dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from .yamlfile import safe_load


def _f(unit: str, doc: str, lo: float | None = None, hi: float | None = None,
       lo_open: bool = False):
    """Field metadata: unit, one-line physics doc and the admissible range."""
    return field(metadata={"unit": unit, "doc": doc, "lo": lo, "hi": hi, "lo_open": lo_open})


def _pos(unit: str, doc: str):
    return _f(unit, doc, lo=0.0, lo_open=True)


def _nonneg(unit: str, doc: str, hi: float | None = None):
    return _f(unit, doc, lo=0.0, hi=hi)


# ----------------------------------------------------------------------------- blocks
@dataclass(frozen=True)
class Integration:
    """Fixed-step integration and output decimation."""
    dt: float = _pos("s", "fine integration step")
    sample_rate: float = _pos("Hz", "output sample rate (decimation of the fine step)")


@dataclass(frozen=True)
class Controller:
    """Servo-amplifier: PID on the position error, minus velocity feedback GAS."""
    kp: float = _nonneg("A/m", "proportional gain")
    ki: float = _nonneg("A/(m s)", "integral gain")
    kd: float = _nonneg("A s/m", "derivative gain")
    gas: float = _nonneg("A s/m", "velocity feedback gain GAS")
    i_max: float = _pos("A", "servovalve current saturation (rated current)")
    hysteresis: float = _nonneg("A", "total width of the current hysteresis (play) band")
    null_bias: float = _f("A", "valve null bias current added to the command")


@dataclass(frozen=True)
class TorqueMotor:
    """Torque motor: T = GM * i."""
    gm: float = _pos("N m/A", "torque-motor gain GM (healthy)")


@dataclass(frozen=True)
class FlapperNozzle:
    """Reference first stage: armature/flapper, nozzle bridge, feedback wire."""
    inertia: float = _pos("kg m^2", "armature + flapper inertia J_a")
    damping: float = _nonneg("N m s/rad", "armature viscous damping B_a")
    stiffness: float = _f("N m/rad", "net armature stiffness (torsion tube minus magnetic spring)")
    nozzle_arm: float = _pos("m", "pivot-to-nozzle distance r")
    wire_arm: float = _pos("m", "pivot-to-spool distance of the feedback wire (r + b)")
    wire_stiffness: float = _pos("N/m", "feedback-wire bending stiffness K_w")
    nozzle_diameter: float = _pos("m", "nozzle diameter d_n")
    null_gap: float = _pos("m", "flapper-nozzle gap at null x_f0")
    orifice_diameter: float = _pos("m", "fixed upstream orifice diameter d_0")
    cd_orifice: float = _f("-", "discharge coefficient of the fixed orifice", lo=0.0, hi=1.0, lo_open=True)
    cd_nozzle: float = _f("-", "discharge coefficient of the nozzle curtain", lo=0.0, hi=1.0, lo_open=True)
    oil_density: float = _pos("kg/m^3", "hydraulic oil density")
    clogging: float = _f("-", "first-stage filter clogging: pilot supply drop fraction", lo=0.0, hi=0.95)
    spool_end_area: float = _pos("m^2", "spool end area A_s")


@dataclass(frozen=True)
class FirstStage2:
    """Monitor first stage: second-order system plus integrating spool."""
    natural_frequency: float = _pos("rad/s", "first-stage natural frequency")
    damping_ratio: float = _pos("-", "first-stage damping ratio")
    spool_time_constant: float = _pos("s", "spool position-loop time constant")
    static_gain: float = _pos("m/A", "static spool position per unit current (healthy)")
    spool_rate_limit: float = _pos("m/s", "spool speed limit (pilot-flow saturation)")


@dataclass(frozen=True)
class Hydraulics:
    """Spool stroke and the fluid-dynamic servovalve block (linearised, saturated)."""
    spool_stroke: float = _pos("m", "spool stroke limit (each side)")
    supply_pressure: float = _pos("Pa", "supply pressure P_s")
    return_pressure: float = _nonneg("Pa", "return pressure P_r")
    flow_gain: float = _pos("m^2/s", "flow per unit spool displacement K_q")
    pressure_gain: float = _pos("Pa/m", "blocked-load pressure per unit spool displacement G_P")
    leakage: float = _nonneg("m^3/(s Pa)", "piston-seal leakage coefficient C_l")
    flow_asymmetry: float = _f("-", "extend/retract gain asymmetry a: the block sees x_s (1 + a sign x_s) "
                               "(unequal metering edges or piston areas)", lo=-0.9, hi=0.9)


@dataclass(frozen=True)
class Jack:
    """Symmetrical double-acting jack with viscous and dry friction, end stops."""
    area: float = _pos("m^2", "piston area A")
    mass: float = _pos("kg", "rod + piston mass")
    viscous: float = _nonneg("N s/m", "viscous friction coefficient")
    static_friction: float = _nonneg("N", "static (breakaway) friction, healthy")
    dynamic_friction: float = _nonneg("N", "dynamic (sliding) friction, healthy")
    stroke: float = _pos("m", "end-of-travel stop (each side of centre)")


@dataclass(frozen=True)
class Linkage:
    """Jack-to-surface mechanical link, with its play (backlash)."""
    stiffness: float = _pos("N/m", "link contact stiffness")
    damping: float = _nonneg("N s/m", "link contact damping")
    backlash: float = _nonneg("m", "nominal total play (healthy)")


@dataclass(frozen=True)
class Surface:
    """User (control surface, reduced to the jack axis) and its aerodynamic load."""
    mass: float = _pos("kg", "surface equivalent mass")
    hinge_stiffness: float = _nonneg("N/m", "elastic aerodynamic hinge-moment stiffness")
    damping: float = _nonneg("N s/m", "aerodynamic damping")
    external_force: float = _f("N", "constant external load (opposes +x when positive)")
    hinge_friction: float = _nonneg("N", "hinge-bearing dry friction reduced to the jack axis")


@dataclass(frozen=True)
class FaultLimits:
    """What a fault coefficient of 1 means physically (the limit condition)."""
    gm_loss: float = _f("-", "fraction of GM lost at K_GM = 1", lo=0.0, hi=1.0, lo_open=True)
    friction_gain: float = _pos("-", "dry-friction rise at K_FSJ = 1 (F = F0 (1 + g K))")
    backlash: float = _pos("m", "total backlash at K_BKL = 1")


# ----------------------------------------------------------------------------- effects
@dataclass(frozen=True)
class Compressibility:
    """Oil compressibility in the jack chambers: P12 becomes a state."""
    enabled: bool
    bulk_modulus: float = _pos("Pa", "effective bulk modulus (oil + hoses)")
    chamber_volume: float = _pos("m^3", "volume of each chamber at mid stroke, lines included")


@dataclass(frozen=True)
class SensorNoise:
    """White acquisition noise on the recorded channels (not inside the loop)."""
    enabled: bool
    position: float = _nonneg("m", "position noise standard deviation")
    velocity: float = _nonneg("m/s", "velocity noise standard deviation")
    pressure: float = _nonneg("Pa", "differential pressure noise standard deviation")
    current: float = _nonneg("A", "current noise standard deviation")


@dataclass(frozen=True)
class Quantization:
    """Quantisation steps of the acquisition (ADC resolution) per channel."""
    enabled: bool
    position: float = _pos("m", "position resolution")
    velocity: float = _pos("m/s", "velocity resolution")
    pressure: float = _pos("Pa", "pressure resolution")
    current: float = _pos("A", "current resolution")


@dataclass(frozen=True)
class SensorDelay:
    """Pure transport delay of the position transducer (inside the loop)."""
    enabled: bool
    delay: float = _nonneg("s", "position/velocity measurement delay")


@dataclass(frozen=True)
class SensorCalibration:
    """Position transducer bias and gain error (inside the loop)."""
    enabled: bool
    bias: float = _f("m", "position reading offset")
    gain_error: float = _f("-", "relative gain error (reading = (1 + e) x + bias)", lo=-0.5, hi=0.5)


@dataclass(frozen=True)
class CommandCalibration:
    """The recorded command against the command the actuator received: recorded = (1 + e) c + offset
    (a logger's ADC offset and gain on the command line, or a DAC's against its setpoint)."""
    enabled: bool
    offset: float = _f("m", "offset of the recorded command")
    gain_error: float = _f("-", "relative gain error of the recorded command", lo=-0.5, hi=0.5)


@dataclass(frozen=True)
class Stribeck:
    """Velocity-dependent dry friction: F(v) = F_d + (F_s - F_d) exp(-(v/v_s)^2)."""
    enabled: bool
    velocity: float = _pos("m/s", "Stribeck velocity v_s")


@dataclass(frozen=True)
class CommandNoise:
    """Electrical (EMI) noise added to the servovalve current, seeded."""
    enabled: bool
    sigma: float = _nonneg("A", "white current noise standard deviation per fine step")


@dataclass(frozen=True)
class VibrationNullShift:
    """Servovalve null that moves with vibration: i_null += gain <|a|>.

    <|a|> is the jack's absolute acceleration averaged over ``time_constant`` (first
    order). A valve's null can shift under vibration (servovalve specifications list it
    beside null shift with pressure and temperature; one cause is vibration rectified by a
    nonlinear first stage); a loop without integral action then holds the jack off the
    command by a vibration-dependent amount. Found on a real rig (docs/discrepancy.md).
    """
    enabled: bool
    gain: float = _f("A s^2/m", "null-bias current per unit mean |acceleration|")
    time_constant: float = _pos("s", "averaging time of the vibration level")
    velocity_filter: float = _pos("s", "first-order velocity filter ahead of the acceleration (bandwidth of "
                                  "the vibration the valve feels)")


@dataclass(frozen=True)
class Effects:
    """Optional effects the paper's model lacks; all off by default."""
    compressibility: Compressibility
    sensor_noise: SensorNoise
    quantization: Quantization
    sensor_delay: SensorDelay
    sensor_calibration: SensorCalibration
    stribeck: Stribeck
    command_noise: CommandNoise
    vibration_null_shift: VibrationNullShift
    command_calibration: CommandCalibration


#: Names of the optional effects, as accepted by ``with_effect_names`` and the CLI.
EFFECT_NAMES = tuple(f.name for f in fields(Effects))


# ----------------------------------------------------------------------------- model
@dataclass(frozen=True)
class ModelParams:
    """A complete parameter set for either model (``kind`` selects the first stage)."""
    kind: str
    integration: Integration
    controller: Controller
    torque_motor: TorqueMotor
    flapper_nozzle: FlapperNozzle
    first_stage: FirstStage2
    hydraulics: Hydraulics
    jack: Jack
    linkage: Linkage
    surface: Surface
    fault_limits: FaultLimits
    effects: Effects

    def __post_init__(self):
        if self.kind not in ("reference", "monitor"):
            raise ValueError(f"kind must be 'reference' or 'monitor', got {self.kind!r}")
        validate(self)

    def with_effects(self, **changes: Any) -> "ModelParams":
        """Copy with effects switched, e.g. ``with_effects(sensor_delay={'enabled': True})``."""
        eff = self.effects
        for name, upd in changes.items():
            if not hasattr(eff, name):
                raise ValueError(f"unknown effect {name!r}; known: {[f.name for f in fields(Effects)]}")
            cur = getattr(eff, name)
            eff = replace(eff, **{name: replace(cur, **upd) if isinstance(upd, dict) else upd})
        return replace(self, effects=eff)

    def with_effect_names(self, names) -> "ModelParams":
        """Copy with the named effects switched on (their parameters as loaded)."""
        for n in names:
            if n not in EFFECT_NAMES:
                raise ValueError(f"unknown effect {n!r}; known: {', '.join(EFFECT_NAMES)}")
        return self.with_effects(**{n: {"enabled": True} for n in names})

    def enabled_effects(self) -> tuple[str, ...]:
        return tuple(n for n in EFFECT_NAMES if getattr(self.effects, n).enabled)

    def updated(self, block: str, **values: Any) -> "ModelParams":
        """Copy with fields of one block changed, e.g. ``updated('jack', mass=6.0)``."""
        return replace(self, **{block: replace(getattr(self, block), **values)})


def validate(obj: Any, prefix: str = "") -> None:
    """Raise ``ValueError`` naming the first parameter that is non-finite or out of range."""
    for f in fields(obj):
        v = getattr(obj, f.name)
        name = f"{prefix}{f.name}"
        if is_dataclass(v):
            validate(v, name + ".")
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        m = f.metadata
        if not math.isfinite(v):
            raise ValueError(f"parameter {name} must be finite, got {v}")
        lo, hi = m.get("lo"), m.get("hi")
        unit = m.get("unit", "")
        if lo is not None and (v < lo or (m.get("lo_open") and v == lo)):
            rel = ">" if m.get("lo_open") else ">="
            raise ValueError(f"parameter {name} must be {rel} {lo} {unit}, got {v}".rstrip())
        if hi is not None and v > hi:
            raise ValueError(f"parameter {name} must be <= {hi} {unit}, got {v}")


# ----------------------------------------------------------------------------- YAML I/O
def _build(cls, data: dict, where: str):
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls)}
    unknown = set(data) - set(known)
    if unknown:
        raise ValueError(f"{where}: unknown parameter(s) {sorted(unknown)}")
    kwargs = {}
    for name, f in known.items():
        if name not in data:
            raise ValueError(f"{where}.{name}: missing")
        v = data[name]
        tp = f.type if not isinstance(f.type, str) else globals().get(f.type, f.type)
        if isinstance(tp, type) and is_dataclass(tp):
            kwargs[name] = _build(tp, v, f"{where}.{name}")
        elif f.type in ("bool", bool):
            if not isinstance(v, bool):
                raise ValueError(f"{where}.{name}: expected true/false, got {v!r}")
            kwargs[name] = v
        elif f.type in ("str", str):
            kwargs[name] = str(v)
        else:
            if isinstance(v, str):  # YAML 1.1 reads 20.7e6 (no sign in the exponent) as text
                try:
                    v = float(v)
                except ValueError:
                    pass
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{where}.{name}: expected a number in {f.metadata.get('unit', '')}, got {v!r}")
            kwargs[name] = float(v)
    return cls(**kwargs)


def _deep_merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _deep_merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def _read_yaml(path) -> dict:
    try:
        text = Path(path).read_text() if not hasattr(path, "read_text") else path.read_text()
        data = safe_load(text)
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML ({e})") from None
    return data or {}


@functools.lru_cache(maxsize=None)
def _packaged_yaml(name: str) -> dict:
    """Parsed shipped YAML (read once per process; callers get a deep copy)."""
    return _read_yaml(resources.files("eha_health") / "data" / name)


def _packaged(name: str) -> dict:
    return copy.deepcopy(_packaged_yaml(name))


def load(kind: str = "reference", path: str | Path | None = None, overrides: dict | None = None) -> ModelParams:
    """Load a parameter set.

    ``kind='reference'`` reads ``data/params.yaml``; ``kind='monitor'`` adds the
    calibrated overrides of ``data/monitor.yaml``. ``path`` (a user YAML with the
    same structure, partial allowed) and ``overrides`` (a nested dict) are
    merged on top, in that order.
    """
    if kind not in ("reference", "monitor"):
        raise ValueError(f"kind must be 'reference' or 'monitor', got {kind!r}")
    data = _packaged("params.yaml")
    if kind == "monitor":
        data = _deep_merge(data, _packaged("monitor.yaml"))
    if path is not None:
        data = _deep_merge(data, _read_yaml(path))
    if overrides:
        data = _deep_merge(data, overrides)
    data["kind"] = kind
    return _build(ModelParams, data, kind)


def field_table(obj: Any, prefix: str = "") -> list[tuple[str, Any, str, str]]:
    """Rows ``(name, value, unit, doc)`` of every numeric parameter (for docs and reports)."""
    rows = []
    for f in fields(obj):
        v = getattr(obj, f.name)
        if is_dataclass(v):
            rows += field_table(v, f"{prefix}{f.name}.")
        elif f.metadata:
            rows.append((prefix + f.name, v, f.metadata.get("unit", ""), f.metadata.get("doc", "")))
    return rows


