"""Assemble one test window from per-channel stamped samples, and check it.

Samples arrive per channel (command, position, velocity, pressure, current), each
with an integer-nanosecond stamp. The command defines the window's time grid: the
plant answers each command sample with one sample per channel at the same stamp,
so channels align exactly. :func:`assemble` checks order, duplicates, NaN, gaps,
dropped samples and length, and raises :class:`WindowError` with one line naming
the channel, the problem and where it is.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..physics.sequence import FDISequence
from ..signals.channels import MEASURED
from ..signals.response import Response

NS = 1_000_000_000


class WindowError(ValueError):
    """The recorded window cannot be diagnosed; the message says why."""


@dataclass
class Samples:
    """One channel in arrival order: stamps [ns] and values [SI]."""
    stamps: np.ndarray
    values: np.ndarray

    @classmethod
    def of(cls, pairs) -> "Samples":
        if len(pairs) == 0:
            return cls(np.zeros(0, np.int64), np.zeros(0))
        s, v = zip(*pairs)
        return cls(np.asarray(s, np.int64), np.asarray(v, float))


def _t(ns: int, start: int) -> str:
    return f"t={(ns - start) / NS:.4f} s"


def _check_order(name: str, s: Samples, start: int) -> None:
    d = np.diff(s.stamps)
    if (d == 0).any():
        raise WindowError(f"{name}: duplicate stamp at {_t(s.stamps[1:][d == 0][0], start)}")
    if (d < 0).any():
        raise WindowError(f"{name}: stamps out of order at {_t(s.stamps[1:][d < 0][0], start)}")
    bad = ~np.isfinite(s.values)
    if bad.any():
        raise WindowError(f"{name}: {int(bad.sum())} NaN/inf sample(s), first at {_t(s.stamps[bad][0], start)}")


def assemble(channels: dict[str, Samples], start_ns: int, end_ns: int,
             sequence: FDISequence | None = None, meta: dict | None = None, record: bool = False) -> Response:
    """Build the :class:`Response` of the window ``[start_ns, end_ns]`` (stamps, inclusive).

    ``channels`` maps 'command' and the :data:`MEASURED` names to their samples
    (may extend beyond the window). ``t`` of the result is relative to ``start_ns``.
    ``record=True`` reads a measured record rather than an FDI test: only command and
    position are required, a channel absent or never measured (all NaN) comes out all
    NaN, an optional 'load' channel [N] becomes ``Response.load``, and the window need
    not cover the FDI sequence.
    """
    seq = sequence or FDISequence()
    if end_ns <= start_ns:
        raise WindowError(f"window end ({end_ns} ns) is not after its start ({start_ns} ns)")
    required = ("command", "position") if record else ("command",) + MEASURED
    for name in required:
        if name not in channels:
            raise WindowError(f"channel {name} missing")
    cut = {}
    for name, s in channels.items():
        inside = (s.stamps >= start_ns) & (s.stamps <= end_ns)
        if record and name not in required and not np.isfinite(s.values[inside]).any():
            continue            # not measured on this rig
        cut[name] = Samples(s.stamps[inside], s.values[inside])
        if len(cut[name].stamps) == 0:
            raise WindowError(f"{name}: no samples in the test window")
        _check_order(name, cut[name], start_ns)
    grid = cut["command"].stamps
    if len(grid) < 100:
        raise WindowError(f"window too short: {len(grid)} command samples")
    dt = np.diff(grid)
    step = int(np.median(dt))
    gaps = np.abs(dt - step) > max(step // 100, 1)
    if gaps.any():
        i = int(np.argmax(gaps))
        raise WindowError(f"command: gap of {dt[i] / 1e6:.3f} ms at {_t(grid[i + 1], start_ns)} "
                          f"(sample period {step / 1e6:.3f} ms): samples dropped or jittered")
    if grid[0] != start_ns:
        raise WindowError(f"command: first sample at {_t(grid[0], start_ns)}, not at the window start")
    covered = (grid[-1] - grid[0] + step) / NS
    if not record and covered < seq.duration - 1e-9:
        raise WindowError(f"window too short: {covered:.3f} s recorded, the FDI sequence lasts {seq.duration:g} s")
    out = {}
    n = len(grid)
    for name in MEASURED + (("load",) if record else ()):
        if name not in cut:
            out[name] = np.full(n, np.nan)
            continue
        s = cut[name]
        have = np.isin(grid, s.stamps)
        if not have.all():
            raise WindowError(f"{name}: {int((~have).sum())} sample(s) missing, first at {_t(grid[~have][0], start_ns)}")
        extra = ~np.isin(s.stamps, grid)
        if extra.any():
            raise WindowError(f"{name}: {int(extra.sum())} sample(s) at stamps with no command, "
                              f"first at {_t(s.stamps[extra][0], start_ns)}")
        out[name] = s.values
    load = out.pop("load", None)
    return Response(t=(grid - start_ns) / NS, command=cut["command"].values, spool=np.full(n, np.nan),
                    meta=dict(meta or {}), load=None if load is None or np.isnan(load).all() else load, **out)
