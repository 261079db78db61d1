"""Library of candidate effects the monitor model may lack.

Each :class:`Candidate` is one physical mechanism with its own parameters
(:class:`augment.Knob`), applied to the monitor's :class:`ModelParams`. A knob at
its ``off`` value leaves the model unchanged, so a candidate's signature is the
change of the outputs when its knobs move from ``off``. The library is defined
on the monitor's physics, not on the plant's effect switches: several entries
(supply sag, extra viscous friction, null bias, load stiffness, leakage, mount
compliance, load mass, the controller's gains) are not switches of the plant at all.

=====================  =================================================  ============
candidate              mechanism (knob)                                   unit
=====================  =================================================  ============
compressibility        oil + hose compliance 1/beta; P12 becomes a state  1/GPa
sensor_delay           transport delay of the position transducer         s
sensor_bias            offset of the position reading                     m
sensor_gain            relative gain error of the position reading        -
supply_pressure        supply sag d: P_s -> P_r + (P_s-P_r)(1-d)           -
viscous_friction       extra jack viscous friction                        N s/m
stribeck               Stribeck velocity of the dry friction              m/s
valve_null_bias        servovalve null-bias current                       A
load_stiffness         change of the hinge (load) stiffness               N/m
leakage                extra internal (cross-piston) leakage              m^3/(s Pa)
mount_compliance       compliance in series with the link (soft mount)    m/N
flow_asymmetry         extend/retract gain asymmetry of valve and jack    -
vibration_null_shift   null bias k <|a|> + b0 (shift under vibration)     A s^2/m, A
load_mass              change of the load's (surface's) mass              kg
controller_gain        relative error e of the position gain: kp (1+e)    -
velocity_feedback      relative error e of the velocity feedback gain     -
command_offset         offset of the recorded command (model input)       m
command_scale          gain error of the recorded command (model input)   -
valve_response         slower spool: time constant x (1+a), rate /(1+a)   -
=====================  =================================================  ============

These act *in the loop* (the controller sees them; they move the actuator). The
*recording* candidates (:data:`RECORDING`) are generated from the channel list
(:data:`~eha_health.signals.channels.MEASURED`): for every measured channel an offset,
a scale error, a time skew against the command, a first-order sensor lag and a drift of its
zero (:mod:`~eha_health.signals.recording`), named ``<channel>_<kind>``, and two of the whole
record: ``command_skew`` (every channel late alike against the recorded command) and
``time_base`` (every channel on a time base off the command's). They change the
recorded output only: the other channels do not show them, which is the evidence that
tells ``position_skew`` from the in-loop ``sensor_delay``, or ``position_offset`` from
``sensor_bias`` (the loop holds the surface off by a feedback bias, and the hinge
load -- the pressure -- shows it). ``command_skew`` is also what a transport delay of the
command before the actuator looks like: the outputs cannot tell the two apart.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..identification.knobs import Knob
from ..identification.residual import CHANNEL_COLUMNS, CHANNEL_SCALES
from ..physics.params import ModelParams
from ..signals import recording
from ..signals.channels import MEASURED, UNITS

IN_LOOP, RECORDING_CHAIN = "in-loop", "recording"


@dataclass(frozen=True)
class Candidate:
    """A missing-effect hypothesis: a mechanism and the knobs that size it.

    ``kind`` is :data:`IN_LOOP` (changes the model, needs a simulation) or
    :data:`RECORDING_CHAIN` (transforms the recorded ``channel`` of a simulation's output).
    """
    name: str
    mechanism: str
    knobs: tuple[Knob, ...]
    kind: str = IN_LOOP
    channel: str | None = None
    #: (knob, simpler candidate): with ``knob`` at its off value this candidate *is* the simpler one
    nests: tuple[tuple[str, str], ...] = ()
    #: candidates that share part of its physics, so that a record may not tell them apart: when
    #: either ranks first, the other is refitted too and the report says if they are equally supported
    overlaps: tuple[str, ...] = ()

    @property
    def recorded(self) -> tuple[str, ...]:
        """The recorded channels a recording effect changes (none for an in-loop one)."""
        return tuple(c for k in self.knobs if k.recording for c in k.output.channels)

    def applies_to(self, channels) -> bool:
        """A recording effect needs its channel in the record."""
        return self.channel is None or self.channel in channels


def _compressibility(p: ModelParams, compliance: float) -> ModelParams:
    if compliance <= 0.0:
        return p.with_effects(compressibility={"enabled": False})
    return p.with_effects(compressibility={"enabled": True, "bulk_modulus": 1e9 / compliance})


def _delay(p: ModelParams, d: float) -> ModelParams:
    return p.with_effects(sensor_delay={"enabled": d > 0.0, "delay": max(d, 0.0)})


def _calibration(p: ModelParams, bias: float | None = None, gain: float | None = None) -> ModelParams:
    cur = p.effects.sensor_calibration
    b = cur.bias if bias is None else bias
    g = cur.gain_error if gain is None else gain
    return p.with_effects(sensor_calibration={"enabled": True, "bias": b, "gain_error": g})


def _command(p: ModelParams, offset: float | None = None, gain: float | None = None) -> ModelParams:
    cur = p.effects.command_calibration
    o = cur.offset if offset is None else offset
    g = cur.gain_error if gain is None else gain
    return p.with_effects(command_calibration={"enabled": True, "offset": o, "gain_error": g})


def _supply(p: ModelParams, d: float) -> ModelParams:
    """Supply sag d: P_s - P_r -> (P_s - P_r)(1 - d).

    Orifice flows go as sqrt(pressure drop): the pilot flow that moves the spool falls by
    sqrt(1 - d) (slower spool, lower rate limit); the fluid block is linearised about null
    (K_q, G_P fixed), so on the power stage the sag acts through the pressure limit (stall
    force and the flow-saturated speed under load).
    """
    h, fs = p.hydraulics, p.first_stage
    r = max(1.0 - d, 1e-3) ** 0.5
    p = p.updated("first_stage", spool_time_constant=fs.spool_time_constant / r,
                  spool_rate_limit=fs.spool_rate_limit * r)
    return p.updated("hydraulics", supply_pressure=h.return_pressure + (h.supply_pressure - h.return_pressure) * (1 - d))


def _stribeck(p: ModelParams, v: float) -> ModelParams:
    if v <= 0.0:
        return p.with_effects(stribeck={"enabled": False})
    return p.with_effects(stribeck={"enabled": True, "velocity": v})


def _vibration(p: ModelParams, gain: float) -> ModelParams:
    return p.with_effects(vibration_null_shift={"enabled": gain != 0.0, "gain": gain})


def _spool(p: ModelParams, a: float) -> ModelParams:
    """Spool speed: the spool end area A_s (or the pilot flow) off by (1 + a).

    The spool moves at v_s = Q_pilot / A_s: its position-loop time constant goes as A_s and its
    rate limit (the saturated pilot flow over A_s) as 1 / A_s, so both move by the one factor
    (the reference's flapper-nozzle stage; a worn or clogged pilot stage, a larger valve).
    """
    fs, k = p.first_stage, max(1.0 + a, 1e-3)
    return p.updated("first_stage", spool_time_constant=fs.spool_time_constant * k,
                     spool_rate_limit=fs.spool_rate_limit / k)


def _mount(p: ModelParams, c: float) -> ModelParams:
    return p.updated("linkage", stiffness=1.0 / (1.0 / p.linkage.stiffness + max(c, 0.0)))


CANDIDATES: tuple[Candidate, ...] = (
    Candidate("compressibility", "oil and hose compliance: the chamber pressure lags the flow, "
              "a hydraulic spring against the jack mass",
              (Knob("oil_compliance", "1/GPa", 0.05, 20.0, 1.0, 0.0, _compressibility,
                    doc="1/bulk modulus [1/GPa]; 1 = 1 GPa"),)),
    Candidate("sensor_delay", "transport delay of the position transducer inside the loop",
              (Knob("delay", "s", 0.0, 0.02, 1e-3, 0.0, _delay, doc="position/velocity delay"),)),
    Candidate("sensor_bias", "offset of the position reading (the loop holds the surface off by it)",
              (Knob("bias", "m", -2e-3, 2e-3, 1e-4, 0.0, lambda p, v: _calibration(p, bias=v),
                    doc="reading = x + bias"),)),
    Candidate("sensor_gain", "gain error of the position reading",
              (Knob("gain_error", "-", -0.3, 0.3, 0.02, 0.0, lambda p, v: _calibration(p, gain=v),
                    doc="reading = (1 + e) x"),)),
    Candidate("supply_pressure", "supply pressure sag: less stall force and less flow per spool stroke",
              (Knob("sag", "-", 0.0, 0.8, 0.2, 0.0, _supply, doc="fractional drop of P_s - P_r"),)),
    Candidate("viscous_friction", "extra viscous friction on the jack (seal drag, cold oil)",
              (Knob("extra_viscous", "N s/m", -2000.0, 3e4, 3000.0, 0.0,
                    lambda p, v: p.updated("jack", viscous=max(p.jack.viscous + v, 0.0)),
                    doc="added to jack.viscous"),)),
    Candidate("stribeck", "velocity-dependent dry friction: F = F_d + (F_s - F_d) exp(-(v/v_s)^2)",
              (Knob("v_stribeck", "m/s", 1e-4, 0.1, 5e-3, 0.0, _stribeck, doc="Stribeck velocity"),)),
    Candidate("valve_null_bias", "servovalve null bias: a constant current offset the loop must cancel",
              (Knob("null_bias", "A", -2e-3, 2e-3, 2e-4, 0.0,
                    lambda p, v: p.updated("controller", null_bias=v), doc="current added at the valve"),)),
    Candidate("load_stiffness", "change of the elastic load (hinge moment) stiffness",
              (Knob("extra_stiffness", "N/m", -8e4, 1e6, 4e4, 0.0,
                    lambda p, v: p.updated("surface", hinge_stiffness=max(p.surface.hinge_stiffness + v, 0.0)),
                    doc="added to surface.hinge_stiffness"),)),
    Candidate("leakage", "extra internal leakage across the piston (worn seal, bypass)",
              (Knob("extra_leakage", "m^3/(s Pa)", 0.0, 1e-10, 5e-12, 0.0,
                    lambda p, v: p.updated("hydraulics", leakage=max(p.hydraulics.leakage + v, 0.0)),
                    doc="added to hydraulics.leakage"),)),
    Candidate("mount_compliance", "compliant mount or attachment in series with the jack-to-surface link",
              (Knob("mount_compliance", "m/N", 0.0, 2e-6, 1e-7, 0.0, _mount, doc="series compliance"),)),
    Candidate("flow_asymmetry", "unequal extend/retract gains (metering edges, single-rod piston): "
              "the jack drifts to one side under alternating motion",
              (Knob("asymmetry", "-", -0.5, 0.5, 0.05, 0.0,
                    lambda p, v: p.updated("hydraulics", flow_asymmetry=v),
                    doc="block sees x_s (1 + a sign x_s)"),)),
    Candidate("vibration_null_shift", "servovalve null that moves with vibration: a null bias at rest "
              "that shifts with the jack's mean |acceleration| (rectified by the valve), so the offset "
              "between command and position changes with the motion",
              (Knob("null_shift_per_accel", "A s^2/m", -2e-4, 2e-4, 2e-5, 0.0, _vibration,
                    doc="null-bias change per m/s^2 of mean |acceleration|"),
               Knob("rest_null_bias", "A", -2e-3, 2e-3, 2e-4, 0.0,
                    lambda p, v: p.updated("controller", null_bias=v), doc="null bias at rest")),
              nests=(("null_shift_per_accel", "valve_null_bias"),)),
    # the nominal parameters of the loop a test rig or an installation gets wrong (measured with
    # tools/unlisted_effects.py: a surface twice as heavy, a position gain 15 % high and a velocity
    # feedback 30 % high each read "unexplained", the faults 0.06-0.09 off). A position gain
    # *below* nominal is K_GM's direction (both scale the current per metre of error): the data
    # tell the two apart only where the current saturates.
    Candidate("load_mass", "heavier or lighter load (surface, specimen, fixture): more inertia against the jack",
              (Knob("extra_load_mass", "kg", -12.0, 60.0, 5.0, 0.0,
                    lambda p, v: p.updated("surface", mass=max(p.surface.mass + v, 0.5)),
                    doc="added to surface.mass"),)),
    Candidate("controller_gain", "position-loop gain off its nominal (a mis-set or drifted controller gain): "
              "i = kp (1 + e) (x_c - x) - gas v",
              (Knob("position_gain_error", "-", -0.5, 0.5, 0.05, 0.0,
                    lambda p, v: p.updated("controller", kp=p.controller.kp * (1.0 + v)),
                    doc="controller.kp x (1 + e)"),)),
    Candidate("velocity_feedback", "velocity-feedback gain off its nominal (the loop's damping term): "
              "i = kp (x_c - x) - gas (1 + e) v",
              (Knob("velocity_gain_error", "-", -0.9, 2.0, 0.1, 0.0,
                    lambda p, v: p.updated("controller", gas=p.controller.gas * (1.0 + v)),
                    doc="controller.gas x (1 + e)"),),
              # kp (1 + e) is the loop gain (K_GM's direction) x a velocity feedback gas / (1 + e):
              # with K_GM free, only the current's saturation tells the two apart
              overlaps=("controller_gain",)),
    # the recorded command's own chain (found with an FDI test whose command was logged 50 um off:
    # "unexplained"). The model must be driven by the command the actuator received, so these
    # change the simulation, unlike the outputs' recording effects: with backlash and a hinge
    # spring, an operating point 50 um off changes the contacts (velocity residual 5 mm/s RMS at
    # (0.3, 0.4, 0.3)), which no offset of the recorded position mimics
    Candidate("command_offset", "offset of the recorded command: the actuator received the recorded command "
              "less it (a logger's or DAC's zero), so every output is off the recorded command by it",
              (Knob("command_offset", "m", -2e-3, 2e-3, 1e-4, 0.0, lambda p, v: _command(p, offset=v),
                    doc="recorded command = command + offset"),)),
    Candidate("command_scale", "gain error of the recorded command: the actuator received the recorded "
              "command / (1 + e)",
              (Knob("command_scale", "-", -0.3, 0.3, 0.02, 0.0, lambda p, v: _command(p, gain=v),
                    doc="recorded command = (1 + e) command"),)),
    Candidate("valve_response", "slower (or faster) servovalve spool: its time constant x (1 + a) and its rate "
              "limit / (1 + a) (spool end area, clogged pilot stage)",
              (Knob("valve_slowdown", "-", -0.6, 3.0, 0.2, 0.0, _spool,
                    doc="first_stage.spool_time_constant x (1 + a), spool_rate_limit / (1 + a)"),),
              # a supply sag slows the spool as well (its pilot flow): the two differ by the sagged
              # supply's pressure limit only, which an FDI test reaches only under a high load
              overlaps=("supply_pressure",)),
)

@dataclass(frozen=True)
class Recorded:
    """A knob's ``output``: the measurement-chain effect ``kind`` (:mod:`~..signals.recording`) on
    the recorded ``channels`` of a simulated output [n, N_OUT]; the one place a recording knob
    says what it does (the correction of the data reads it too)."""
    kind: str
    channels: tuple[str, ...]

    def __call__(self, out: np.ndarray, value: float, rate: float) -> np.ndarray:
        out = out.copy()
        for c in self.channels:
            col = CHANNEL_COLUMNS[c]
            out[:, col] = recording.APPLY[self.kind](out[:, col], value, rate)
        return out


#: Sizes of the recording effects: (lower, upper, typical) per kind; an offset in the channel's
#: residual scale (position 0.1 mm, pressure 0.5 MPa, ...), a drift in residual scales per second.
RECORDING_SIZES = {"offset": (-50.0, 50.0, 1.0), "scale": (-0.3, 0.3, 0.02), "skew": (-0.02, 0.02, 1e-3),
                   "lag": (0.0, 0.02, 1e-3), "drift": (-10.0, 10.0, 0.3), "stretch": (-0.02, 0.02, 1e-3)}
_IN_SCALES = ("offset", "drift")
_RECORDING_DOCS = {
    "offset": "offset of the recorded {c} (transducer zero, amplifier offset)",
    "scale": "scale error of the recorded {c} (transducer calibration, amplifier gain)",
    "skew": "time skew of the recorded {c} against the command (logger channel timing), either sign",
    "lag": "first-order lag of the {c} transducer or its anti-alias filter",
    "drift": "drift of the recorded {c}'s zero over the record (temperature, a charge amplifier's leak)"}


def corrected(response, model, x):
    """A copy of ``response`` with the recording effects of ``model`` at ``x`` undone on its channels
    (what a re-identification with those effects in the model must fit)."""
    import copy
    r = copy.copy(response)
    for k, v in zip(model.knobs, np.asarray(x, float)):
        if k.recording and v != k.off:
            for c in k.output.channels:
                setattr(r, c, recording.undo(k.output.kind, np.asarray(getattr(r, c), float), float(v),
                                             response.sample_rate))
    return r


def recording_candidates(channels=MEASURED) -> tuple[Candidate, ...]:
    """The measurement-chain candidates of ``channels``: offset, scale, skew, lag and drift of
    each, and two of the whole record: every channel skewed alike against the command, and every
    channel on a time base off the command's."""
    out = []
    for c in channels:
        for kind in recording.KINDS:
            lo, hi, typ = RECORDING_SIZES[kind]
            unit = recording.UNIT[kind].replace("channel", UNITS[c])
            if kind in _IN_SCALES:
                lo, hi, typ = (v * CHANNEL_SCALES[c] for v in (lo, hi, typ))
            out.append(Candidate(f"{c}_{kind}", _RECORDING_DOCS[kind].format(c=c),
                                 (Knob(f"{c}_{kind}", unit, lo, hi, typ, 0.0, output=Recorded(kind, (c,)),
                                       doc=_RECORDING_DOCS[kind].format(c=c)),),
                                 RECORDING_CHAIN, c))
    every = tuple(channels)
    for name, kind, doc in (
            ("command_skew", "skew", "every measured channel late against the recorded command alike (the command "
                                     "logged by another clock or buffer, or a transport delay before the actuator): "
                                     "a whole-record time skew, either sign"),
            ("time_base", "stretch", "every measured channel sampled on a time base (1 + e) faster than the "
                                     "command's (a logger clock, or a stated sample rate, off by e)")):
        lo, hi, typ = RECORDING_SIZES[kind]
        out.append(Candidate(name, doc, (Knob(name, recording.UNIT[kind], lo, hi, typ, 0.0,
                                              output=Recorded(kind, every), doc=doc),), RECORDING_CHAIN))
    return tuple(out)


def _lead(p: ModelParams, t_d: float) -> ModelParams:
    """Controller lead: i = kp (e + T_d de/dt), i.e. a derivative gain kd = kp T_d."""
    return p.updated("controller", kd=p.controller.kp * max(t_d, 0.0))


def _first_stage(p: ModelParams, df: float | None = None, dz: float | None = None) -> ModelParams:
    fs = p.first_stage
    return p.updated("first_stage", **({"natural_frequency": fs.natural_frequency * (1.0 + df)} if df is not None else {}),
                     **({"damping_ratio": fs.damping_ratio * (1.0 + dz)} if dz is not None else {}))


#: Loop structure a rig's frequency response can ask for beyond its calibration band (the gain
#: error above it): a lead in the controller and the valve's second-order (first-stage) dynamics.
#: Offered to rig records (no floor of the FDI monitor was measured with them).
STRUCTURAL: tuple[Candidate, ...] = (
    Candidate("controller_lead", "a lead in the position controller: i = kp (e + T_d de/dt); the closed loop's "
              "gain falls slower with frequency",
              (Knob("lead_time", "s", 0.0, 0.02, 1e-3, 0.0, _lead, doc="T_d = kd / kp"),)),
    Candidate("valve_dynamics", "the servovalve's second-order first stage: its natural frequency and damping "
              "(a resonance near the loop's bandwidth lifts or drops the gain there)",
              (Knob("valve_frequency_change", "-", -0.9, 3.0, 0.2, 0.0, lambda p, v: _first_stage(p, df=v),
                    doc="relative change of the first-stage natural frequency"),
               Knob("valve_damping_change", "-", -0.9, 3.0, 0.2, 0.0, lambda p, v: _first_stage(p, dz=v),
                    doc="relative change of the first-stage damping ratio"))),
)

#: In-loop candidates that change only the model's input (the recorded command's chain): the
#: monitor that holds the right one is the base monitor driven by the command the actuator got, so
#: its floor is the base floor (``bench floor`` measures the others' ``effect_floor``).
COMMAND_CHAIN = ("command_offset", "command_scale")

#: In-loop physics and every measured channel's recording chain.
IN_LOOP_CANDIDATES = CANDIDATES
RECORDING = recording_candidates()
CANDIDATES = IN_LOOP_CANDIDATES + RECORDING
BY_NAME = {c.name: c for c in CANDIDATES}


def overlapping(name: str, candidates) -> tuple[str, ...]:
    """The candidates of ``candidates`` that overlap ``name`` (:attr:`Candidate.overlaps`, either way)."""
    mine = next((c.overlaps for c in candidates if c.name == name), ())
    return tuple(c.name for c in candidates if c.name in mine or name in c.overlaps)
