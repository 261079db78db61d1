"""The discrepancy loop on FDI tests altered in ways the bench does not list (a generalisation probe).

    python tools/unlisted_effects.py [NAME ...]

`eha-health bench discrepancy` scores the loop on one alteration per candidate, of one size,
made by another numerical method than the candidate's. This script asks what the loop says of
alterations with no candidate of their own, or of other sizes and shapes: a second-order
transducer, a channel held at a quarter of the rate, a velocity differentiated from the position,
a nonlinear pressure transducer, mains hum with a current offset, two recording effects on two
channels, one chamber's pressure recorded as P12, a pressure with its sign inverted, one-sample
glitches, a logger that froze, a hum on the position, a clipped pressure transducer, a different
sign or size of the bench's ones, quantisation, coloured and stronger noise, a dropout written as
NaN, a command recorded off its zero with a position lag, a channel in mA or with its sign
inverted, and nominal-parameter changes in the plant (valve flow gain, jack area, controller
gain either way, hinge friction, supply, leakage, a slower valve; oil softer than the bench's,
alone and with a pressure offset). One noisy reference run at faults (0.3, 0.4, 0.3), seed 777,
up to two effects; per case the verdict, the selection, the first three candidates, the data checks, the largest fault-coefficient error before -> after and the
loop's time (or the error that refused the record before any fit). The figures of docs/discrepancy.md ("Alterations the bench does not list") come
from this script.
"""
import copy
import sys

import numpy as np
from scipy.signal import butter, cont2discrete, lfilter

from eha_health.bench.discrepancy import all_late, drifting, fast_clock, lagged, late, offset, reference_run, scaled
from eha_health.discrepancy.loop import analyse_fdi_test
from eha_health.physics.faults import Faults
from eha_health.physics.params import load


def second_order(r, channel="position", f_hz=30.0, zeta=0.6):
    """``channel`` through a second-order transducer (natural frequency ``f_hz``, damping ``zeta``)."""
    w = 2 * np.pi * f_hz
    b, a, _ = cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), 1.0 / r.sample_rate, method="bilinear")
    y = getattr(r, channel)
    setattr(r, channel, lfilter(np.ravel(b), a, y - y[0]) + y[0])
    return r


def held(r, channel="position", k=4):
    """``channel`` sampled at 1/``k`` of the rate and held (zero-order hold)."""
    y = getattr(r, channel)
    setattr(r, channel, np.repeat(y[::k], k)[:len(y)])
    return r


def quadratic_pressure(r):
    r.pressure = r.pressure + 0.05 * r.pressure ** 2 / 1e7      # +5 % of reading per 10 MPa
    return r


def differentiated_velocity(r):
    r.velocity = np.gradient(r.position, r.t)
    return r


def one_chamber_pressure(r):
    r.pressure = 0.5 * r.pressure + 10.35e6        # P1 = Ps / 2 + P12 / 2 recorded as P12
    return r


def inverted_pressure(r):
    r.pressure = -r.pressure                         # P2 - P1 recorded for P1 - P2
    return r


def position_glitches(r):
    r.position = r.position.copy()
    r.position[np.random.default_rng(5).choice(len(r.t), 5, replace=False)] += 1e-3
    return r


def position_frozen(r, every=500, hold=25):
    """The logger repeats its last position value for ``hold`` samples every ``every``."""
    y = r.position.copy()
    for s in range(100, len(y) - hold, every):
        y[s:s + hold] = y[s]
    r.position = y
    return r


def position_hum(r):
    r.position = r.position + 10e-6 * np.sin(2 * np.pi * 60.0 * r.t)
    return r


def pressure_clipped(r):
    r.pressure = np.clip(r.pressure, -1e6, 1e6)     # a transducer (or its amplifier) at +-1 MPa
    return r


def dead(r, channel):
    """The transducer (or its cable) dead: the channel reads 0 all test."""
    setattr(r, channel, np.zeros_like(getattr(r, channel)))
    return r


def logged_slower(r, k):
    """A logger at 1/k of the controller's rate: every k-th sample of every signal."""
    return r.sliced(slice(None, None, k))


def hum_and_current_offset(r):
    r.pressure = r.pressure + 2e5 * np.sin(2 * np.pi * 50.0 * r.t)
    r.current = r.current + 2e-4
    return r


def quantised(r, channel, step):
    setattr(r, channel, np.round(getattr(r, channel) / step) * step)
    return r


def coloured_position_noise(r, sd=8e-6, f_hz=5.0):
    """Low-frequency noise on the position (second-order Butterworth below ``f_hz``), ``sd`` [m] RMS."""
    b, a = butter(2, f_hz / (r.sample_rate / 2))
    n = lfilter(b, a, np.random.default_rng(9).normal(0.0, 1.0, len(r.t)))
    r.position = r.position + n * sd / n.std()
    return r


def more_noise(r, k=3.0):
    """White noise ``k`` x the default sensor noise (params.yaml) added on every channel (4x its power in all)."""
    rng, sn = np.random.default_rng(10), load("reference").effects.sensor_noise
    for c in ("position", "velocity", "pressure", "current"):
        setattr(r, c, getattr(r, c) + rng.normal(0.0, k * getattr(sn, c), len(r.t)))
    return r


def pressure_gap(r):
    r.pressure = r.pressure.copy()
    r.pressure[1200:1220] = np.nan                   # a logger dropout written as NaN
    return r


