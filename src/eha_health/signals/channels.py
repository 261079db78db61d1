"""Channel names and units: the one place they are defined.

A test response holds the command and, per sample, what the actuator's sensors measure.
Every value is SI: the unit of each channel is below; reports show the readable units of
:data:`DISPLAY_UNITS`.
"""
from __future__ import annotations

#: What a rig measures and an identification compares: surface position and velocity (the
#: user side of the backlash), jack differential pressure P12 and servovalve current.
MEASURED = ("position", "velocity", "pressure", "current")
#: Channels a simulated response also holds (a rig rarely instruments the spool).
SIMULATED = MEASURED + ("spool", "jack_position")
#: SI unit of every channel.
UNITS = {"t": "s", "command": "m", "position": "m", "velocity": "m/s", "pressure": "Pa", "current": "A",
         "spool": "m", "jack_position": "m", "load": "N"}
#: (factor, unit) to show each measured channel's residual in readable units (reports and plots).
DISPLAY_UNITS = {"position": (1e6, "um"), "velocity": (1e3, "mm/s"), "pressure": (1e-3, "kPa"), "current": (1e6, "uA")}
