"""Kinematic consistency: a recorded velocity against the derivative of the recorded position.

Whatever the actuator does, v = dx/dt. A measurement-chain effect E on the velocity recording
(scale, skew, lag, offset: :mod:`.recording`) makes v_rec = E(dx/dt), and no model of the
actuator is needed to see it: the mismatch between the two recordings is free of the model's
form error, which hides a velocity effect in a weighted model residual (the velocity repeats the
position's information there and weighs little). Both sides are low-passed by one zero-phase
filter (4th-order Butterworth at ``band_hz``, twice the command's band by default) to bring the
differentiated position noise down, and compared away from the ends. The mismatch that the two
channels' white noise alone leaves is known from the filter: sigma_x^2 sum(h_x^2) +
sigma_v^2 sum(h_v^2), h the pipeline's impulse responses (measured: ratio 1.0-1.1 on
unaltered FDI tests; a +3 % velocity scale 300x at 25 Hz).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from . import recording
from .datachecks import command_band
from .residuals import noise_level

#: Samples dropped at each end of the compared signals [s] (filter and derivative start-up).
EDGE_S = 0.05


@dataclass
class Kinematics:
    """The two recordings of one motion, filtered, and the mismatch their noise leaves."""
    derivative: np.ndarray     # dx/dt of the recorded position, central differences [m/s]
    velocity: np.ndarray       # the recorded velocity [m/s]
    rate: float                # Hz
    band_hz: float
    noise_position: float      # white-noise standard deviation of the position recording [m]
    noise_velocity: float      # ... of the velocity recording [m/s]

    def __post_init__(self):
        self._sos = butter(4, self.band_hz, fs=self.rate, output="sos")
        self._edge = int(round(EDGE_S * self.rate))
        self._v = self._filter(self.velocity)
        # the pipeline's impulse responses give what white noise of each channel leaves
        imp = np.zeros(8192)
        imp[len(imp) // 2] = 1.0
        hx, hv = self._filter(np.gradient(imp, 1.0 / self.rate)), self._filter(imp)
        #: mismatch power of the channels' white noise alone [(m/s)^2]
        self.noise_power = self.noise_position ** 2 * float(hx @ hx) + self.noise_velocity ** 2 * float(hv @ hv)
        #: mismatch power of the recordings as they are (v against dx/dt) [(m/s)^2]
        self.identity_mismatch = self.mismatch()

    def _filter(self, y: np.ndarray) -> np.ndarray:
        return sosfiltfilt(self._sos, y)

    def mismatch(self, kind: str | None = None, value: float = 0.0) -> float:
        """Mean square of v_rec - E(dx/dt) after the filter [(m/s)^2], E the velocity recording
        effect ``kind`` of size ``value`` (none: the plain identity v = dx/dt)."""
        d = self.derivative if kind is None else recording.APPLY[kind](self.derivative, value, self.rate)
        m = (self._v - self._filter(d))[self._edge:len(d) - self._edge]
        return float(np.mean(m ** 2))

    @property
    def significant(self) -> bool:
        """The recordings disagree beyond 4x what their noise explains."""
        return self.identity_mismatch > 4.0 * self.noise_power


def kinematics(position: np.ndarray, velocity: np.ndarray, command: np.ndarray, rate: float) -> Kinematics | None:
    """:class:`Kinematics` of a record, or None when it is too short to filter (< 1 s)."""
    x, v = np.asarray(position, float), np.asarray(velocity, float)
    if len(x) < rate or len(x) != len(v) or not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
        return None
    band = float(np.clip(2.0 * command_band(command, rate), 5.0, 0.4 * rate))
    return Kinematics(np.gradient(x, 1.0 / rate), v, rate, band, noise_level(x), noise_level(v))