def current_in_ma(r):
    r.current = r.current * 1e3
    return r


def inverted_velocity(r):
    r.velocity = -r.velocity
    return r


def _on_a_copy(alter):
    """``alter`` applied to a copy: the functions above set the channels of the response they are
    given, and a caller reusing one simulated run across alterations would get them stacked."""
    return lambda r: alter(copy.deepcopy(r))


ALTERED = {
    "position drift 30 um/s": lambda r: drifting(r, "position", 30e-6),
    "every channel 3 ms late": lambda r: all_late(r, 3e-3),
    "time base 1 % fast": lambda r: fast_clock(r, 0.01),
    "position 2 ms early": lambda r: late(r, "position", -2e-3),
    "position, 2nd-order transducer 30 Hz": second_order,
    "position held at 250 Hz": held,
    "pressure transducer quadratic": quadratic_pressure,
    "velocity differentiated from position": differentiated_velocity,
    "pressure 50 Hz hum + current offset 0.2 mA": hum_and_current_offset,
    "current lag 2 ms + scale +5 %": lambda r: scaled(lagged(r, "current", 2e-3), "current", 0.05),
    "pressure -0.3 MPa + position scale -2 %": lambda r: scaled(offset(r, "pressure", -3e5), "position", -0.02),
    "one chamber's pressure recorded as P12": one_chamber_pressure,
    "pressure recorded as P2 - P1": inverted_pressure,
    "position, 5 one-sample glitches of 1 mm": position_glitches,
    "position frozen 25 ms every 0.5 s": position_frozen,
    "position 60 Hz hum 10 um": position_hum,
    "pressure clipped at +-1 MPa": pressure_clipped,
    "pressure transducer dead (reads 0)": lambda r: dead(r, "pressure"),
    "position transducer dead (reads 0)": lambda r: dead(r, "position"),
    "logged at 250 Hz (controller at 1 kHz)": lambda r: logged_slower(r, 4),
    "oil 1.5 GPa + pressure offset 0.2 MPa": lambda r: offset(r, "pressure", 2e5),
    "position quantised 20 um": lambda r: quantised(r, "position", 20e-6),
    "pressure quantised 50 kPa": lambda r: quantised(r, "pressure", 5e4),
    "position coloured noise 8 um below 5 Hz": coloured_position_noise,
    "noise x4 on every channel": more_noise,
    "velocity offset 5 mm/s": lambda r: offset(r, "velocity", 5e-3),
    "current 1.5 ms early": lambda r: late(r, "current", -1.5e-3),
    "pressure lag 3 ms + position offset 0.2 mm": lambda r: offset(lagged(r, "pressure", 3e-3), "position", 2e-4),
    "pressure NaN for 20 samples": pressure_gap,
    "command recorded 50 um off + position lag 2 ms": lambda r: lagged(offset(r, "command", 5e-5), "position", 2e-3),
    "current recorded in mA": current_in_ma,
    "velocity sign inverted": inverted_velocity,
}
ALTERED = {name: _on_a_copy(alter) for name, alter in ALTERED.items()}
PLANT = {
    "valve flow gain -10 %": lambda p: p.updated("hydraulics", flow_gain=p.hydraulics.flow_gain * 0.9),
    "jack area +5 %": lambda p: p.updated("jack", area=p.jack.area * 1.05),
    "controller gain +15 %": lambda p: p.updated("controller", kp=p.controller.kp * 1.15),
    "hinge friction 300 -> 200 N": lambda p: p.updated("surface", hinge_friction=200.0),
    "controller gain -15 %": lambda p: p.updated("controller", kp=p.controller.kp * 0.85),
    "supply 10 % low": lambda p: p.updated("hydraulics", supply_pressure=p.hydraulics.supply_pressure * 0.9),
    "leakage x20": lambda p: p.updated("hydraulics", leakage=p.hydraulics.leakage * 20),
    "slower valve (spool end area x1.6)": lambda p: p.updated("flapper_nozzle",
                                                              spool_end_area=p.flapper_nozzle.spool_end_area * 1.6),
    "oil 0.8 GPa": lambda p: p.with_effects(compressibility={"enabled": True, "bulk_modulus": 8e8}),
    "oil 1.5 GPa + pressure offset 0.2 MPa": lambda p: p.with_effects(compressibility={"enabled": True,
                                                                                       "bulk_modulus": 1.5e9}),
}


def main() -> None:
    names = sys.argv[1:] or list(dict.fromkeys(list(ALTERED) + list(PLANT)))   # a name in both: plant and record
    ref, faults = load("reference"), Faults(0.3, 0.4, 0.3)
    for name in names:
        r = reference_run(faults, 777, PLANT.get(name), ALTERED.get(name), ref)
        try:
            rep = analyse_fdi_test(r, max_effects=2, truth=faults.as_dict())
        except ValueError as e:        # a record the data checks refuse before any fit
            print(f"{name}: refused: {e}", flush=True)
            continue
        first = ", ".join(c.name for c in rep.candidates[:3])
        print(f"{name}: {rep.verdict}; selected {', '.join(rep.selected) or '-'}; first {first}; "
              f"max|dK| {max(rep.before.errors.values()):.3f} -> {max(rep.after.errors.values()):.3f}; "
              f"{rep.wall_time_s:.1f} s" + (f"; checks: {'; '.join(rep.data_checks)}" if rep.data_checks else ""),
              flush=True)


if __name__ == "__main__":
    main()
