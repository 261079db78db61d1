"""The FDI test sequence of the paper (Sec. V, Fig. 9), parametrised, with named segments.

    ramp    0    -> 1.0 s : x = 5 mm/s * t                 (FSJ and BKL signatures)
    step    1.0  -> 1.5 s : x = 10 mm                      (GM: overshoot)
    return  1.5  -> 1.8 s : x = 0
    sine    1.8  -> 3.5 s : x = A sin(phase), 2.5 Hz until 2.5 s, then 4 Hz

The paper gives neither the sine amplitude nor the end time. We use A = 5 mm
(half the step: large enough that the surface, not the sensor noise, dominates
the response, small enough that the 4 Hz peak speed 2 pi 4 A = 0.126 m/s stays
below the valve's 0.2 m/s no-load speed, so the sine probes the dynamics and not
the flow saturation) and 3.5 s (four full 4 Hz periods after the switch). The
phase is continuous at the frequency switch so the command has no jump there.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FDISequence:
    """Position command of the FDI test [m] as a function of time [s]."""
    ramp_rate: float = 5.0e-3      # m/s
    step_time: float = 1.0         # s, ramp end and step start
    step_level: float = 10.0e-3    # m
    return_time: float = 1.5       # s
    sine_start: float = 1.8        # s
    sine_amplitude: float = 5.0e-3  # m
    f_low: float = 2.5             # Hz
    switch_time: float = 2.5       # s
    f_high: float = 4.0            # Hz
    duration: float = 3.5          # s
    settle: float = 0.5            # s, between two tests: back to the first command, then rest
    preroll: float = 1.0           # s of the sequence's end simulated before a test that follows one

    def __post_init__(self):
        if not (np.isfinite(self.settle) and self.settle >= 0 and np.isfinite(self.preroll) and self.preroll >= 0):
            raise ValueError("sequence settle and preroll must be finite and >= 0 [s]")
        order = (0.0, self.step_time, self.return_time, self.sine_start, self.switch_time, self.duration)
        if any(b <= a for a, b in zip(order, order[1:])):
            raise ValueError(f"sequence times must increase: 0 < step < return < sine < switch < end, got {order}")
        for name in ("ramp_rate", "step_level", "sine_amplitude", "f_low", "f_high"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) <= 0:
                raise ValueError(f"sequence {name} must be a positive finite number")

    def command(self, t) -> np.ndarray:
        """Commanded position [m] at times ``t`` [s]."""
        t = np.asarray(t, dtype=float)
        x = np.zeros_like(t)
        ramp = t < self.step_time
        x[ramp] = self.ramp_rate * np.maximum(t[ramp], 0.0)
        x[(t >= self.step_time) & (t < self.return_time)] = self.step_level
        low = (t >= self.sine_start) & (t < self.switch_time)
        x[low] = self.sine_amplitude * np.sin(2 * np.pi * self.f_low * (t[low] - self.sine_start))
        high = t >= self.switch_time
        phase0 = 2 * np.pi * self.f_low * (self.switch_time - self.sine_start)
        x[high] = self.sine_amplitude * np.sin(phase0 + 2 * np.pi * self.f_high * (t[high] - self.switch_time))
        return x

    def return_to_start(self, u_from: float, n: int) -> np.ndarray:
        """``n`` samples from ``u_from`` [m] back to the first command, a raised cosine: the
        first half of the settle between two tests (the actuator then rests there)."""
        u0 = float(self.command(np.zeros(1))[0])
        return u_from + (u0 - u_from) * (1 - np.cos(np.pi * np.arange(1, n + 1) / n)) / 2

    def preamble(self, sample_rate: float) -> np.ndarray:
        """Command [m] that leads into a test following another one: the last ``preroll`` s of
        the sequence, the return to start over half the ``settle`` and the rest over the other
        half. Simulated from rest before the test, it leaves a model where the earlier test left
        the actuator: off the command by the dry friction, holding a load pressure, the jack at
        one side of its play (the state a fit from rest misses)."""
        t = self.times(sample_rate)
        tail = self.command(t[t >= self.duration - self.preroll])
        m = int(round(self.settle / 2 * sample_rate))
        return np.concatenate([tail, self.return_to_start(tail[-1], m), np.full(m, self.command(np.zeros(1))[0])])

    def times(self, sample_rate: float) -> np.ndarray:
        """Sample times [s] covering [0, duration)."""
        n = int(round(self.duration * sample_rate))
        return np.arange(n) / sample_rate

    def segments(self) -> dict[str, tuple[float, float]]:
        """Named segments ``name -> (t_start, t_end)`` [s] that identification can address."""
        return {
            "ramp": (0.0, self.step_time),
            "step": (self.step_time, self.return_time),
            "return": (self.return_time, self.sine_start),
            "sine": (self.sine_start, self.duration),
            "sine_low": (self.sine_start, self.switch_time),
            "sine_high": (self.switch_time, self.duration),
        }

    def mask(self, name: str, t: np.ndarray) -> np.ndarray:
        """Boolean mask of the samples of segment ``name``."""
        segs = self.segments()
        if name not in segs:
            raise ValueError(f"unknown segment {name!r}; known: {sorted(segs)}")
        a, b = segs[name]
        return (t >= a) & (t < b)
