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


class NoSamples(WindowError):
    """Not one sample of ``channel`` in the window: nothing of that source reached the reader."""

    def __init__(self, channel: str):
        super().__init__(f"{channel}: no samples in the test window")
        self.channel = channel


class IncompleteWindow(WindowError):
    """The samples of a channel stop before the window's end (the source stopped: a plant killed
    mid-test, a link gone): the window is reported incomplete, not diagnosed on what arrived."""


#: Gap fill: at most this fraction of a channel's samples may be filled [-].
MAX_FILL_FRACTION = 0.10


def _runs(missing: np.ndarray) -> tuple[int, int]:
    """Longest run of consecutive True in ``missing`` and the index where it starts."""
    d = np.diff(np.concatenate([[0], missing.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    if len(starts) == 0:
        return 0, 0
    i = int(np.argmax(ends - starts))
    return int(ends[i] - starts[i]), int(starts[i])


def fill_gaps(name: str, grid: np.ndarray, s: Samples, start_ns: int, max_fill: int) -> tuple[np.ndarray, int]:
    """``s`` on ``grid`` and the number of samples filled.

    Missing samples (lost messages) are filled by linear interpolation between their neighbours
    when no run of them is longer than ``max_fill`` samples and at most :data:`MAX_FILL_FRACTION`
    of the channel is missing; otherwise :class:`WindowError` names the gap. A channel whose
    samples stop before the window end (a tail longer than ``max_fill``) raises
    :class:`IncompleteWindow`.
    """
    have = np.isin(grid, s.stamps)
    missing = ~have
    n_miss = int(missing.sum())
    if n_miss == 0:
        return s.values, 0
    n = len(grid)
    tail = n - 1 - int(np.flatnonzero(have)[-1]) if have.any() else n
    if tail > max_fill:
        raise IncompleteWindow(f"{name}: samples stop at {_t(s.stamps[-1], start_ns)}, {tail} of {n} missing to the "
                               f"window end at {_t(grid[-1], start_ns)} (the source stopped answering)")
    longest, at = _runs(missing)
    if max_fill <= 0:
        raise WindowError(f"{name}: {n_miss} sample(s) missing, first at {_t(grid[missing][0], start_ns)}")
    if longest > max_fill or n_miss > MAX_FILL_FRACTION * n:
        raise WindowError(f"{name}: {n_miss} sample(s) missing, longest gap {longest} at {_t(grid[at], start_ns)} "
                          f"(gap fill limit: runs of {max_fill}, {MAX_FILL_FRACTION:.0%} of the window)")
    out = np.empty(n)
    out[have] = s.values
    out[missing] = np.interp(grid[missing].astype(float), s.stamps.astype(float), s.values)
    return out, n_miss


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
             sequence: FDISequence | None = None, meta: dict | None = None, record: bool = False,
             max_fill: int = 0) -> Response:
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
            raise NoSamples(name)
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
    out, filled = {}, {}
    n = len(grid)
    for name in MEASURED + (("load",) if record else ()):
        if name not in cut:
            out[name] = np.full(n, np.nan)
            continue
        s = cut[name]
        extra = ~np.isin(s.stamps, grid)
        if extra.any():
            raise WindowError(f"{name}: {int(extra.sum())} sample(s) at stamps with no command, "
                              f"first at {_t(s.stamps[extra][0], start_ns)}")
        out[name], k = fill_gaps(name, grid, s, start_ns, max_fill)
        if k:
            filled[name] = k
    load = out.pop("load", None)
    return Response(t=(grid - start_ns) / NS, command=cut["command"].values, spool=np.full(n, np.nan),
                    meta={**(meta or {}), **({"filled": filled} if filled else {})},
                    load=None if load is None or np.isnan(load).all() else load, **out)
